"""The PLC logic in the gateway: loading ``[plc] logic``, the NC port the scan acts through,
and the scan on the engine's clock.

The scan is an engine timer every ``plc.scan_ms`` of machine time: on the virtual clock in
``sim`` (deterministic: the same scans at the same instants every run) and on the wall clock
in ``run`` (the wall-clock driver fires engine timers on the asyncio loop).  Scan k is due at
``t0 + k * period``, whatever the scans before it cost, so the scan never drifts; when the
loop comes late past a whole period the missed scans are skipped and counted as overruns.

``nc.stall_s`` with PLC logic (spec 2.3): the scan is not pending work.  In ``sim`` the scan
stops rescheduling itself once every process with a program has waited (or stood held: a
closed simulation has no operator, ``Engine.stalled``) ``stall_s`` with no change (no state
change, no image write) and no other timer is pending, and the run ends as a stall; in
``run`` the wall-clock driver reports the stall on the same rule (waits only).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import gc
import logging
import math
import sqlite3
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ncgate.config import Config, ConfigError
from ncgate.config.state import state_folder
from ncgate.errors import InputRefused, Reason
from ncgate.gateway.door import Door
from ncgate.gateway.wiring import Runtime
from ncgate.inputs import (
    Command,
    CommandKind,
    FieldbusAlarm,
    Override,
    Snd,
    Source,
    SourceKind,
    Var,
    Write,
    var_name,
)
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import Engine, ProcessState
from ncgate.interpreter.engine.events import PlcReload
from ncgate.interpreter.engine.states import WAITING_STATES
from ncgate.interpreter.engine.timers import NS_PER_S, Timer, due_time, grid_index
from ncgate.plc.retain import RetainStore, default_path
from ncgate.plc.scan import NcSnapshot, PlcRuntime, PlcState, PlcStatus
from ncgate.plc.st.diagnostics import LogicError, StCode, StDiagnostic
from ncgate.plc.st.logic import Logic

if TYPE_CHECKING:
    from ncgate.plc.st.compiler import Context
    from ncgate.plc.st.nodes import SourceFile

# The Structured Text toolchain (its parser, its compiler, PLCopen's reader: 10 MB resident)
# is imported by the functions that read and compile logic, when a cell has some: `run` of a
# cell without PLC logic never loads it (bench/modbus.py 3.).

log = logging.getLogger("ncgate.plc")

# The PLC status block of the fieldbus maps (Modbus input registers, CANopen 0x2700).
PLC_REGISTERS = ("state (0 stopped, 1 running, 2 fault)", "scans (hi)", "scans (lo)",
                 "last scan µs (hi)", "last scan µs (lo)", "max scan µs (hi)",
                 "max scan µs (lo)", "overruns (hi)", "overruns (lo)",
                 "fault source line (0: none)", "last scan lateness µs (hi)",
                 "last scan lateness µs (lo)", "max scan lateness µs (hi)",
                 "max scan lateness µs (lo)")


def logic_context(config: Config) -> Context:
    from ncgate.plc.st.compiler import Context

    plc, nc = config.plc, config.nc
    return Context(plc.sa_bits, plc.k_bytes, plc.syvars, nc.processes, nc.external,
                   tuple(config.symbols.items()), plc.strict)


Sources = dict[str, str]  # a logic file's path -> its content (plcopen.read_logic_text)
# The key (no path is empty) of a reload's sources when the files could not be read: its
# value is the error, which the session record carries and its replay reports again.
UNREAD = ""


FileStat = tuple[int, int, int] | None  # mtime (ns), size, inode; None: no such file


def file_stat(path: Path) -> FileStat:
    try:
        st = path.stat()
    except OSError:  # being replaced (an editor's rename), or gone
        return None
    return (st.st_mtime_ns, st.st_size, st.st_ino)


# run --watch's baseline: each logic file as it stood just BEFORE the PLC last read it.  A
# save made while the files were being read and compiled is then a change the watcher sees
# (its own first look, after the read, would take that save as the baseline and miss it).
_stat_when_read: dict[Path, FileStat] = {}


def read_sources(files: tuple[Path, ...], config: Config | None = None,
                 section: str = "plc") -> Sources:
    """The content of every logic file, as the PLC loads it and a session record keeps it.
    With ``config``, a file that cannot be read is a ConfigError naming ``section.logic``
    (the config checked that each is a file; reading it may still fail: its permissions)."""
    from ncgate.plc.st.plcopen import read_logic_text

    out: Sources = {}
    for i, path in enumerate(files):
        try:
            _stat_when_read[path.absolute()] = file_stat(path)
            out[str(path)] = read_logic_text(path)
        except OSError as exc:
            if config is None:
                raise
            raise ConfigError(f"{config.source or '<config>'}: "
                              f"{logic_key(section, i, len(files))}: cannot read {path}: "
                              f"{exc.strerror or exc}") from None
    return out


def logic_key(section: str, i: int, count: int) -> str:
    """The config key of the ``i``-th of ``count`` files of ``section.logic``."""
    return f"{section}.logic" + (f"[{i}]" if count > 1 else "")


def parsed_logic(path: str, text: str) -> SourceFile:
    """A logic file's syntax tree, kept for the same path and text when the file is small
    (PARSE_KEPT_MAX characters): a suite of scenarios (or a sweep) runs the same logic again
    and again, and its parse is two thirds of starting it (the machine example: 11 ms of 16).
    The tree is immutable (frozen nodes), so a runtime that compiles it shares nothing that
    changes; a file that does not parse is not kept.  A big file's tree is not kept: the
    cyclic collector would walk its nodes on every collection (docs/decisions.md)."""
    if len(text) > PARSE_KEPT_MAX:
        from ncgate.plc.st.plcopen import logic_from_text

        return logic_from_text(path, text)
    return _kept_parse(path, text)


PARSE_KEPT_MAX = 32 * 1024


@functools.lru_cache(maxsize=16)
def _kept_parse(path: str, text: str) -> SourceFile:
    from ncgate.plc.st.plcopen import logic_from_text

    return logic_from_text(path, text)


def load_logic(files: tuple[Path, ...], config: Config,
               sources: Sources | None = None, section: str = "plc", *,
               warn: bool = True) -> Logic:
    """Parse and check every file (Structured Text, or PLCopen XML by its .xml suffix) --
    from ``sources`` when given (a replay runs the logic its record carries); raises
    LogicError with all the diagnostics.  ``section``: ``plant`` warns of its RETAIN
    (SW005).  ``warn``: log the warnings (a scenario suite loads the same logic for each
    scenario, and says them with its first only)."""
    from ncgate.plc.st.compiler import compile_logic
    from ncgate.plc.st.plcopen import read_logic_file

    parsed = ([read_logic_file(path) for path in files] if sources is None else
              [parsed_logic(path, text) for path, text in sources.items()])
    logic = compile_logic(parsed, logic_context(config))
    if not warn:
        return logic
    for warning in (*logic.warnings,  # plc.strict = false: what IEC would refuse
                    *(retain_in_plant(parsed) if section == "plant" else ())):
        log.warning("%s", warning.render())
    return logic


def retain_in_plant(files: Sequence[SourceFile]) -> list[StDiagnostic]:
    """SW005 for each ``VAR RETAIN`` of the plant's logic: accepted, and nothing kept."""
    return [StDiagnostic(StCode.RETAIN_IN_PLANT, f"{decl.name} is RETAIN: the plant's logic "
                         "keeps nothing across a restart (docs/plant.md)", decl.span,
                         f.line(decl.span.line))
            for f in files for decl in (*f.globals, *(d for pou in f.pous for d in pou.decls))
            if decl.qualifier == "RETAIN"]


