"""``ncgate sweep`` takes its variants as a stream: a spec's ids are hashed as its variants are
taken, not when it is loaded, and ``--resume`` skips the kept rows' variants as they come,
making and running the others in the spec's order, each once.  ``execute`` is replaced by
one that runs nothing (the pool and Dask are test_sweep's), so what is seen is the order the
sweep hands the variants out in, and what was made before each."""

from __future__ import annotations

import hashlib
import io
import itertools
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pytest

from ncgate.gateway.sweep import main as sweep_main
from ncgate.gateway.sweep import run as sweep_run
from ncgate.gateway.sweep import spec as sweep_spec
from ncgate.gateway.sweep.spec import SpecError, Variant, load_spec, variant_id
from ncgate.gateway.sweep.table import Parts, make_row

from .test_sweep import LOOPS, rows_of
from .test_sweep_scale import MILLION

GRID_OF_MILLION = [list(range(50, 60)), [float(i) for i in range(10)], list(range(1, 11)),
                   [0.5 + i / 10 for i in range(10)], [float(i) for i in range(10)],
                   list(range(10))]  # test_sweep_scale's MILLION, in its order

FEEDS = [50, 75, 100, 125]
SCANS = [1, 2, 4, 8]
BLOCKS = [0.0, 5.0, 10.0, 20.0]
SPEC = ('[sweep]\nprograms = ["OK.nc"]\n[grid]\n'
        f'"nc.feed_override" = {FEEDS}\n"plc.scan_ms" = {SCANS}\n'
        f'"nc.block_time_ms" = {BLOCKS}\n')


class Recorder:
    """``execute``'s stand-in: each variant as it is taken, and how many variants had been
    made by then; every result ``ok``."""

    def __init__(self, made: dict[str, int]) -> None:
        self.made = made
        self.taken: list[Variant] = []
        self.made_then: list[int] = []

    def __call__(self, variants: Iterable[Variant], options: sweep_main.Options,
                 client: object = None) -> Iterator[tuple[Variant, sweep_run.Result]]:
        for variant in variants:
            self.taken.append(variant)
            self.made_then.append(self.made["made"])
            yield variant, sweep_run._result("ok")


def spec_variant(folder: Path, keys: list[str], values: tuple[Any, ...]) -> Variant:
    """The variant of OK.nc (no config, no script) with these values, made here: its id is
    the hash of its identity (docs/sweep.md), as test_sweep_scale checks it."""
    sets = tuple(zip(keys, values, strict=True))
    identity = {"program": "OK.nc", "config": None, "script": None, "until": None,
                "sets": sets, "budget_s": 3600.0}
    return Variant(variant_id(identity), "OK.nc", "OK", None, None, None, sets, 3600.0,
                   str(folder.resolve()))


def counting_variants(monkeypatch: pytest.MonkeyPatch, most: int) -> dict[str, int]:
    counts = {"made": 0}
    real = sweep_spec.Variant

    def made(*args: Any, **kwargs: Any) -> Variant:
        counts["made"] += 1
        assert counts["made"] <= most, "variants made ahead of being taken"
        return real(*args, **kwargs)

    monkeypatch.setattr(sweep_spec, "Variant", made)
    return counts


