"""``ncgate sweep`` at its limits: a spec of the most variants a sweep may run (1,000,000)
is built without per-variant path work and its variants made as they are taken; ``--explore``
says what its reduction does, step by step, and does not reduce a wall timeout."""

from __future__ import annotations

import itertools
import shlex
from pathlib import Path
from typing import Any

import pytest

from ncgate.gateway.sweep import main as sweep_main
from ncgate.gateway.sweep import run as sweep_run
from ncgate.gateway.sweep import spec as sweep_spec
from ncgate.gateway.sweep.spec import MAX_VARIANTS, load_spec, variant_id

from .test_sweep import LOOPS, ncgate, rows_of

# 10 ** 6 = MAX_VARIANTS: six keys of ten values each, one program.
MILLION = '[sweep]\nprograms = ["OK.nc"]\n[grid]\n' + "".join(
    f'"{key}" = {values}\n' for key, values in [
        ("nc.feed_override", list(range(50, 60))),
        ("nc.block_time_ms", [float(i) for i in range(10)]),
        ("plc.scan_ms", list(range(1, 11))),
        ("sim.input_delay_scale", [0.5 + i / 10 for i in range(10)]),
        ("sim.input_jitter_ms", [float(i) for i in range(10)]),
        ("sim.seed", list(range(10)))])


def test_a_million_variants_are_made_as_they_are_taken(monkeypatch: pytest.MonkeyPatch,
                                                        tmp_path: Path) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text(MILLION)
    counts = {"shown": 0, "rel": 0, "made": 0}

    def counted(name: str, function: Any, most: int) -> Any:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            counts[name] += 1
            # Per variant, not per run: fail at once, not after minutes of it.
            assert counts[name] <= most, f"{name} called per variant"
            return function(*args, **kwargs)
        return wrapper

    monkeypatch.setattr(sweep_spec, "shown", counted("shown", sweep_spec.shown, 3))
    monkeypatch.setattr(sweep_spec, "_rel", counted("rel", sweep_spec._rel, 3))
    monkeypatch.setattr(sweep_spec, "Variant", counted("made", sweep_spec.Variant, 10))
    monkeypatch.chdir(tmp_path)
    spec = load_spec("spec.toml")
    assert len(spec.variants) == MAX_VARIANTS
    assert counts == {"shown": 1, "rel": 3, "made": 0}  # the paths once, for the one run
    first = list(itertools.islice(iter(spec.variants), 5))
    assert counts["made"] == 5  # the first five, the rest not made
    ids = list(itertools.islice(spec.variants.ids(), 5))
    assert [v.id for v in first] == ids == sorted(ids)
    assert spec.variants.find(ids[3]) == first[3] and spec.variants.find("0" * 12) is None
    last = spec.variants[-1]
    assert last.id > ids[-1] and last.command().startswith("ncgate sim OK.nc --set ")
    assert counts["made"] == 7


def test_each_variant_is_what_its_id_and_command_say(monkeypatch: pytest.MonkeyPatch,
                                                      tmp_path: Path) -> None:
    """The ids and rows of variants made lazily are those made one by one from the spec:
    the id hashes the same JSON, the command names the same files."""
    for name in ("A.nc", "B.nc"):
        (tmp_path / "progs").mkdir(exist_ok=True)
        (tmp_path / "progs" / name).write_text(LOOPS["OK"])
    for name in ("one.toml", "two.toml"):
        (tmp_path / name).write_text('[[write]]\nat = 0.5\nset = "SA10=1"\n')
    (tmp_path / "spec.toml").write_text(
        '[sweep]\nprograms = ["progs/*.nc"]\nscript = ["one.toml", "two.toml"]\n'
        'examples = ["scheme3"]\n[grid]\n"nc.snd" = ["rendezvous", "latched"]\n'
        '"nc.lookahead" = [0, 4]\n[random]\nseed = 3\nsamples = 3\n'
        '"nc.feed_override" = [50, 150]\n"nc.block_time_ms" = [0.0, 20.0]\n')
    monkeypatch.chdir(tmp_path)
    spec = load_spec("spec.toml")
    variants = list(spec.variants)
    assert len(variants) > 2 * 2 * 2 * 3 and [v.id for v in variants] == sorted(
        v.id for v in variants)
    for v in variants:
        identity = {"program": sweep_spec._rel(Path(v.program), tmp_path),
                    "config": None if v.config is None else sweep_spec._rel(Path(v.config),
                                                                           tmp_path),
                    "script": None if v.script is None else sweep_spec._rel(Path(v.script),
                                                                           tmp_path),
                    "until": None, "sets": v.sets, "budget_s": 3600.0}
        assert v.id == variant_id(identity)
        words = shlex.split(v.command())
        assert words[:3] == ["ncgate", "sim", v.program if v.config is None else v.main]
        assert [k for k, _ in v.sets] == spec.keys
        assert spec.variants.find(v.id) == v


# -- --explore's reduction says what it does ---------------------------------------------


def test_explore_does_not_reduce_a_wall_timeout(tmp_path: Path) -> None:
    (tmp_path / "SPIN.nc").write_text(LOOPS["SPIN"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["SPIN.nc"]\n[explore]\n'
                                        '"nc.feed_override" = [50, 150]\n')
    done = ncgate("sweep", "spec.toml", "--explore", "2", "--workers", "1", "--timeout",
                  "0.1", cwd=tmp_path)
    assert done.returncode == 1, done.stderr
    # (A run that reaches the runaway-loop alarm within the 0.1 s is an alarm row instead.)
    walls = [r for r in rows_of(tmp_path / "spec-explore.csv")
             if r["signature"] == "timeout wall"]
    assert walls, done.stdout
    first = min(walls, key=lambda r: r["id"])
    assert ("smallest reproducer: not looked for (a wall timeout: each try could take the "
            f"--timeout); the variant: {first['command']}") in done.stdout, done.stdout
    assert f"reducing {first['id']}" not in done.stderr, done.stderr


def test_explore_says_each_reduction_step_and_a_step_past_the_timeout(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        tmp_path: Path) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [80]\n"plc.scan_ms" = [7]\n')
    monkeypatch.chdir(tmp_path)
    variant = load_spec("spec.toml").variants[0]
    tried = []

    def runner(fewer: sweep_spec.Variant, timeout_s: float | None) -> sweep_run.Result:
        tried.append((fewer.sets, timeout_s))
        if len(tried) == 1:  # without the feed override: it hangs
            return sweep_run._result("timeout", signature="timeout wall")
        return sweep_run._result("stall", signature="stall P1")  # without the scan: still

    monkeypatch.setattr(sweep_run, "run_variant", runner)
    smallest = sweep_main.reduce(variant, "stall", "stall P1", 0.25)
    assert smallest.sets == (("nc.feed_override", 80),)
    assert [t for _, t in tried] == [0.25, 0.25]
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"reducing {variant.id}: trying nc.feed_override at its default, not 80 (1 of 2)...",
        f"reducing {variant.id}: nc.feed_override at its default ran past the --timeout of "
        "0.25 s: nc.feed_override kept",
        f"reducing {variant.id}: trying plc.scan_ms at its default, not 7 (2 of 2)..."], err
    # -q: no "trying" lines (the progress line's kind), the kept key still said
    tried.clear()
    assert sweep_main.reduce(variant, "stall", "stall P1", 0.25, said=False) == smallest
    assert capsys.readouterr().err.splitlines() == [
        f"reducing {variant.id}: nc.feed_override at its default ran past the --timeout of "
        "0.25 s: nc.feed_override kept"]