def shared_writes(config: Config, plc: Logic | None, plant: Logic | None
                  ) -> list[StDiagnostic]:
    """SW006 for each image variable a logic writes (at a constant place) that another
    writer of the cell writes too: a plant model's output (the model drives what the machine
    does; the logic overwrites it, or it the logic), or the other logic.  Each overwrites the
    other, and the image shows whichever wrote last -- a classic of commissioning, found
    nowhere else (each writer alone is right).  The PLC's logic and the plant's are told
    apart on the plant's side: its line is where the machine builder models the machine."""
    from ncgate.config.plant import MODEL_KEYS
    from ncgate.gateway.wiring import image_var
    from ncgate.plc.st.nodes import Span

    symbols = {name.upper(): image_var(text) for name, text in config.symbols.items()}
    shown = io_namer(config)

    def ran(logic: Logic, section: str) -> dict[tuple[str, int], tuple[str, int, int]]:
        """What the PROGRAMs the section runs write, and what they reach does."""
        try:
            order: list[str] | None = program_order(logic, config, section)
        except ConfigError:  # (said where the config is checked)
            order = None
        return logic.image_writes(order)

    writes = {id(logic): ran(logic, section) for logic, section in ((plc, "plc"),
                                                                       (plant, "plant"))
              if logic is not None}

    def diagnostic(logic: Logic, key: tuple[str, int], message: str) -> StDiagnostic:
        file, line, column = writes[id(logic)][key]
        text = next((f.line(line) for f in logic.files if f.path == file), "")
        return StDiagnostic(StCode.SHARED_OUTPUT, message, Span(file, line, column), text)

    out: list[StDiagnostic] = []
    logics = [logic for logic in (plc, plant) if logic is not None]
    for model in config.plant.model:
        for key, text in model.keys.items():
            if MODEL_KEYS[model.kind][key][0] != "out" or not isinstance(text, str):
                continue
            found = symbols.get(text.strip().upper())
            try:
                var = found if found is not None else image_var(text)
            except (InputRefused, ValueError):
                continue  # (the plant refuses it, naming the key)
            for logic in logics:
                hit = next((k for k in _storage(*var.address) if k in writes[id(logic)]),
                           None)
                if hit is not None:
                    out.append(diagnostic(logic, hit, (
                        f"{shown(*var.address)} is written here and by plant model "
                        f"{model.name} ({key}): each overwrites the other (a model's output "
                        "is the machine's answer: read it, or drop the model)")))
    if plc is not None and plant is not None:
        told: set[tuple[int, int, int]] = set()
        plant_writes, plc_writes = writes[id(plant)], writes[id(plc)]
        for place in sorted(plant_writes.keys() & plc_writes.keys()):
            area, index = place
            where = plant_writes[place]
            at = plc_writes[place]
            if (where[1], at[1], at[2]) in told:
                continue  # (the 8 bits of one byte written by both: said once)
            told.add((where[1], at[1], at[2]))
            out.append(diagnostic(plant, place, (
                f"{shown(area, index, PLACE_VIEW[area])} is written here and by the PLC's "
                f"logic at {at[0]}:{at[1]}:{at[2]}: each overwrites the other (the plant's "
                "logic models the machine: it reads what the PLC writes)")))
    return sorted(out, key=lambda d: (d.span.file, d.span.line, d.span.column))


