"""A commissioning session on disk, and its replay on the virtual clock (``run --record``,
``sim --replay``).  The format is documented in docs/console.md ("The session record").

The record is JSON Lines, in the order things happened:

- line 1, the header: ``{"ncgate_record": 2, "version", "config", "overrides",
  "time_scale", "files": {path: sha256}}`` -- what the replay needs to run the same cell; the
  files are the ones the session used from the start (the config, the PLC logic);
- ``{"program": path, "sha256"}`` when the session first reads a part program (and again
  when it changed): the replay warns when a program it runs is not the one recorded;
- ``{"plc_logic": {path: text}, "t"}``: the PLC logic's files as the PLC runs them when the
  record starts, and as each online change (``reload_plc``) read them, right after its
  command's line: the replay loads these, not the files as they are now (``{"": error}``:
  that reload could not read them, and the replay's fails with the same error);
- an *input* line for everything that came through the door from outside the cell, with its
  machine time and its source (``who``: the trace's attribution; ``peer``: the address):
  ``{"input": "write", "t", "who", "peer", "changes": [[area, index, view, value], ...]}``,
  ``"command"`` (``command``: cycle_start | feed_hold | reset, ``process``: a number, or
  null for the cell),
  ``"snd"`` (``from``, ``to``), ``"start"`` (``prog``, ``proc``), ``"alarm"`` (``code``: the
  alarm number, ``message``).  The PLC logic's inputs are not recorded: the replay runs the
  same logic.  An input applied before the other timers of its instant (``"first": true``:
  ``run --script``'s start and its entries at the scenario's 0, at a scan's instant) is
  replayed there; any other after them;
- every trace event of spec 4.4, as in a trace file (the lines with ``"seq"``);
- ``{"skipped": "plc" | "plant", "k", "n", "t"}``: scans ``k`` .. ``k + n - 1`` of the PLC
  logic (or of the plant's) that the session did not run -- those due while the fieldbus
  started (``k`` 0), and each overrun, the loop a whole period late -- which the replay skips
  too;
- ``{"plant": "cut" | "stretch", "t", "n"}``: what the wall clock's budget decided at the
  plant's tick at ``t`` -- the tick cut short after ``n`` models, the tick's period stretched
  to ``n`` scans -- which the replay decides the same (a line at no tick of the plant, or an
  ``n`` the budget never decides, is refused: :func:`check_plant_lines`);
- on a clean stop, ``{"stop": t}``.

An input's line is written before the events it causes, and lines are written whole
(:class:`~ncgate.gateway.tracefile.TraceFile`), so a record cut anywhere -- ``kill -9``, a
full disk -- holds no effect without its cause and replays up to its last line.  Every line is
validated on reading: anything else than the above is an error naming the line (exit 2).

:func:`replay` runs the recorded config and programs on the virtual clock, applies every input
at its time through the same door (:class:`~ncgate.gateway.door.Door`) with its recorded
source, and compares what each process did -- the blocks at which it started, waited,
resumed, sent, started another, raised an alarm or ended, in order, with times within a
tolerance -- against the recording.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ncgate import __version__
from ncgate.config import Config, ConfigError, load_config
from ncgate.config.plant import fault_input
from ncgate.errors import InputRefused
from ncgate.gateway.door import Door
from ncgate.gateway.errors import UsageError
from ncgate.gateway.plant.plant import MAX_STRETCH
from ncgate.gateway.plc import OnlineChange, start_plant_logic, start_plc
from ncgate.gateway.tracefile import TraceFile
from ncgate.gateway.wiring import Runtime, build_runtime, start_plant
from ncgate.inputs import (
    Break,
    ClearFault,
    Command,
    CommandKind,
    Fault,
    FieldbusAlarm,
    Force,
    Input,
    Override,
    PlcVar,
    Snd,
    Source,
    Start,
    Var,
    Write,
    Writes,
)
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import run_through
from ncgate.interpreter.engine.events import Event
from ncgate.interpreter.engine.trace import EventDict

FORMAT = 2
ALARMS = frozenset(int(code) for code in AlarmCode)  # what an "alarm" input may carry
# What is compared, per process, and the fields that must agree besides the block.
COMPARED: dict[str, tuple[str, ...]] = {
    "start": ("prog", "by"), "wait": ("on",), "resume": ("by",), "snd": ("to",),
    "exe": ("to", "target_prog"), "end": ("how",), "alarm": ("code",),
    # The auxiliary functions' handshake ([nc.aux]): each output and its acknowledge.
    "aux": ("code", "handshake"), "aux_ack": ("code",),
    # Where the operator's stops stand: a single-block, step, M00/M01 or breakpoint stop, a
    # step given, a feed hold on or off (a replay that stops elsewhere diverged).
    "stop": ("cause",), "step": (), "hold": ("on",),
}
EVENTS = frozenset({*COMPARED, "write", "deadlock", "stall", "hazard", "display", "signal",
                    "plc_reload",
                    "remove", "override", "break", "force", "forced", "fault",
                    "fault_clear"})
UNBOUNDED = 1 << 62  # a record is never rotated: it must stay whole
SCANNED = ("plc", "plant")  # the logic whose skipped scans a record keeps


def program_files(config: Config) -> list[Path]:
    """Every file on the config's storage devices (what the console lists)."""
    out: list[Path] = []
    for folder in dict.fromkeys(config.nc.storage.devices.values()):
        if folder.is_dir():
            out += [path for path in sorted(folder.iterdir())
                    if path.is_file() and not path.name.startswith(".")]
    return out


