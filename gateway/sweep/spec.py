"""A sweep's spec (``ncgate sweep SPEC.toml``): what to run, as a list of variants.

```toml
[sweep]
programs = ["progs/*.nc"]          # main programs (globs, relative to this file)
examples = ["scheme3", "hazard"]   # and/or installed examples ("*": every runnable one)
config = "cell.toml"               # default: ncgate.toml beside each program, else built-in
script = "plc.toml"                # or a list of globs: each script is a variant of its own
until = 60.0                       # stop each run here (as sim --until)
budget_s = 3600.0                  # no until: virtual time a variant may run (then: timeout)

[grid]                             # every combination of these values
"nc.snd" = ["rendezvous", "latched"]
"nc.lookahead" = [0, 4, 16]

[random]                           # and this many seeded samples of these ranges each
seed = 1
samples = 10
"nc.feed_override" = [50, 150]     # integers: an integer in the range; floats: a float

[explore]                          # --explore N: N seeded samples of these instead of the
seed = 0                           # grid and random ones (default: EXPLORE_RANGES)
"nc.feed_override" = [50, 150]
"sim.input_delay_scale" = [0.5, 2.0]
```

Every variant is a plain ``ncgate sim`` run: its row's ``command`` repeats it.  Its id is a
hash of its resolved inputs (the files' paths relative to the spec, the values), so the
same spec gives the same ids wherever it runs.  Errors name the spec file and the dotted key.
"""

from __future__ import annotations

import array
import bisect
import contextlib
import glob
import hashlib
import itertools
import json
import math
import os
import random
import shlex
import tomllib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

from ncgate.config import ConfigError, load_config
from ncgate.config.reader import read_toml

Value = bool | int | float | str
SWEEP_KEYS = ("programs", "examples", "config", "script", "until", "budget_s")
DEFAULT_BUDGET_S = 3600.0
# What --explore varies by default: when each process's motion ends (the feed override),
# how long each block takes, when the PLC logic sees a change (its scan period), and when the
# scripted PLC answers (its times scaled, and jittered by draws from a seed).
EXPLORE_RANGES: dict[str, list[Value]] = {
    "nc.feed_override": [50, 150], "nc.block_time_ms": [0.0, 20.0], "plc.scan_ms": [1, 50],
    "sim.input_delay_scale": [0.5, 2.0], "sim.input_jitter_ms": [0.0, 100.0],
    "sim.seed": [0, 1_000_000]}
# Hex digits of the sha-256: 48 bits.  Two of n distinct variants share an id with a chance
# of about n ** 2 / 2 ** 49: 1 in 56,000 for 100,000 variants, 1 in 560 for 1,000,000.  A
# sweep refuses such a pair when it takes the second one (main.py: the rows are by id).
ID_LENGTH = 12
# The most variants a spec may give (programs x scripts x grid x samples): counted before any
# is made, so that a grid of 20 ** 8 combinations is a spec error, not a MemoryError.
MAX_VARIANTS = 1_000_000
BOM = b"\xef\xbb\xbf"


class SpecError(ConfigError):
    """A spec that cannot be run: the message names the file and the dotted key."""


@dataclass(frozen=True, slots=True)
class Variant:
    """One ``ncgate sim`` run of a sweep."""

    id: str
    program: str  # the main program's file, as shown (relative to the working folder)
    main: str  # the name run_sim starts (with a config: the program's name on its storage)
    config: str | None  # the config file (None: the built-in one, MP0 = the program's folder)
    script: str | None
    until: float | None
    sets: tuple[tuple[str, Value], ...]  # the swept keys and their values, in column order
    budget_s: float = DEFAULT_BUDGET_S
    storage: str | None = None  # without a config: the program's folder, as MP0
    # What the run reads: the config and script as absolute paths.  ``config`` and ``script``
    # are as shown, relative to the client's working folder, which a Dask worker's is not.
    config_file: str | None = None
    script_file: str | None = None

    def set_args(self) -> list[str]:
        return [f"{key}={render_value(value)}" for key, value in self.sets]

    def overrides(self) -> dict[str, Any]:
        """The config overrides, parsed back from ``--set`` text exactly as ``sim`` does."""
        out = {key: parse_value(text) for key, _, text in
               (item.partition("=") for item in self.set_args())}
        if self.storage is not None:
            out["nc.storage.MP0"] = self.storage
        return out

    def command(self) -> str:
        """The ``ncgate sim`` command line that runs this variant alone."""
        words = ["ncgate", "sim", self.program if self.config is None else self.main]
        if self.config is not None:
            words += ["--config", self.config]
        if self.script is not None:
            words += ["--script", self.script]
        if self.until is not None:
            words += ["--until", render_value(self.until)]
        for item in self.set_args():
            words += ["--set", item]
        return shlex.join(words)