# The view of the variable a place of Logic.image_writes / image_reads is: ("SA", bit),
# ("SK", byte), ("SYVAR", n).
PLACE_VIEW = {"SA": "bit", "SK": "BY", "SYVAR": "IN"}


def io_namer(config: Config) -> Callable[[str, int, str], str]:
    """A variable's name as a diagnostic or ``ncgate map`` shows it: ``SA30 (clamp_closed)``
    when an I/O name of [symbols] names it, else ``SA30``."""
    from ncgate.gateway.wiring import image_var

    named = {image_var(text).address: name for name, text in config.symbols.items()}

    def shown(area: str, index: int, view: str) -> str:
        name = named.get((area, index, view))
        text = var_name(area, index, view)
        return f"{text} ({name})" if name else text

    return shown


def warn_shared_writes(config: Config, plc: Logic | None, plant: Logic | None) -> None:
    """:func:`shared_writes` in the log, as the logic's other warnings are (load_logic)."""
    for shared in shared_writes(config, plc, plant):
        log.warning("%s", shared.render())


def _storage(area: str, index: int, view: str) -> tuple[tuple[str, int], ...]:
    """The places of a variable as Logic.image_writes names them."""
    if area == "SA":
        if view == "bit":
            return (("SA", index),)
        return tuple(("SA", index * 8 + bit) for bit in range(16 if view == "IN" else 8))
    if area == "SK":
        return (("SK", index), ("SK", index + 1)) if view == "IN" else (("SK", index),)
    return ((area, index),)


def program_order(logic: Logic, config: Config, section: str = "plc") -> list[str]:
    """``plc.programs`` (``section``: ``plant`` for the plant's logic) checked against the
    logic (ConfigError naming the key), or every PROGRAM in file order."""
    programs: tuple[str, ...] = getattr(config, section).programs
    if not programs:
        if not logic.programs:
            where = config.source or "<config>"
            raise ConfigError(f"{where}: {section}.logic: the files hold no PROGRAM to run")
        return list(logic.programs)
    order = []
    for i, name in enumerate(programs):
        if name.upper() not in logic.programs:
            known = ", ".join(logic.display.values()) or "none"
            raise ConfigError(f"{config.source or '<config>'}: {section}.programs[{i}]: no "
                              f"PROGRAM {name} in {section}.logic (PROGRAMs: {known})")
        order.append(name)
    return order


_NO_AUX = (0, False) * 4  # NC.P[k].M, MSTROBE, S, ... without [nc.aux]
# A state's code, whether it is a wait, whether it is IDLE (the snapshot's, every scan).
_STATE_FIELDS = {state: (int(state), state in WAITING_STATES, state is ProcessState.IDLE)
                 for state in ProcessState}