def _sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def session_files(config: Config) -> dict[str, str]:
    """sha256 of the files a session uses from its start: the config, the PLC logic."""
    paths = ([config.source] if config.source else []) + list(config.plc.logic) + list(
        config.plant.logic)
    return {str(Path(p).resolve()): digest for p in paths
            if (digest := _sha256(Path(p))) is not None}


# -- inputs as lines, and back ------------------------------------------------------------------

def input_line(item: Input, t: float) -> dict[str, Any]:
    """The record's line for an input at machine time ``t``."""
    out: dict[str, Any] = {"input": "", "t": round(t, 6), "who": str(item.source),
                           "peer": item.source.peer}
    if isinstance(item, Write):
        out.update(input="write", changes=[[*item.var.address, item.value]])
    elif isinstance(item, Writes):
        out.update(input="write", changes=[[*v.address, value] for v, value in item.changes])
    elif isinstance(item, Command):
        out.update(input="command", command=CommandKind(item.kind).label,
                   process=item.process)
    elif isinstance(item, Snd):
        out.update({"input": "snd", "from": item.sender, "to": item.target})
    elif isinstance(item, Start):
        out.update(input="start", prog=item.program, proc=item.process)
        if item.at is not None:
            out.update(at=item.at, with_calc=item.with_calc)
    elif isinstance(item, Override):
        out.update(input="override", feed=item.feed, rapid=item.rapid, process=item.process)
    elif isinstance(item, Break):
        out.update({"input": "break", "at": item.at, "on": item.on})
    elif isinstance(item, Force):
        var = item.var
        out.update(input="force", value=item.value,
                   var=None if var is None else str(var) if isinstance(var, PlcVar)
                   else list(var.address))
    elif isinstance(item, Fault):
        out.update(input="fault", target=item.target, kind=item.kind,
                   params={k: list(v) if isinstance(v, tuple) else v for k, v in item.params},
                   for_s=item.for_s)
    elif isinstance(item, ClearFault):
        out.update(input="fault_clear", target=item.target)
    elif isinstance(item, FieldbusAlarm):
        out.update(input="alarm", code=int(item.code), message=item.message)
    else:
        raise TypeError(f"no record line for {item!r}")
    return out


class RecordError(UsageError):
    """A line of a record that is not what ``run --record`` writes (exit 2)."""


def _field(item: dict[str, Any], name: str, kinds: type | tuple[type, ...], what: str,
           optional: bool = False) -> Any:
    if name not in item:
        if optional:
            return None
        raise ValueError(f'"{name}" is missing')
    value = item[name]
    if value is None and optional:
        return None
    if isinstance(value, bool) and bool not in (kinds if isinstance(kinds, tuple)
                                                 else (kinds,)):
        raise ValueError(f'"{name}": expected {what}, got {json.dumps(value)}')
    if not isinstance(value, kinds):
        raise ValueError(f'"{name}": expected {what}, got {json.dumps(value)}')
    return value


def _time(item: dict[str, Any], name: str) -> float:
    t = _field(item, name, (int, float), "a time in seconds")
    if not math.isfinite(t) or t < 0:  # (json.loads reads NaN and Infinity: said so)
        raise ValueError(f'"{name}": expected a time >= 0, got {json.dumps(t)}')
    return float(t)