def test_a_resume_runs_the_rows_it_lacks_in_the_specs_order_each_once_as_taken(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Kept rows in the middle of the spec's order (and one at its start): the resume runs
    exactly the others, in the spec's order (the last key varying fastest), once each, and
    makes each variant only when it is taken -- no list of what remains is made first."""
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text(SPEC)
    monkeypatch.chdir(tmp_path)
    spec = load_spec("spec.toml")
    # The spec's order, told from the values (the last key varying fastest).
    places = {tuple(c): i for i, c in enumerate(itertools.product(FEEDS, SCANS, BLOCKS))}
    order = sorted(spec.variants, key=lambda v: places[tuple(value for _, value in v.sets)])
    assert len(order) == len(spec.variants) == 64
    kept = [0, *range(20, 40)]
    # A stopped sweep's parts: these rows done (``hazard``, to tell them from rows run now).
    parts = Parts(Path("spec.csv"), spec)
    parts.start(resume=False)
    parts.add([make_row(order[i], sweep_run._result("hazard"), spec.keys) for i in kept])

    counts = counting_variants(monkeypatch, 64)
    recorder = Recorder(counts)
    monkeypatch.setattr(sweep_main, "execute", recorder)
    out = io.StringIO()
    status, rows = sweep_main.run_sweep(
        spec, sweep_main.Options(Path("spec.csv"), workers=1, resume=True, progress=False),
        out)
    assert status == sweep_main.EXIT_FAILED  # the kept rows are hazards
    assert "resuming: 21 of 64 variants done, 43 to run" in out.getvalue()
    rest = [i for i in range(64) if i not in kept]
    assert [v.id for v in recorder.taken] == [order[i].id for i in rest]
    # Each made as it was taken: the kept ones before it and itself, nothing ahead.
    assert recorder.made_then == [i + 1 for i in rest]
    table = rows_of(Path("spec.csv"))
    assert [r["id"] for r in table] == sorted(v.id for v in order)
    verdicts = {r["id"]: r["verdict"] for r in table}
    assert {i for i, v in enumerate(order) if verdicts[v.id] == "hazard"} == set(kept)
    assert [r["id"] for r in rows] == [r["id"] for r in table]


def test_a_resume_of_a_million_starts_its_first_variant_without_making_the_rest(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A spec of 1,000,000 with its first 3 rows kept: the first variant the resume runs is
    the 4th of the spec, and it is the 4th variant made (a list of the remaining ones would
    have made a million first)."""
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text(MILLION)
    monkeypatch.chdir(tmp_path)
    spec = load_spec("spec.toml")
    first = [spec_variant(tmp_path, spec.keys, values)
             for values in itertools.islice(itertools.product(*GRID_OF_MILLION), 5)]
    parts = Parts(Path("spec.csv"), spec)
    parts.start(resume=False)
    parts.add([make_row(v, sweep_run._result("ok"), spec.keys) for v in first[:3]])

    counts = counting_variants(monkeypatch, 10)
    recorder = Recorder(counts)

    def two_then_stop(variants: Iterable[Variant], options: sweep_main.Options,
                      client: object = None) -> Iterator[tuple[Variant, sweep_run.Result]]:
        for n, item in enumerate(recorder(variants, options, client), 1):
            yield item
            if n == 2:
                raise KeyboardInterrupt("SIGTERM")

    monkeypatch.setattr(sweep_main, "execute", two_then_stop)
    status, _ = sweep_main.run_sweep(
        spec, sweep_main.Options(Path("spec.csv"), workers=1, resume=True, progress=False),
        io.StringIO())
    assert status == sweep_main.EXIT_FAILED  # stopped by "SIGTERM"
    assert [v.id for v in recorder.taken] == [v.id for v in first[3:5]]
    assert recorder.made_then == [4, 5]


def test_a_spec_is_loaded_without_hashing_its_ids(monkeypatch: pytest.MonkeyPatch,
                                                   tmp_path: Path) -> None:
    """A spec of 1,000,000 is counted, not hashed, when it is loaded: the sha-256s taken are
    the files' (the spec, the program), and each variant's id is hashed when it is taken."""
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text(MILLION)
    hashes = {"n": 0}

    class Counted:
        def __getattr__(self, name: str) -> Any:
            return getattr(hashlib, name)

        @staticmethod
        def sha256(*args: Any) -> Any:
            hashes["n"] += 1
            assert hashes["n"] <= 100, "a hash per variant"
            return hashlib.sha256(*args)

    monkeypatch.setattr(sweep_spec, "hashlib", Counted())
    monkeypatch.chdir(tmp_path)
    spec = load_spec("spec.toml")
    assert len(spec.variants) == 1_000_000
    loaded = hashes["n"]
    assert loaded <= 4  # the fingerprint and each file's digest
    taken = list(itertools.islice(spec.variants.in_spec_order(), 3))
    assert hashes["n"] == loaded + 3 and len({v.id for v in taken}) == 3


def test_two_variants_of_one_id_are_refused_as_they_are_taken(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Ids cut to 2 hex digits (256 ids for 64 variants: two share one): the sweep refuses
    the second of the pair when it takes it, naming both, and keeps the rows run before it
    in its parts.  (A run given twice is refused at load: test_sweep.)"""
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text(SPEC)
    monkeypatch.setattr(sweep_spec, "ID_LENGTH", 2)
    monkeypatch.chdir(tmp_path)
    spec = load_spec("spec.toml")  # loads: no run is given twice
    order = list(spec.variants.in_spec_order())
    seen: dict[str, Variant] = {}
    for second in order:
        if second.id in seen:
            break
        seen[second.id] = second
    else:
        pytest.fail("no two variants share a 2-digit id")
    recorder = Recorder({"made": 0})
    monkeypatch.setattr(sweep_main, "execute", recorder)
    with pytest.raises(SpecError, match=f"two variants have the id {second.id}") as refused:
        sweep_main.run_sweep(spec, sweep_main.Options(Path("spec.csv"), workers=1,
                                                      progress=False), io.StringIO())
    assert seen[second.id].command() in str(refused.value)
    assert second.command() in str(refused.value)
    assert [v.id for v in recorder.taken] == [v.id for v in order[:order.index(second)]]
    kept = Parts(Path("spec.csv"), spec).folder
    assert sum(len(p.read_text().splitlines()) for p in kept.glob("part-*.jsonl")) == len(
        recorder.taken)