class EngineNc:
    """The scan's view of the engine (:class:`ncgate.plc.scan.NcPort`): it reads the engine,
    and acts on it through the door, attributed ``plc FILE:LINE`` (where the logic set the
    output).

    It acts from inside the scan, an engine timer: at the scan's own time
    (:meth:`Door.apply_on_time`), as the plant's models do.  On the wall clock, bringing the
    engine to now first would stamp an output (an M06's acknowledge, a cycle start) with the
    time the loop got round to the scan, and fire the timers due meanwhile in the middle of
    it: ``run`` and a replay of its session (``sim --replay``) would disagree."""

    def __init__(self, engine: Engine, door: Door, kind: SourceKind = SourceKind.PLC) -> None:
        """``kind``: the source its inputs carry (``plant`` for the plant's logic)."""
        self.engine = engine
        self.door = door
        self.kind = kind
        self._image = door.runtime.image
        # Per process: for M, S, T and H, the key of the value last output, the strobe's
        # byte and its bit's mask.
        self._aux_places: dict[int, tuple[tuple[tuple[int, str], int, int], ...]] = {}

    def snapshot(self) -> list[NcSnapshot]:
        """Each process's status and its auxiliary functions, as the scan reads them (every
        scan: the strobes are read from the image's bytes at places worked out once)."""
        out: list[NcSnapshot] = []
        aux = self.engine.aux
        sa = self._image.sa
        for p in self.engine.processes.values():
            code, waiting, idle = _STATE_FIELDS[p.state]
            _, line, n = p.where
            alarm = p.alarm
            if aux is None:
                out.append((code, n or 0, line, waiting, alarm is not None,
                            alarm[0] if alarm else 0, idle, p.held, *_NO_AUX))
                continue
            places = self._aux_places.get(p.number)
            if places is None:
                places = self._aux_places[p.number] = tuple(
                    (key, strobe >> 3, 1 << (strobe & 7))
                    for key, strobe in aux.snapshot_places(p.number))
            last = aux.last
            (m, mb, mm), (s, sb, sm), (t, tb, tm), (h, hb, hm) = places
            out.append((code, n or 0, line, waiting, alarm is not None,
                        alarm[0] if alarm else 0, idle, p.held,
                        last.get(m, 0), sa[mb] & mm != 0, last.get(s, 0), sa[sb] & sm != 0,
                        last.get(t, 0), sa[tb] & tm != 0, last.get(h, 0), sa[hb] & hm != 0))
        return out

    def events(self) -> int:
        return self.engine.trace.counter

    def last_snd(self) -> tuple[int, int, int]:
        last = self.engine.last_snd
        return (last[0], last[1], self.engine.snd_seq) if last else (0, 0, 0)

    def command(self, word: int, where: str, process: int | None = None) -> None:
        self.door.apply_on_time(Command(CommandKind(word), process, Source(self.kind, where)))

    def override(self, feed: int, where: str, process: int | None = None) -> None:
        self.door.apply_on_time(Override(feed, None, process, Source(self.kind, where)))

    def send(self, sender: int, target: int, where: str) -> None:
        self.door.apply_on_time(Snd(sender, target, Source(self.kind, where)))

    def aux_ack(self, process: int, letter: str, value: bool, where: str) -> None:
        """NC.P[k].MACK ..: a write of the acknowledge's SA bit, through the door."""
        aux = self.engine.aux
        if aux is None:
            raise InputRefused(Reason.NOT_CONFIGURED, "no auxiliary function is output: the "
                               "config has no [nc.aux]")
        ack = aux.settings.place(process, letter)[2]
        self.door.apply_on_time(Write(Var("SA", ack, "bit"), int(value),
                              Source(self.kind, where)))

    def fault(self, message: str) -> None:
        what = "plant logic" if self.kind is SourceKind.PLANT else "PLC"
        self.door.apply_on_time(FieldbusAlarm(AlarmCode.PLC_FAULT, f"{what} fault: {message}",
                                      Source(self.kind)))

    def hazard(self, message: str) -> None:
        self.engine.note_hazard(0, message)


@dataclass(frozen=True, slots=True)
class ReloadOutcome:
    """What an online change did (the console's answer, the trace's ``plc_reload``, the
    log): ``ok`` False with the diagnostics when the logic did not load (the old logic
    runs on); else how many variables kept their value, and the paths that start from their
    initial value (new or retyped) and that are gone."""

    ok: bool
    files: tuple[str, ...]
    diagnostics: tuple[str, ...] = ()
    kept: int = 0
    initial: tuple[str, ...] = ()
    dropped: tuple[str, ...] = ()
    sources: Sources = field(default_factory=dict, repr=False, compare=False)  # (a record's)

    def as_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "files": list(self.files), "kept": self.kept,
                "initial": list(self.initial), "dropped": list(self.dropped),
                "diagnostics": list(self.diagnostics)}