def parse_input(item: dict[str, Any]) -> tuple[float, Input]:
    """An input line as (t, input); ValueError saying what is wrong."""
    kind = item["input"]
    t = _time(item, "t")
    who = _field(item, "who", str, "a source such as \"modbus 127.0.0.1:40312\"")
    peer = _field(item, "peer", str, "an address or null", optional=True)
    try:
        source = Source.parse(who, peer)
    except InputRefused as exc:
        raise ValueError(f'"who": {exc}') from None
    if kind == "write":
        changes = _field(item, "changes", list, "a list of [area, index, view, value]")
        out = []
        for change in changes:
            if not (isinstance(change, list) and len(change) == 4
                    and all(isinstance(x, str) for x in change[0:1] + change[2:3])
                    and all(isinstance(x, int) and not isinstance(x, bool)
                            for x in (change[1], change[3]))):
                raise ValueError(f'"changes": {json.dumps(change)} is not [area, index, '
                                 "view, value]")
            area, index, view, value = change
            if area not in ("SA", "SK", "SYVAR") or view not in ("bit", "BY", "IN"):
                raise ValueError(f'"changes": {json.dumps(change)} names no image variable')
            out.append((Var(area, index, view), value))
        if not out:
            raise ValueError('"changes" is empty')
        return t, Writes(tuple(out), source)
    if kind == "command":
        name = _field(item, "command", str, "cycle_start, feed_hold or reset")
        kinds = {k.label: k for k in CommandKind}
        if name not in kinds:
            raise ValueError(f'"command": expected {", ".join(kinds)}, got {json.dumps(name)}')
        process = _field(item, "process", int, "a process number, or null for the cell",
                         optional=True)
        return t, Command(kinds[name], process, source)
    if kind == "snd":
        return t, Snd(_field(item, "from", int, "a process number"),
                      _field(item, "to", int, "a process number"), source)
    if kind == "start":
        return t, Start(_field(item, "prog", str, "a program name"),
                        _field(item, "proc", int, "a process number"), source,
                        _field(item, "at", str, "a label or an N number", optional=True),
                        bool(_field(item, "with_calc", bool, "true or false", optional=True)))
    if kind == "alarm":
        code = _field(item, "code", int, "an alarm number")
        if code not in ALARMS:
            raise ValueError(f'"code": {code} is no alarm of the fieldbus side')
        return t, FieldbusAlarm(code, _field(item, "message", str, "a text"), source)
    if kind == "force":
        raw = _field(item, "var", (list, str), "[area, index, view], a PLC variable or null",
                     optional=True)
        var: Var | PlcVar | None = None
        if isinstance(raw, str):
            try:
                var = PlcVar(raw)
            except InputRefused:
                raise ValueError(f'"var": {json.dumps(raw)} names no PLC variable') from None
        elif raw is not None:
            if not (len(raw) == 3 and raw[0] in ("SA", "SK", "SYVAR") and raw[2] in (
                    "bit", "BY", "IN") and isinstance(raw[1], int)
                    and not isinstance(raw[1], bool)):
                raise ValueError(f'"var": {json.dumps(raw)} names no image variable')
            var = Var(raw[0], raw[1], raw[2])
        return t, Force(var, _field(item, "value", (int, float, bool), "a value or null",
                                    optional=True), source)
    if kind == "break":
        return t, Break(_field(item, "at", str, "a breakpoint such as \"PROG92:8\""),
                        _field(item, "on", bool, "true (set) or false (clear)"), source)
    if kind == "override":
        return t, Override(_field(item, "feed", int, "a percent or null", optional=True),
                           _field(item, "rapid", int, "a percent or null", optional=True),
                           _field(item, "process", int, "a process number, or null for the "
                                  "cell", optional=True), source)
    if kind == "fault":
        params = _field(item, "params", dict, "an object of the fault's keys")
        for_s = _field(item, "for_s", (int, float), "seconds or null", optional=True)
        # What no cell's plant takes is no record's (a kind "melt" replayed as a divergence
        # "560 ms apart", its refusal a hazard in the trace); what this cell's refuses (its
        # models, its image) the replay says.
        fault_input(_field(item, "kind", str, "a fault kind"), params, for_s, ValueError)
        return t, Fault(_field(item, "target", str, "a fault's target"),
                        _field(item, "kind", str, "a fault kind"),
                        tuple(sorted((str(k), tuple(v) if isinstance(v, list) else v)
                                     for k, v in params.items())),
                        None if for_s is None else float(for_s), source)
    if kind == "fault_clear":
        return t, ClearFault(_field(item, "target", str, "a target or null", optional=True),
                             source)
    raise ValueError(f'"input": unknown kind {json.dumps(kind)} (write, command, snd, start, '
                     "alarm, override, break, force, fault, fault_clear)")