@dataclass
class Spec:
    file: Path
    variants: Variants  # made as taken: in the spec's order, or sorted by id
    keys: list[str]  # the swept keys, one column each
    fingerprint: str  # the spec and the files it names: a resumed sweep must match it
    seed: int | None = None
    files: list[Path] = field(default_factory=list)
    draws: tuple[int, int] | None = None  # random draws made, and the distinct ones kept
    explore: int | None = None  # --explore N's N
    digests: dict[str, str] = field(default_factory=dict)  # each file's: what --resume names


def render_value(value: Value) -> str:
    """A value as ``--set`` text that ``parse_value`` reads back to the same value."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value) if isinstance(value, float) else str(value)
    try:
        same = parse_value(value) == value
    except ValueError:
        same = False
    return value if same and value.strip() == value and value else json.dumps(value)


def parse_value(text: str) -> Any:
    """``--set``'s reading of a value (gateway/cli): TOML, and a bare word is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def shown(path: Path) -> str:
    """A path as rows show it: relative to the working folder when it is inside it."""
    try:
        return path.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return str(path.resolve())


def variant_id(identity: dict[str, Any]) -> str:
    text = json.dumps(identity, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:ID_LENGTH]


def load_spec(path: str | Path, explore: int | None = None) -> Spec:
    """The spec's variants; with ``explore``, that many seeded samples of its [explore]
    ranges per program and script instead of its [grid] and [random]."""
    file = Path(path)
    raw = _read_spec(file)
    where = str(file)

    def fail(key: str, message: str) -> SpecError:
        return SpecError(f"{where}: {key}: {message}")

    for name in raw:
        if name not in ("sweep", "grid", "random", "explore"):
            raise fail(name, "unknown key (expected [sweep], [grid], [random] or [explore])")
    sweep = _table(raw, "sweep", fail)
    for name in sweep:
        if name not in SWEEP_KEYS:
            raise fail(f"sweep.{name}", f"unknown key (expected {', '.join(SWEEP_KEYS)})")
    base = file.parent
    until = _number(sweep, "until", fail, None)
    budget = _number(sweep, "budget_s", fail, DEFAULT_BUDGET_S)
    assert budget is not None
    if until is not None and until < 0:
        raise fail("sweep.until", f"expected a time >= 0, got {until}")
    if not budget > 0:
        raise fail("sweep.budget_s", f"expected a time > 0, got {budget}")
    config = sweep.get("config")
    if config is not None and not isinstance(config, str):
        raise fail("sweep.config", "expected a file name")
    config_path = None
    if config is not None:
        config_path = base / config
        if not config_path.is_file():
            raise fail("sweep.config", f"{config}: no such file")
    scripts = _files(sweep, "script", base, fail) if "script" in sweep else [None]
    runs = _programs(sweep, base, config_path, scripts, fail)
    if not runs:
        raise fail("sweep.programs", "no program to run (give programs or examples)")
    grid = _flat(_table(raw, "grid", fail), "grid", fail)
    rand = _flat(_table(raw, "random", fail), "random", fail)
    table = _flat(_table(raw, "explore", fail), "explore", fail)
    if "samples" in table:  # N is the command line's: --explore N
        raise fail("explore.samples", "unknown key: the number of samples is --explore N's "
                   "(expected seed and key = [low, high])")
    if explore is not None:
        ranges = {k: v for k, v in table.items() if k != "seed"} or EXPLORE_RANGES
        grid = {}
        rand = {"seed": table.get("seed", 0), "samples": explore, **ranges}
        fail_ = fail

        def fail(key: str, message: str) -> SpecError:
            return fail_(key.replace("random", "explore", 1), message)
    lists, keys = _grid(grid, fail)
    draws, seed, random_keys = _random(rand, fail, set(keys))
    _check_values(runs, grid, rand, where, "random" if explore is None else "explore")
    count = len(runs) * math.prod(len(v) for v in lists) * max(1, draws)
    if count > MAX_VARIANTS:
        raise fail("sweep", f"{count:,} variants (programs x scripts x [grid] x samples): "
                   f"more than the {MAX_VARIANTS:,} a sweep may run; split the spec")
    samples = _draw(rand, seed, draws)
    keys += random_keys
    files: set[Path] = {file.resolve()}
    for run in runs:
        files.update(p.resolve() for p in run.files)
    files.update(_inputs(runs))
    variants = Variants(runs, base, until, budget, grid_keys=keys[:len(lists)], lists=lists,
                        samples=samples)
    dup = variants.duplicate()
    if dup is not None:
        raise fail("sweep", f"two variants are the same run (id {dup}): a program, script "
                   "or value is given twice")
    digest = hashlib.sha256()
    each: dict[str, str] = {}
    for f in sorted(files):
        data = f.read_bytes()
        digest.update(str(f).encode() + b"\0" + data + b"\0")
        each[str(f)] = hashlib.sha256(data).hexdigest()
    return Spec(file, variants, keys, digest.hexdigest(), seed,
                sorted(files), (draws, len(samples)) if draws else None, explore, each)