class OnlineChange:
    """Reloads ``[plc] logic`` into the running PLC between two scans: the
    command ``reload_plc`` from any door, and ``run --watch``.

    :meth:`prepare` reads and compiles the files -- slow for a big program, so ``run`` calls
    it in a thread -- and the door's RELOAD_PLC calls the object on the loop, which swaps
    the logic in (:meth:`ncgate.plc.scan.PlcRuntime.reload`) or, when the files did not
    load, leaves the old logic running and reports the diagnostics.

    A session record carries the logic's sources: those running when the record starts and
    those of each reload (:meth:`record_to`), so that its replay runs the logic the session
    ran (``recorded``: the sources of the session's reloads, in order)."""

    def __init__(self, config: Config, runtime: Runtime, plc: PlcRuntime,
                 sources: Sources) -> None:
        self.config = config
        self.runtime = runtime
        self.plc = plc
        self.sources = sources  # of the logic that runs
        self.recorded: list[Sources] | None = None
        self._record: Callable[[Sources, float], None] | None = None
        self._prepared: tuple[Logic, list[str], Sources] | ReloadOutcome | None = None
        self.last: ReloadOutcome | None = None
        self._lock = threading.Lock()

    def record_to(self, record: Callable[[Sources, float], None] | None) -> None:
        """Write the running logic's sources now, and those of every reload from now on,
        with ``record`` (``SessionRecorder.logic``; None: no more)."""
        self._record = record
        if record is not None:
            record(self.sources, self.runtime.engine.now)

    @property
    def files(self) -> tuple[str, ...]:
        return tuple(str(p) for p in self.config.plc.logic)

    def prepare(self) -> None:
        """Read and compile the files now (any thread); the next reload swaps this in.

        The cyclic garbage collector is paused meanwhile: parsing allocates hundreds of
        thousands of objects, and a full collection they trigger runs in this thread
        holding the interpreter's lock -- the loop stood still for it.  Measured on
        ``bench/plc.py``'s 1,000-statement program (a probe task on the loop, 1 ms sleeps,
        three rounds each, alternating): worst loop gap 47..377 ms with the collector, 44..69
        ms without (then Python's own ``compile()``, now done in pieces of ~10 ms: Logic).
        What the parse leaves is freed by reference counting."""
        paused = gc.isenabled()
        gc.disable()
        try:
            prepared = self._compile()
        finally:
            if paused:
                gc.enable()
        with self._lock:
            self._prepared = prepared

    def _compile(self) -> tuple[Logic, list[str], Sources] | ReloadOutcome:
        config = self.config
        sources: Sources = {}
        try:
            if self.recorded is not None:  # a replay: the session's next reload
                sources = self.recorded.pop(0) if self.recorded else self.sources
                if UNREAD in sources:  # the session could not read the files
                    return ReloadOutcome(False, self.files, (sources[UNREAD],),
                                         sources=sources)
            else:
                sources = read_sources(config.plc.logic)
            logic = load_logic(config.plc.logic, config, sources)
            return logic, program_order(logic, config), sources
        except LogicError as exc:
            said = tuple(d.render() for d in exc.diagnostics)
        except ConfigError as exc:  # plc.programs names a PROGRAM now gone
            said = (str(exc),)
        except OSError as exc:  # a file removed, unreadable, a directory now: the record
            said = (str(exc),)  # says so, for its replay to say the same
            sources = {UNREAD: said[0]}
        return ReloadOutcome(False, self.files, said, sources=sources)

    def __call__(self, by: str) -> ReloadOutcome:
        """Swap in what :meth:`prepare` compiled (or compile now, on the virtual clock)."""
        with self._lock:
            prepared, self._prepared = self._prepared, None
        if prepared is None:
            prepared = self._compile()
        sources = prepared.sources if isinstance(prepared, ReloadOutcome) else prepared[2]
        if self._record is not None:  # what the replay will load here (as this did)
            self._record(sources, self.runtime.engine.now)
        if isinstance(prepared, ReloadOutcome):
            outcome = prepared
            log.error("PLC logic not reloaded (%s); the old logic runs on:\n%s", by,
                      "\n".join(outcome.diagnostics))
        else:
            logic, order, self.sources = prepared
            done = self.plc.reload(logic, order)
            outcome = ReloadOutcome(True, self.files, (), done.kept, done.initial,
                                    done.dropped)
            log.info("PLC logic reloaded (%s): %d variable(s) kept, %d from their initial "
                     "value%s%s", by, done.kept, len(done.initial),
                     f" ({', '.join(done.initial)})" if done.initial else "",
                     f", gone: {', '.join(done.dropped)}" if done.dropped else "")
        self.last = outcome
        engine = self.runtime.engine
        self.runtime.trace.record(PlcReload, engine.now, 0, None, outcome.ok, by,
                                  list(outcome.files), outcome.kept, list(outcome.initial),
                                  list(outcome.dropped), list(outcome.diagnostics))
        return outcome


WATCH_INTERVAL_S = 0.5  # how often run --watch looks at the logic files (one stat each)


class LogicWatcher:
    """``run --watch``: reloads the PLC logic when one of its files changes.

    A daemon thread looks at each file's size, mtime and inode every ``interval_s`` (a stat,
    off the loop: no new dependency, no file read) and hands a change to the loop, where
    ``reload`` applies ``reload_plc`` through the door.  A file still being written -- its
    stat changed again since the last look -- is reloaded once it has stood still for one
    interval, so an editor's save is one reload, not two."""

    def __init__(self, files: tuple[Path, ...], reload: Callable[[], None],
                 loop: asyncio.AbstractEventLoop, interval_s: float = WATCH_INTERVAL_S) -> None:
        self.files = files
        self.reload = reload
        self.loop = loop
        self.interval_s = interval_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="ncgate run --watch",
                                        daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()

    def _look(self) -> tuple[FileStat, ...]:
        return tuple(file_stat(path) for path in self.files)  # (None, gone: a change too)

    def baseline(self) -> tuple[FileStat, ...]:
        """Each file as it stood before the running logic was read (read_sources), so that
        a save made during the read is a change; a file this process never read, as now."""
        now = self._look()
        return tuple(_stat_when_read.get(path.absolute(), stat)
                     for path, stat in zip(self.files, now, strict=True))

    def _watch(self) -> None:
        seen = self.baseline()
        pending = None
        while not self._stop.wait(self.interval_s):
            now = self._look()
            if now != seen:
                seen, pending = now, now  # changed: wait until it stands still
                continue
            if pending is not None and now == pending:
                pending = None
                with contextlib.suppress(RuntimeError):  # the loop is closed: stopping
                    self.loop.call_soon_threadsafe(self.reload)