def _check_event(item: dict[str, Any]) -> None:
    _field(item, "seq", int, "a whole number")
    _time(item, "t")
    kind = _field(item, "event", str, "an event name")
    if kind not in EVENTS:
        raise ValueError(f'"event": unknown event {json.dumps(kind)}')
    _field(item, "proc", int, "a process number (0: the PLC and the fieldbus)")
    _field(item, "prog", str, "a program name or null", optional=True)
    _field(item, "line", int, "a line number or null", optional=True)
    _field(item, "n", int, "an N number or null", optional=True)


# -- writing ------------------------------------------------------------------------------------

class SessionRecorder:
    """Writes one session: the header at once, then inputs (before their effects), programs
    and trace events as they come."""

    def __init__(self, path: str | Path, config: Config, overrides: dict[str, Any],
                 loop: asyncio.AbstractEventLoop | None = None, *,
                 staged: bool = False) -> None:
        """``staged``: written beside ``path`` until :meth:`commit` puts it there (``run
        --record`` while the gateway starts: a start that fails, a port taken, leaves a
        file already at ``path`` as it was -- it was emptied, and given a stop line)."""
        self.path = Path(path)
        self.staged = staged
        where = (self.path.with_name(f".{self.path.name}.{os.getpid()}.starting") if staged
                 else self.path)
        self._file = TraceFile(where, UNBOUNDED, 0, loop=loop, fresh=True)
        self._programs: dict[str, str] = {}
        header = {"ncgate_record": FORMAT, "version": __version__,
                  # Absolute: a replay from another folder finds it (a relative one was
                  # looked for in the replay's folder).
                  "config": str(Path(config.source).resolve()) if config.source else None,
                  "overrides": overrides, "time_scale": config.nc.time_scale,
                  "files": session_files(config)}
        self._file.append(json.dumps(header) + "\n")
        self._file.flush()

    def event(self, event: Event) -> None:
        """A trace listener."""
        self._file.write(event)

    def input(self, item: Input, t: float, first: bool = False) -> None:
        """The door's recorder: called after validation, before the effect.  ``first``:
        applied before the other timers of its instant (``Door.apply_first``)."""
        line = input_line(item, t)
        if first:
            line["first"] = True
        self._file.append(json.dumps(line) + "\n")

    def program(self, path: Path) -> None:
        """A program file the session read (ProgramStore.loaded)."""
        digest = _sha256(path)
        if digest is not None and self._programs.get(str(path)) != digest:
            self._programs[str(path)] = digest
            self._file.append(json.dumps({"program": str(path), "sha256": digest}) + "\n")

    def logic(self, sources: dict[str, str], t: float) -> None:
        """The PLC logic's sources (path -> content): those running when the record starts
        and those of every online change (``OnlineChange.record_to``), for the replay."""
        self._file.append(json.dumps({"plc_logic": sources, "t": round(t, 6)}) + "\n")

    def skipped(self, who: str, k: int, n: int, t: float) -> None:
        """Scans ``k`` .. ``k + n - 1`` of ``who`` (``plc``, ``plant``: its logic) were not
        run (``ScanDriver.on_skip``): the replay skips them too."""
        self._file.append(json.dumps({"skipped": who, "k": k, "n": n, "t": round(t, 6)})
                          + "\n")

    def plant(self, kind: str, t: float, n: int) -> None:
        """A decision of the plant's tick budget (``Plant.on_decision``): the replay's."""
        self._file.append(json.dumps({"plant": kind, "t": round(t, 6), "n": n}) + "\n")

    def flush(self) -> None:
        """Write what is pending now (a download of the record as far as it is)."""
        self._file.flush()

    def commit(self) -> None:
        """The staged record at its path from now on (the file written so far, renamed)."""
        if self.staged:
            self._file.flush()
            os.replace(self._file.path, self.path)
            self._file.path, self.staged = self.path, False

    def close(self, t: float) -> None:
        """The stop line, and the file closed; a record still staged is removed (the
        session never served: nothing of it is a session to replay)."""
        if self.staged:
            self._file.close()
            with contextlib.suppress(OSError):
                os.unlink(self._file.path)
            return
        self._file.append(json.dumps({"stop": round(t, 6)}) + "\n")
        self._file.close()


# -- reading ------------------------------------------------------------------------------------

@dataclass
class RecordedInput:
    line: int  # in the record file, for messages
    t: float
    input: Input
    first: bool = False  # applied before the other timers of its instant (Door.apply_first)