class Variants(Sequence[Variant]):
    """A spec's variants, each made when it is taken.

    What is the same for every variant of a run -- its files' paths as shown, as hashed and
    as read -- is worked out once per run, and each swept value's JSON once per value: a
    variant's own work, when it is taken, is its id's hash and one small object.  Nothing
    is hashed here: a spec of 1,000,000 variants is ready once it is counted.

    Two orders.  ``in_spec_order()`` streams the variants in the spec's order (run, then
    grid combination, then sample), each id hashed as the variant is taken: what a sweep
    runs.  As a sequence (index, iteration, ``ids()``, ``find()``) they are sorted by id,
    the table's order: that needs every id, so the first such use hashes them all and keeps
    them sorted (two arrays of numbers, seconds for a million)."""

    def __init__(self, runs: Sequence[_Run], base: Path, until: float | None, budget: float,
                 grid_keys: Sequence[str], lists: Sequence[Sequence[Value]],
                 samples: Sequence[dict[str, Value]]) -> None:
        self._runs = [_Shown.of(run, base, until, budget) for run in runs]
        self._until = until
        self._budget = budget
        self._grid = [[(key, v) for v in values] for key, values in zip(grid_keys, lists,
                                                                         strict=True)]
        self._samples = [tuple(s.items()) for s in samples]
        self._per_run = math.prod(len(v) for v in lists) * max(1, len(samples))
        self._count = len(self._runs) * self._per_run
        # Sorted by id, made on the first use as a sequence: the ids as 48-bit numbers, and
        # each one's place in the spec's order.
        self._sorted: tuple[array.array[int], array.array[int]] | None = None

    def _numbers(self, first_run: int = 0) -> Iterator[int]:
        """Each variant's id, as a number, in the spec's order from the run ``first_run``:
        the JSON ``variant_id`` hashes, put together from its parts (the same bytes as
        ``json.dumps``)."""
        pieces = [[_json([k, v]) for k, v in values] for values in self._grid]
        tails: list[str | None] = [",".join(_json([k, v]) for k, v in s)
                                   for s in self._samples] or [None]
        sha = hashlib.sha256
        for run in self._runs[first_run:]:
            head, end = run.json_head, run.json_end
            for combo in itertools.product(*pieces):
                sets = ",".join(combo)
                for tail in tails:
                    text = sets if tail is None else (f"{sets},{tail}" if sets else tail)
                    digest = sha(f"{head}{text}{end}".encode()).digest()
                    yield int.from_bytes(digest[:ID_LENGTH // 2], "big")

    def duplicate(self) -> str | None:
        """An id two variants have because the spec gives one run twice (a program matched
        by two globs), else None -- the id of that run's first variant.

        Told by the runs alone, no id hashed: two variants are the same run exactly when
        their runs' files and their swept values are.  Within one run the values of two
        variants always differ: a [grid] list may not give a value twice, a key is swept
        once (by [grid] or by [random]), and a repeated draw is left out.  So a run is
        given twice exactly when two runs have the same files as the id sees them."""
        seen: set[tuple[str, str]] = set()
        for i, run in enumerate(self._runs):
            if (run.json_head, run.json_end) in seen:
                number = next(self._numbers(i))
                return f"{number:0{ID_LENGTH}x}"
            seen.add((run.json_head, run.json_end))
        return None

    def in_spec_order(self) -> Iterator[Variant]:
        """Every variant in the spec's order, its id hashed as it is taken."""
        return (self._make(place, number) for place, number in enumerate(self._numbers()))

    def _index(self) -> tuple[array.array[int], array.array[int]]:
        if self._sorted is None:
            found = [(number << 20) | place for place, number in enumerate(self._numbers())]
            found.sort()
            self._sorted = (array.array("Q", (f >> 20 for f in found)),
                            array.array("L", (f & 0xFFFFF for f in found)))
        return self._sorted

    def __len__(self) -> int:
        return self._count

    @overload
    def __getitem__(self, index: int) -> Variant: ...

    @overload
    def __getitem__(self, index: slice) -> list[Variant]: ...

    def __getitem__(self, index: int | slice) -> Variant | list[Variant]:
        if isinstance(index, slice):
            return [self._sorted_at(i) for i in range(*index.indices(len(self)))]
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError("variant index out of range")
        return self._sorted_at(index)

    def __iter__(self) -> Iterator[Variant]:
        return (self._sorted_at(i) for i in range(len(self)))

    def ids(self) -> Iterator[str]:
        """The ids, sorted, without making the variants."""
        return (f"{number:0{ID_LENGTH}x}" for number in self._index()[0])

    def find(self, id: str) -> Variant | None:
        """The variant of this id, or None."""
        try:
            number = int(id, 16)
        except ValueError:
            return None
        ids, _ = self._index()
        i = bisect.bisect_left(ids, number)
        if len(id) != ID_LENGTH or i == len(self) or ids[i] != number:
            return None
        return self._sorted_at(i)

    def _sorted_at(self, index: int) -> Variant:
        ids, order = self._index()
        return self._make(order[index], ids[index])

    def _make(self, place: int, number: int) -> Variant:
        """The variant at ``place`` in the spec's order, whose id is ``number``."""
        run = self._runs[place // self._per_run]
        rest = place % self._per_run
        if self._samples:
            rest, sample = divmod(rest, len(self._samples))
        sets: list[tuple[str, Value]] = []
        for values in reversed(self._grid):  # the last key varies fastest (itertools.product)
            rest, i = divmod(rest, len(values))
            sets.append(values[i])
        sets.reverse()
        if self._samples:
            sets += self._samples[sample]
        return Variant(f"{number:0{ID_LENGTH}x}", run.program, run.main, run.config,
                       run.script, self._until, tuple(sets), self._budget, run.storage,
                       run.config_file, run.script_file)


def _json(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"))


@dataclass(frozen=True, slots=True)
class _Shown:
    """What each variant of a run shares: its files as rows show them, as ``ncgate sim``
    reads them, and its part of the id's JSON (all but the swept values)."""

    program: str
    main: str
    config: str | None
    script: str | None
    storage: str | None
    config_file: str | None
    script_file: str | None
    json_head: str
    json_end: str

    @classmethod
    def of(cls, run: _Run, base: Path, until: float | None, budget: float) -> _Shown:
        identity: dict[str, Any] = {
            "program": _rel(run.program, base), "config": _rel(run.config, base),
            "script": _rel(run.script, base), "until": until, "sets": [],
                    "budget_s": budget if until is None else None}
        text = json.dumps(identity, sort_keys=True, separators=(",", ":"))
        head, _, end = text.partition('"sets":[]')
        return cls(shown(run.program), run.main,
                   None if run.config is None else shown(run.config),
                   None if run.script is None else shown(run.script),
                   None if run.config is not None else str(run.program.parent.resolve()),
                   None if run.config is None else str(run.config.resolve()),
                   None if run.script is None else str(run.script.resolve()),
                   head + '"sets":[', "]" + end)


def _read_spec(file: Path) -> dict[str, Any]:
    """The spec's TOML; a UTF-8 byte-order mark (some Windows editors write one) is skipped."""
    try:
        with file.open("rb") as raw:
            bom = raw.read(len(BOM)) == BOM
    except OSError:
        bom = False
    if not bom:
        return read_toml(file)
    try:
        return tomllib.loads(file.read_text(encoding="utf-8-sig"))
    except UnicodeDecodeError as exc:
        raise SpecError(f"{file}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{file}: {exc}") from None


def _inputs(runs: Sequence[_Run]) -> set[Path]:
    """What a variant's run can read besides its program, config and script: every program
    file on the config's storage devices (a subprogram it calls, MP0..MP3), the PLC logic,
    the plant logic and the symbols file.  A resumed sweep must find them unchanged."""
    from ncgate.interpreter.storage import PROGRAM_SUFFIXES

    out: set[Path] = set()
    for config, storage in sorted({(r.config, r.storage) for r in runs}, key=str):
        overrides = {} if storage is None else {"nc.storage.MP0": str(storage)}
        loaded = load_config(config, overrides=overrides, serving=False)
        for folder in loaded.nc.storage.devices.values():
            try:
                entries = list(Path(folder).iterdir())
            except OSError:
                continue
            out.update(e.resolve() for e in entries
                       if not e.name.startswith(".") and e.suffix.lower() in PROGRAM_SUFFIXES
                       and e.is_file())
        logic = (*loaded.plc.logic, *loaded.plant.logic, loaded.symbols_file)
        out.update(Path(f).resolve() for f in logic if f is not None and Path(f).is_file())
    return out


# -- the parts of a spec -------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Run:
    program: Path
    main: str
    config: Path | None
    script: Path | None
    files: tuple[Path, ...]

    @property
    def storage(self) -> Path | None:
        """Without a config: the program's folder, as MP0 of the built-in config."""
        return self.program.parent.resolve() if self.config is None else None


def _table(raw: dict[str, Any], key: str, fail: Any) -> dict[str, Any]:
    table = raw.get(key, {})
    if not isinstance(table, dict):
        raise fail(key, "expected a table")
    return table


def _number(table: dict[str, Any], key: str, fail: Any, default: float | None) -> float | None:
    value = table.get(key, default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise fail(f"sweep.{key}", f"expected a number of seconds, got {value!r}")
    return float(value)


def _strings(table: dict[str, Any], key: str, fail: Any) -> list[str]:
    value = table.get(key, [])
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise fail(f"sweep.{key}", "expected a list of names or globs")
    return value


def _files(table: dict[str, Any], key: str, base: Path, fail: Any) -> list[Path | None]:
    out: list[Path | None] = []
    for pattern in _strings(table, key, fail):
        found = sorted(glob.glob(str(base / pattern), recursive=True))
        if not found:
            raise fail(f"sweep.{key}", f"{pattern}: no such file")
        out += [Path(f) for f in found]
    return out


def _programs(sweep: dict[str, Any], base: Path, config: Path | None,
              scripts: Sequence[Path | None], fail: Any) -> list[_Run]:
    from ncgate.gateway.examples import examples
    from ncgate.gateway.programs import storage_of

    runs: list[_Run] = []
    for found in _files(sweep, "programs", base, fail):
        assert found is not None
        if not found.is_file():
            raise fail("sweep.programs", f"{found}: not a program file")
        own = config
        if own is None and (found.parent / "ncgate.toml").is_file():
            own = found.parent / "ncgate.toml"
        main = found.stem
        if own is not None:
            loaded = load_config(own, serving=False)
            on_storage = storage_of(loaded).find(main)
            if on_storage is None or on_storage.resolve() != found.resolve():
                raise fail("sweep.programs", f"{found}: not the program {main} of the config "
                           f"{own} (its storage devices hold "
                           f"{'another' if on_storage else 'no'} {main})")
        for script in scripts:
            extra = tuple(p for p in (own, script) if p is not None)
            runs.append(_Run(found, main, own, script, (found, *extra)))
    names = _strings(sweep, "examples", fail)
    if names:
        known = {e.name: e for e in examples() if e.main is not None}
        chosen = sorted(known) if "*" in names else names
        for name in chosen:
            if name not in known:
                raise fail("sweep.examples", f"no runnable example {name!r} (there are: "
                           f"{', '.join(sorted(known))})")
            example = known[name]
            loaded = load_config(example.config, serving=False)
            program = storage_of(loaded).find(example.main or "")
            assert program is not None
            suite: list[Path | None] = list(example.scripts) or [None]
            for script in suite:
                extra = tuple(p for p in (example.config, script) if p is not None)
                runs.append(_Run(program, example.main or "", example.config, script,
                                 (program, *extra)))
    return runs


def _flat(table: dict[str, Any], section: str, fail: Any, prefix: str = "") -> dict[str, Any]:
    """A table's dotted keys as written, quoted (``"nc.snd" = ...``) or not (``nc.snd = ...``,
    which TOML reads as nested tables).  One key in both forms is two keys to TOML, and one
    here: it is the spec's error, as a value given twice is (the later one won, unsaid)."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        found = (_flat(value, section, fail, f"{prefix}{key}.") if isinstance(value, dict)
                 else {f"{prefix}{key}": value})
        for name, item in found.items():
            if name in out:
                raise fail(f"{section}.{name}", "the key is given twice (quoted and dotted: "
                           f'"{name}" and {name}); give it once')
            out[name] = item
    return out


def _grid(grid: dict[str, Any], fail: Any) -> tuple[list[list[Value]], list[str]]:
    """Each swept key's values (checked), and the keys: their product is made only once the
    count is known to be in bounds."""
    keys = []
    lists = []
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise fail(f"grid.{key}", "expected a non-empty list of values")
        for v in values:
            if not isinstance(v, bool | int | float | str):
                raise fail(f"grid.{key}", f"expected numbers, strings or booleans, got {v!r}")
        if len({_same(v) for v in values}) != len(values):
            raise fail(f"grid.{key}", "a value is given twice")
        keys.append(key)
        lists.append(values)
    return lists, keys


def _same(value: Value) -> tuple[str, Any]:
    """What tells two of a key's values apart: a number by its value (``1`` and ``1.0`` are
    one value, given twice: they ran twice), a boolean or a string by itself."""
    if isinstance(value, bool):
        return "bool", value
    if isinstance(value, int | float):
        return ("number", value) if value == value else ("nan", None)
    return "text", value


def _random(table: dict[str, Any], fail: Any,
            taken: set[str]) -> tuple[int, int | None, list[str]]:
    """The number of draws, the seed and the sampled keys (the ranges checked)."""
    if not table:
        return 0, None, []
    seed = table.get("seed", 0)
    samples = table.get("samples")
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise fail("random.seed", f"expected an integer, got {seed!r}")
    if isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= 1_000_000:
        raise fail("random.samples", f"expected an integer 1..1000000, got {samples!r}")
    ranges = {k: v for k, v in table.items() if k not in ("seed", "samples")}
    if not ranges:
        raise fail("random", "no key to sample: give key = [low, high]")
    for key, bounds in ranges.items():
        if key in taken:
            raise fail(f"random.{key}", "swept by [grid] too")
        if (not isinstance(bounds, list) or len(bounds) != 2
                or not all(isinstance(b, int | float) and not isinstance(b, bool)
                           for b in bounds) or not bounds[0] <= bounds[1]):
            raise fail(f"random.{key}", f"expected [low, high] with low <= high, got {bounds!r}")
    return samples, seed, list(ranges)


def _draw(table: dict[str, Any], seed: int | None, draws: int) -> list[dict[str, Value]]:
    """``draws`` seeded samples of the ranges, a draw that repeats an earlier one left out
    (the same run twice: nothing was given twice, the seed drew it again)."""
    ranges = {k: v for k, v in table.items() if k not in ("seed", "samples")}
    rng = random.Random(seed)
    out = []
    seen = set()
    for _ in range(draws):
        sample: dict[str, Value] = {}
        for key, (low, high) in ranges.items():  # in the spec's order: the same draws
            if isinstance(low, int) and isinstance(high, int):
                sample[key] = rng.randint(low, high)
            else:
                sample[key] = round(rng.uniform(float(low), float(high)), 6)
        text = json.dumps(sample, sort_keys=True)
        if text not in seen:
            seen.add(text)
            out.append(sample)
    return out


def _check_values(runs: Sequence[_Run], grid: dict[str, Any], rand: dict[str, Any],
                  where: str, sampled: str) -> None:
    """Every swept value on every config the spec names: a value the config refuses is the
    spec's error (exit 2), not a row."""
    configs = {r.config for r in runs}
    values: list[tuple[str, str, Value]] = [("grid", k, v) for k, vs in grid.items() for v in vs]
    values += [(sampled, k, b) for k, bs in rand.items() if k not in ("seed", "samples")
               for b in bs]
    for config in sorted(configs, key=lambda c: str(c)):
        for section, key, value in values:
            try:
                load_config(config, overrides={key: parse_value(render_value(value))},
                            origins={key: f"{where}: [{section}]"}, serving=False)
            except ConfigError as exc:
                raise SpecError(str(exc)) from None


def _rel(path: Path | None, base: Path) -> str | None:
    """A path as a variant's id hashes it: relative to the spec's folder, or -- for a file of
    an installed example -- to the examples' folder (``examples:scheme3/PROG91.nc``), so an
    example's variant has the same id wherever the spec and ncgate are."""
    if path is None:
        return None
    from ncgate.gateway.examples import examples_folder

    resolved = path.resolve()
    with contextlib.suppress(ValueError):
        return f"examples:{resolved.relative_to(examples_folder().resolve()).as_posix()}"
    return Path(os.path.relpath(resolved, base.resolve())).as_posix()