# The most still scans one leap passes over (the next leap goes on from there).
LEAP_SCANS = 1 << 16


class ScanDriver:
    """Runs the scan every ``scan_ms`` as an engine timer."""

    def __init__(self, engine: Engine, runtime: PlcRuntime, scan_ms: int, *,
                 wall: Callable[[], float] | None = None, closed: bool = False,
                 stall_s: float = 60.0, scale: float = 1.0, leap: bool = False) -> None:
        """``wall``: machine time now by the wall clock (``run``); ``scale``: the time scale
        that turns the scans' lateness back into wall-clock time; ``leap``: every input
        comes from an engine timer (``sim``: see :meth:`_leap`)."""
        self.engine = engine
        self.scale = scale
        self.runtime = runtime
        self.period = scan_ms / 1000.0
        self.wall = wall
        self.closed = closed
        self.leap = leap and closed and wall is None
        runtime.timed = self.leap
        runtime.leap_passed = self._passed_ms if self.leap else None
        self.stall_s = stall_s
        self.t0 = engine.now
        self.k = 0
        self._leapt = 0  # still scans leapt over, counted when the next one runs
        self._leapt_from = 0.0  # the time the leap was taken
        self._reach = 16  # scans the next leap with nothing ahead passes (doubling)
        # The scans not run (the first's index -> how many): ``run`` tells ``on_skip`` of
        # each (the session's record keeps them), a replay skips the same ones (``skips``):
        # those due while the fieldbus started (index 0) and the overruns.
        self.on_skip: Callable[[int, int], None] | None = None
        self.skips: dict[int, int] = {}
        self._timer: Timer | None = engine.call_at(self.t0, self._scan)
        engine.periodic.append(self)

    def _only_scans_left(self) -> bool:
        """No timer is armed but the other scan drivers' (the PLC's beside the plant's
        logic): each saw the other's next scan as something still to come, and a stalled
        closed run with both never ended."""
        others = sum(1 for d in self.engine.periodic if isinstance(d, ScanDriver)
                     and d is not self and d._timer is not None
                     and d._timer.callback is not None)
        return self.engine.live_timers == others

    def _scan(self) -> None:
        engine, period = self.engine, self.period
        status = self.runtime.status
        if self.wall is not None:
            now = self.wall()
            if self.k == 0:
                # The first scan is on time whenever the gateway got round to it (starting
                # the fieldbus may take a while): the scans count from here -- from the point
                # of their grid (t0 + k * period, t0 the time the PLC started) at or before
                # now, not from now itself, so that they stay on the grid a replay of the
                # session scans on (``sim --replay``, which cannot know how late that was).
                self.k = max(0, grid_index(now - self.t0, period, math.floor))
                if self.k and self.on_skip is not None:
                    self.on_skip(0, self.k)
                lateness = 0
            else:
                # On the wall clock, as the scan's own time is: machine time / time scale.
                lateness = max(0, round((now - (self.t0 + self.k * period)) * 1e6
                                        / self.scale))
            status.last_lateness_us = lateness
            status.max_lateness_us = max(status.max_lateness_us, lateness)
        elif self.skips and self.k == 0:
            self.k = self.skips.pop(0, 0)
        if self._leapt:  # (a running timer this scan does not call reads as they left it)
            self.runtime.catch_up(self._ms(self.k - 1))
            status.scans += self._leapt
            self._leapt = 0
        self.runtime.scan(self._ms(self.k))
        self.k += 1
        if self.wall is not None:
            late = self.wall() - (self.t0 + self.k * period)
            if late >= period:  # the loop came a whole period late or more: skip, count
                missed = int(late // period)
                status.overruns += missed
                if self.on_skip is not None:
                    self.on_skip(self.k, missed)
                self.k += missed
        elif self.skips and self.k in self.skips:  # a replay: an overrun of the session's
            missed = self.skips.pop(self.k)
            status.overruns += missed
            self.k += missed
        later = engine.next_timer() if self.closed else None
        if self.closed and engine.now - engine.last_change >= self.stall_s and (
                engine.stalled and (later is None or self._only_scans_left())):
            self._timer = None  # nothing but the scans is left: let the run end as a stall
            return
        if self.leap and not self.runtime.scan_listeners:
            if self.runtime.still:
                self._leap(later)
                return
            until = self.runtime.still_until
            if until is not None:
                self._leap(later, until)
                return
        self._timer = engine.call_at(self.t0 + self.k * period, self._scan)

    def _leap(self, later: float | None, until: int | None = None) -> None:
        """Arm the first scan that may see something new, past the still ones before it.

        The last scan changed nothing and read what it reads now (``PlcRuntime.still``):
        until another timer fires, nothing can change -- in ``sim`` every input is a timer
        (a script's entry, the plant, the NC's motion) -- so each scan before then would
        be skipped as still.  The first scan armed is the first due at or after that timer
        (or, with none left and the cell stalled, the one the stall rule stops at; with none
        left and no stall to come, nothing changes any more, and the scans go on until the
        run's end -- ``--until``, a scenario's horizon -- leapt over in steps that double),
        at the very time the scans one after the other would have given it (each is armed
        from the time the one before ran: ``due_time``), so the trace is the same to the
        bit.  The scans leapt over are counted.  ``later``: when the next other timer is due
        (None: there is none).  ``until``: the last scan was timed still
        (PlcRuntime.still_until): the first scan at or after this time (ms) sees a running
        timer's Q change, and is armed if nothing comes first."""
        engine, period = self.engine, self.period
        stalls = later is None and engine.stalled
        reach = LEAP_SCANS
        if later is None and until is None:  # (a stall to come too: the run may end long
            # before it -- a scenario's horizon -- and a leap to it passed its scans one by
            # one for nothing)
            reach, self._reach = self._reach, min(LEAP_SCANS, 2 * self._reach)
        start = now = engine.now
        k, t0 = self.k, self.t0
        for _ in range(reach):
            due = t0 + k * period  # the time call_at would give (due_time, inline: a leap
            due = round((due if due > now else now) * NS_PER_S) / NS_PER_S  # runs it a lot)
            if until is not None and self._ms(k) >= until:
                break  # scan k sees a timer's Q change
            if (due >= later) if later is not None else stalls and (
                    due - engine.last_change >= self.stall_s):
                break  # scan k may see something new (or the stall rule stops at it)
            now = due
            k += 1
        else:
            due = due_time(self.t0 + k * period, now)
        # The one timer the leap arms, from the time now: at the time worked out, or the
        # scans go on one at a time.
        if k > self.k and due_time(due, start) == due:
            self._leapt, self._leapt_from = k - self.k, start
            self.k = k
            self._timer = engine.call_at(due, self._scan)
        else:
            self._timer = engine.call_at(self.t0 + self.k * period, self._scan)

    def settle(self) -> None:
        """The run ended before the scan a leap armed: count the still scans leapt over
        that the clock has passed (each ran, as far as anyone can tell)."""
        if not self._leapt:
            return
        passed = self._passed()
        self.runtime.status.scans += passed
        if passed:  # (a timed still scan's running timers: their ETs then)
            self.runtime.catch_up(self._ms(self.k - self._leapt + passed - 1))
        self._leapt = 0

    def _passed(self) -> int:
        """How many of the scans the leap in progress passes the clock has passed."""
        t, engine = self._leapt_from, self.engine
        for n, k in enumerate(range(self.k - self._leapt, self.k)):
            t = due_time(self.t0 + k * self.period, t)
            if t > engine.now:
                return n
        return self._leapt

    def _passed_ms(self) -> int | None:
        """The time (ms) of the last scan the leap in progress has passed by now, None when
        none (PlcRuntime.leap_passed: a force or a reload in the middle of a leap)."""
        passed = self._passed()
        return self._ms(self.k - self._leapt + passed - 1) if passed else None

    def _ms(self, k: int) -> int:
        """Scan ``k``'s due time in ms, the time the logic's timers see."""
        return round((self.t0 + k * self.period) * 1000)

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self in self.engine.periodic:
            self.engine.periodic.remove(self)
        self.runtime.stop()


@dataclass(frozen=True, slots=True)
class Prepared:
    """A section's logic read and compiled, its PROGRAMs chosen (:func:`prepare_logic`)."""

    sources: Sources
    logic: Logic
    order: tuple[str, ...]


def prepare_logic(config: Config, section: str, sources: Sources | None = None, *,
                  warn: bool = True) -> Prepared | None:
    """``section``'s (``plc``, ``plant``) logic read (or ``sources``: a replay's), compiled
    and its PROGRAMs chosen: LogicError or ConfigError now.  ``run`` prepares both before its
    fieldbus serves: a PLC connected saw the CANopen node boot, then go, for a typo.
    ``warn``: :func:`load_logic`'s."""
    files = getattr(config, section).logic
    if not files:
        return None
    if sources is None:
        sources = read_sources(files, config, section)
    logic = load_logic(files, config, sources, section, warn=warn)
    return Prepared(sources, logic, tuple(program_order(logic, config, section)))


def start_plc(config: Config, runtime: Runtime, door: Door, *, closed: bool,
              wall: Callable[[], float] | None = None, cold: bool = False,
              sources: Sources | None = None, leap: bool = False,
              prepared: Prepared | None = None) -> tuple[PlcRuntime, ScanDriver] | None:
    """The PLC logic of ``[plc] logic`` running on the engine's clock, or None without it.

    RETAIN values are kept in ``plc.retain_file`` in ``run`` only: a simulation (``closed``)
    starts from the initial values every time, so that it stays deterministic.
    ``sources``: the files' content to load instead of the files (a replay's, recorded).
    ``leap``: every input comes from an engine timer (``sim``): still scans are leapt over
    (:meth:`ScanDriver._leap`).  ``prepared``: :func:`prepare_logic`'s, done already."""
    plc = config.plc
    if prepared is None:
        prepared = prepare_logic(config, "plc", sources)
    if prepared is None:
        return None
    sources, logic, order = prepared.sources, prepared.logic, list(prepared.order)
    store = None
    if not closed and any(v.retain for table in logic.programs.values()
                          for v in table.values()):
        path = plc.retain_file or default_path(state_folder(config.source))
        try:
            store = RetainStore(path)
            if cold:
                store.clear()
        except (sqlite3.Error, OSError) as exc:  # OSError: its folder cannot be made
            raise ConfigError(f"{config.source or '<config>'}: plc.retain_file: cannot keep "
                              f"RETAIN values in {path}: {exc}") from None
    engine = runtime.engine
    logic_runtime = PlcRuntime(logic, runtime.image, EngineNc(engine, door), order,
                               plc.loop_limit, store,
                               watchdog_ms=0 if closed else plc.watchdog_ms)
    runtime.plc = logic_runtime
    logic_runtime.on_overridden = lambda path, value: engine.note_forced(path, value, "plc")
    door.reload_plc = OnlineChange(config, runtime, logic_runtime, sources)
    driver = ScanDriver(engine, logic_runtime, plc.scan_ms, wall=wall, closed=closed,
                        scale=config.nc.time_scale, stall_s=config.nc.stall_s, leap=leap)
    log.info("PLC logic: %s, scan %d ms, programs %s", ", ".join(p.name for p in plc.logic),
             plc.scan_ms, ", ".join(order))
    return logic_runtime, driver


def start_plant_logic(config: Config, runtime: Runtime, door: Door, *, closed: bool,
                      wall: Callable[[], float] | None = None, leap: bool = False,
                      prepared: Prepared | None = None
                      ) -> tuple[PlcRuntime, ScanDriver] | None:
    """The plant's own logic (``[plant] logic``): a second ST task on the engine's clock,
    every ``plant.scan_ms``, its image writes attributed to ``plant`` and its NC outputs to
    ``plant FILE:LINE``; no RETAIN (a machine's physics has no memory to keep), no online
    change.  None without it."""
    plant = config.plant
    if prepared is None:
        prepared = prepare_logic(config, "plant")
    if prepared is None:
        return None
    logic, order = prepared.logic, list(prepared.order)
    engine = runtime.engine
    logic_runtime = PlcRuntime(logic, runtime.image, EngineNc(engine, door, SourceKind.PLANT),
                               order, config.plc.loop_limit,
                               watchdog_ms=0 if closed else config.plc.watchdog_ms,
                               writer="plant")
    driver = ScanDriver(engine, logic_runtime, plant.scan_ms, wall=wall, closed=closed,
                        scale=config.nc.time_scale, stall_s=config.nc.stall_s, leap=leap)
    if runtime.plant is not None:
        runtime.plant.logic = logic_runtime  # (its status in the plant's)
    log.info("plant logic: %s, scan %d ms, programs %s",
             ", ".join(p.name for p in plant.logic), plant.scan_ms, ", ".join(order))
    return logic_runtime, driver


def plc_registers(status: PlcStatus | None) -> list[int]:
    """The PLC status block; all 0 (state 0, stopped) when the PLC runs no logic."""
    if status is None:
        return [0] * len(PLC_REGISTERS)
    regs = [int(status.state)]
    for value in (status.scans, status.last_scan_us, status.max_scan_us, status.overruns):
        value &= 0xFFFFFFFF
        regs += [value >> 16, value & 0xFFFF]
    fault = status.fault
    regs.append(fault.span.line & 0xFFFF if fault is not None and fault.span else 0)
    for late in (status.last_lateness_us, status.max_lateness_us):
        late = min(late, 0xFFFFFFFF)
        regs += [late >> 16, late & 0xFFFF]
    return regs


__all__ = ["EngineNc", "LogicWatcher", "OnlineChange", "PlcState", "ReloadOutcome", "ScanDriver",
           "load_logic", "start_plant_logic", "start_plc"]