@dataclass
class Recording:
    path: Path
    header: dict[str, Any]
    inputs: list[RecordedInput] = field(default_factory=list)
    events: list[EventDict] = field(default_factory=list)
    programs: dict[str, str] = field(default_factory=dict)  # path -> sha256, as last read
    logic: list[dict[str, str]] = field(default_factory=list)  # the PLC logic's sources
    # The scans the session did not run, per logic ("plc", "plant"): first index -> how many.
    skipped: dict[str, dict[int, int]] = field(default_factory=dict)
    # The plant's tick budget's decisions: "cut" / "stretch" -> the tick's time -> n.
    plant: dict[str, dict[float, int]] = field(
        default_factory=lambda: {"cut": {}, "stretch": {}})
    # Each decision's line, for the checks that need the config (check_plant_lines).
    plant_lines: dict[tuple[str, float], int] = field(default_factory=dict)
    stop: float | None = None  # None: the session did not stop cleanly (killed)

    @property
    def end(self) -> float:
        """Where the replay stops: the clean stop, else the last thing recorded."""
        if self.stop is not None:
            return self.stop
        times = [i.t for i in self.inputs[-1:]] + [e["t"] for e in self.events[-1:]]
        return max(times, default=0.0)


def read_record(path: str | Path) -> Recording:
    """A record file, every line validated; RecordError naming the file and line when it
    is not one (a last line cut by a crash of the writer is ignored)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise UsageError(f"{path}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise RecordError(f"{path}: not UTF-8 text: not an ncgate session record") from None
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    recording: Recording | None = None
    for number, line in enumerate(lines, start=1):
        try:
            item = json.loads(line)
        except (ValueError, RecursionError):  # JSONDecodeError, or a number or nesting
            # past what Python reads: not a line run --record writes either way
            if number == len(lines) and not text.endswith("\n"):
                break  # a tail cut by a crash of the writer: replay up to it
            raise RecordError(f"{path}:{number}: not a JSON line") from None
        if not isinstance(item, dict):
            raise RecordError(f"{path}:{number}: not a JSON object")
        if recording is None:
            found = item.get("ncgate_record")
            if found != FORMAT:
                older = (f" (format {found}, from an older ncgate: record the session again)"
                         if isinstance(found, int) and found < FORMAT else "")
                raise RecordError(f"{path}:1: not an ncgate session record{older} (ncgate "
                                  "run --record writes one)")
            recording = Recording(path, item)
            continue
        try:
            if recording.stop is not None:
                raise ValueError("a line after the stop")
            if "input" in item:
                t, parsed = parse_input(item)
                first = _field(item, "first", bool, "true or false", optional=True)
                recording.inputs.append(RecordedInput(number, t, parsed, bool(first)))
            elif "seq" in item:
                _check_event(item)
                recording.events.append(item)
            elif "plc_logic" in item:
                _time(item, "t")
                sources = _field(item, "plc_logic", dict, "the logic files' contents")
                if not all(isinstance(k, str) and isinstance(v, str)
                           for k, v in sources.items()):
                    raise ValueError('"plc_logic": a path -> text object')
                recording.logic.append(sources)
            elif "program" in item:
                recording.programs[_field(item, "program", str, "a path")] = _field(
                    item, "sha256", str, "a sha256")
            elif "skipped" in item:
                who = _field(item, "skipped", str, '"plc" or "plant"')
                if who not in SCANNED:
                    raise ValueError(f'"skipped": expected "plc" or "plant", got '
                                     f"{json.dumps(who)}")
                first = _field(item, "k", int, "a scan's index")
                count = _field(item, "n", int, "a number of scans")
                _time(item, "t")
                if first < 0 or count < 1:
                    raise ValueError(f'"k" {first}, "n" {count}: not a run of scans (k >= 0, '
                                     "n >= 1)")
                recording.skipped.setdefault(who, {})[first] = count
            elif "plant" in item:
                kind = _field(item, "plant", str, '"cut" or "stretch"')
                if kind not in ("cut", "stretch"):
                    raise ValueError(f'"plant": expected "cut" or "stretch", got '
                                     f"{json.dumps(kind)}")
                n = _field(item, "n", int, "a number of models or scans")
                t = round(_time(item, "t"), 6)
                _check_decision(recording, kind, t, n)
                recording.plant[kind][t] = n
                recording.plant_lines[kind, t] = number
            elif "stop" in item:
                recording.stop = _time(item, "stop")
            else:
                raise ValueError("neither an input, an event, a program, the PLC logic, "
                                 "skipped scans, the plant's budget nor the stop")
        except ValueError as exc:
            raise RecordError(f"{path}:{number}: {exc}") from None
    if recording is None:
        if text.strip():  # one line, cut by a crash of the writer before it ended
            raise RecordError(f"{path}:1: cut inside its header: the session stopped before "
                              "its record began (nothing to replay)")
        raise RecordError(f"{path}: empty: not an ncgate session record")
    last = 0.0
    for recorded in recording.inputs:
        if recorded.t < last - 1e-6:
            raise RecordError(f"{path}:{recorded.line}: an input at t={recorded.t} after one "
                              f"at t={last}: a record's inputs come in time order")
        last = recorded.t
    if recording.stop is not None:
        latest = max([i.t for i in recording.inputs] + [e["t"] for e in recording.events],
                     default=0.0)
        if latest > recording.stop + 1e-6:
            raise RecordError(f"{path}:{len(lines)}: the stop at t={recording.stop} comes "
                              f"before what was recorded (t={latest})")
    return recording


def _check_decision(recording: Recording, kind: str, t: float, n: int) -> None:
    """What a line of the plant's tick budget can be (``Plant._on_tick``), as far as the
    record alone says: ValueError otherwise.  A decision the replay's plant never meets would
    be dropped in silence, and the replay's ticks would not be the session's."""
    decided = recording.plant[kind]
    if kind == "cut":
        # The loop breaks before model n, n >= 1: the first model of a tick is always written.
        if n < 1:
            raise ValueError(f'"n" {n}: not a number of models (a tick is cut after 1 '
                             "or more)")
    elif n < 1 or n > MAX_STRETCH or n & (n - 1):
        raise ValueError(f'"n" {n}: not a stretch (a power of 2 from 1 to {MAX_STRETCH} '
                         "scans)")
    if t <= 0:  # the first tick is armed one period after the time it is armed at
        raise ValueError(f'"t" {json.dumps(t)}: no tick of the plant is at 0')
    last = next(reversed(decided), None)  # (in time order, as checked line by line)
    if last is not None and t <= last:
        raise ValueError(f"a {kind} at t={t} after one at t={last}: the plant decides "
                         "tick by tick, in time order, once a tick")
    if kind == "stretch" and last is not None:
        # The budget halves or doubles the period, a step a tick, and says only a change.
        # (The first line has nothing before it to compare with: a record started from the
        # console may begin while the tick is stretched.)
        before = decided[last]
        steps = [s for s in (before // 2, before * 2) if 1 <= s <= MAX_STRETCH]
        if n not in steps:
            raise ValueError(f'"n" {n}: the stretch was {before}: the budget doubles or '
                             f"halves it ({' or '.join(map(str, steps))})")


def check_plant_lines(recording: Recording, scan_ms: int, models: int) -> None:
    """The plant's tick-budget lines against the config the replay runs: each at a tick
    of the plant -- every ``scan_ms`` from 0, times the stretch in force -- and no cut
    past the models.  RecordError naming the line.

    The stretch in force is the record's last stretch before the tick; before the record's
    first stretch it is known only to be a power of 2 (a record started from the console may
    begin while the tick is stretched), so those ticks are checked on the grid of
    ``scan_ms`` alone."""
    scan_s = scan_ms / 1000.0
    stretch: int | None = None
    # At one tick the cut comes before the stretch (the budget decides after the models).
    for (kind, t), line in sorted(recording.plant_lines.items(),
                                  key=lambda x: (x[0][1], x[0][0] == "stretch")):
        n = recording.plant[kind][t]
        where = f"{recording.path}:{line}: a {kind} at t={t}"
        if not models:
            raise RecordError(f"{where}: the config's plant has no model (it never ticks)")
        period = scan_s * (stretch or 1)
        k = round(t / period)
        if k < 1 or abs(t - k * period) > 1e-6:  # (the record rounds to the microsecond)
            near = max(1, math.floor(t / period))
            grid = (f"plant.scan_ms {scan_ms}" if stretch is None
                    else f"plant.scan_ms {scan_ms} x the stretch {stretch} in force")
            raise RecordError(f"{where}: not a tick of the plant (every {grid} from 0: "
                              f"t={round(near * period, 6)}, {round((near + 1) * period, 6)}, "
                              "...)")
        if kind == "cut" and n >= models:
            raise RecordError(f"{where}: after {n} model{'s' if n > 1 else ''}, but the "
                              f"config's plant has {models} model{'s' if models > 1 else ''} "
                              "(a cut leaves one at least to the next tick)")
        if kind == "stretch":
            stretch = n


# -- replaying ----------------------------------------------------------------------------------

@dataclass
class ReplayResult:
    recording: Recording
    runtime: Runtime
    warnings: list[str]
    divergence: str | None  # None: the replay matches the recording
    compared: int  # events compared

    @property
    def events(self) -> list[EventDict]:
        return self.runtime.trace.events


def _changed(recorded: dict[str, str], used: Callable[[str], Path]) -> list[str]:
    """A warning for each recorded file whose counterpart now (``used``) is missing or not
    the same."""
    out = []
    for file, digest in sorted(recorded.items()):
        path = used(file)
        found = _sha256(path)
        as_now = "" if str(path) == file else f" (replayed with {path})"
        if found is None:
            out.append(f"{file}: recorded but not found now{as_now}")
        elif found != digest:
            out.append(f"{file}: changed since the recording{as_now}")
    return out


def replay(path: str | Path, config: str | Path | None = None,
           tolerance_ms: float = 10.0) -> ReplayResult:
    """Re-run a recorded session on the virtual clock and compare it with the recording.

    ``config``: the config file to use instead of the recorded one (a record taken home,
    where the files lie elsewhere)."""
    if not tolerance_ms >= 0 or math.isinf(tolerance_ms):
        raise UsageError(f"--tolerance-ms: expected a number >= 0, got {tolerance_ms}")
    recording = read_record(path)
    header = recording.header
    overrides = header.get("overrides") or {}
    source = config if config is not None else header.get("config")
    scale = header.get("time_scale")
    if not isinstance(overrides, dict) or not isinstance(source, str | Path | None) or (
            scale is not None and (isinstance(scale, bool) or not isinstance(scale, int | float)
                                   or not math.isfinite(scale) or scale <= 0)):
        raise RecordError(f"{recording.path}:1: the header's config, overrides or time "
                          "scale are not what run --record writes")
    try:
        cfg = load_config(source, overrides=dict(overrides))
    except ConfigError as exc:
        hint = "" if config is not None else " (a record taken elsewhere: give --config)"
        raise UsageError(f"the recorded config: {exc}{hint}") from None
    check_plant_lines(recording, cfg.plant.scan_ms, len(cfg.plant.model))
    runtime = build_runtime(cfg, closed=False)  # as in `run`: the fieldbus may start programs
    engine = runtime.engine
    door = Door(runtime, lambda: runtime.plc)
    for recorded in recording.inputs:  # a write the image cannot hold: not this session's
        item = recorded.input
        if isinstance(item, Writes):
            try:
                door.image_changes(item.changes)
            except InputRefused as exc:
                raise RecordError(f"{recording.path}:{recorded.line}: {exc} (in the "
                                  "recorded config)") from None
    # Each recorded file is compared with the one the replay uses: the config it loads for the
    # recorded config, and the logic files and programs of the same name that config finds
    # (by name first: the recorded path may still hold the file the session ran, while the
    # replay, given --config, loads another).  Else the recorded path itself.
    by_name = {p.name: p for p in program_files(cfg)}
    logic_now = {Path(p).name: Path(p) for p in (*cfg.plc.logic, *cfg.plant.logic)}
    recorded_config = header.get("config")

    def program_now(file: str) -> Path:
        p = Path(file)
        return by_name[p.name].resolve() if p.name in by_name else p

    def file_now(file: str) -> Path:
        if file == recorded_config and cfg.source is not None:
            return Path(cfg.source).resolve()
        p = Path(file)
        return logic_now[p.name].resolve() if p.name in logic_now else p

    files = header.get("files")
    files = files if isinstance(files, dict) else {}
    if recording.logic:  # the PLC logic is the record's: its files now do not matter
        plc_names = {Path(p).name for p in cfg.plc.logic}
        files = {k: v for k, v in files.items() if Path(k).name not in plc_names}
    warnings = _changed({str(k): str(v) for k, v in files.items()}, file_now)
    warnings += _changed(recording.programs, program_now)
    plc = start_plc(cfg, runtime, door, closed=True,
                    sources=recording.logic[0] if recording.logic else None)
    if recording.logic and isinstance(door.reload_plc, OnlineChange):
        door.reload_plc.recorded = list(recording.logic[1:])  # the session's reloads
    # The plant as run started it: its models, and the config's faults (neither recorded).
    from ncgate.config.script import Script
    from ncgate.gateway.sim import ScriptPlayer, plant_faults

    plant = start_plant(runtime, door.apply_on_time, closed=False, served=None)
    plant.decided = recording.plant  # the session's budget, not this machine's
    plant_logic = start_plant_logic(cfg, runtime, door, closed=True)
    # The session's scans never stopped (run's do not stop at a stall, which the replay's
    # inputs, not timers, may end): neither do the replay's.  Those it did not run (an
    # overrun: the loop came a whole period late) the replay does not run either.
    for who, started in zip(SCANNED, (plc, plant_logic), strict=True):
        if started is not None:
            started[1].stall_s = math.inf
            started[1].skips = dict(recording.skipped.get(who, {}))
    ScriptPlayer(runtime, Script("<config>", ()), door, plant_faults(cfg)).arm()
    end = recording.end
    refused: tuple[float, str] | None = None
    for recorded in sorted(recording.inputs, key=lambda i: i.t):  # stable: same-time order
        t = recorded.t
        run_through(engine, t, first=recorded.first)
        try:
            door.apply(recorded.input)
        except InputRefused as exc:
            # The session took it (it was recorded after its checks): refused here, the
            # replay is not the session any more.
            refused = refused or (recorded.t, f"replay diverges at the input of line "
                                  f"{recorded.line} (t={recorded.t:.3f}): the session took "
                                  f"it, the replay refuses it: {exc}")
            engine.note_hazard(0, f"replay: the input of line {recorded.line} was refused: "
                               f"{exc}")
        engine.run_until_blocked()
    # A cut record's last event may have come up to the tolerance earlier on the session's
    # wall clock than on the replay's: run that far, what lies past the cut is not compared.
    run_through(engine, end + (tolerance_ms / 1000.0 if recording.stop is None else 0.0))
    engine.finish_stats()
    divergence, compared = compare(recording.events, runtime.trace.events, end,
                                   tolerance_ms / 1000.0, cut=recording.stop is None)
    if refused is not None:  # the cause comes first: a fault the replay refused named only
        # the process's divergence it caused, "560 ms apart"
        divergence = refused[1] if divergence is None else f"{refused[1]}; then {divergence}"
    return ReplayResult(recording, runtime, warnings, divergence, compared)


def _key(event: EventDict) -> tuple[Any, ...]:
    own = COMPARED[event["event"]]
    return (event["event"], event.get("prog"), event.get("line"), event.get("n"),
            *(json.dumps(event.get(f), sort_keys=True) for f in own))


def _said(event: EventDict | None) -> str:
    if event is None:
        return "nothing (no such event)"
    where = ""
    if event.get("prog") and event.get("line") is not None:
        n = f" N{event['n']}" if event.get("n") is not None else ""
        where = f" at {event['prog']}:{event['line']}{n}"
    own = ", ".join(f"{f} {json.dumps(event.get(f))}" for f in COMPARED[event["event"]])
    return f"t={event['t']:.3f} {event['event']}{where} ({own})"


def _per_process(events: list[EventDict], end: float) -> dict[int, list[EventDict]]:
    out: dict[int, list[EventDict]] = {}
    for event in events:
        if event["proc"] and event["event"] in COMPARED and event["t"] <= end:
            out.setdefault(event["proc"], []).append(event)
    return out


def compare(recorded: list[EventDict], replayed: list[EventDict], end: float,
            tolerance_s: float, cut: bool = False) -> tuple[str | None, int]:
    """The first divergence (by recorded time) between two traces, and how many events were
    compared.  ``cut``: the recording ends abruptly at ``end`` (a killed session): what the
    replay does from ``end`` on -- or from within the tolerance before it, which the session
    may have done just after the cut -- was never seen, so it cannot diverge."""
    rec = _per_process(recorded, end)
    rep = _per_process(replayed, end + tolerance_s)
    first: tuple[float, str] | None = None
    compared = 0
    for proc in sorted(set(rec) | set(rep)):
        a, b = rec.get(proc, []), rep.get(proc, [])
        for i in range(max(len(a), len(b))):
            x = a[i] if i < len(a) else None
            y = b[i] if i < len(b) else None
            if x is not None and y is not None and _key(x) == _key(y) and (
                    abs(x["t"] - y["t"]) <= tolerance_s + 1e-9):
                compared += 1
                continue
            if x is None and y is not None and (
                    y["t"] > end or (cut and y["t"] + tolerance_s >= end)):
                break  # replayed past the recording's end: not seen in the session
            at = min(e["t"] for e in (x, y) if e is not None)
            text = (f"replay diverges at P{proc}'s event {i + 1}:\n"
                    f"  recorded: {_said(x)}\n  replayed: {_said(y)}")
            if x is not None and y is not None and _key(x) == _key(y):
                text += f"\n  (the same event, {abs(x['t'] - y['t']) * 1000:.1f} ms apart)"
            if first is None or at < first[0]:
                first = (at, text)
            break
    return (first[1] if first is not None else None), compared
