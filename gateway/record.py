"""A commissioning session on disk, and its replay on the virtual clock (``run --record``,
``sim --replay``).

The record is JSON Lines, in the order things happened:

- line 1, the header: ``{"ncgate_record": 1, "version", "config", "overrides", "time_scale",
  "programs": {file: sha256}}``: what the replay needs to run the same cell;
- an *input* line for everything that came from outside the cell, with its machine time:
  ``{"input": "write", "t", "who", "peer", "changes": [[area, index, view, value], ...]}``,
  ``"command"`` (``word``), ``"snd"`` (``from``, ``to``), ``"start"`` (``prog``, ``proc``),
  ``"alarm"`` (``code``, ``message``: a fieldbus alarm such as a lost CANopen master);
- every trace event of spec 4.4, as in a trace file (the lines with ``"seq"``);
- on a clean stop, ``{"stop": t}``.

The PLC logic's own writes are not inputs: the replay runs the same logic.  Lines are written
whole (:class:`~ncgate.gateway.tracefile.TraceFile`), so a record cut by ``kill -9`` ends on
a whole line and replays up to it.

:func:`replay` runs the recorded config and programs on the virtual clock, applies every input
at its time, and compares what each process did -- the blocks at which it started, waited,
resumed, sent, started another, raised an alarm or ended, in order, with times within a
tolerance -- against the recording.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ncgate import __version__
from ncgate.config import Config, ConfigError, load_config
from ncgate.gateway.errors import UsageError
from ncgate.gateway.plc import start_plc
from ncgate.gateway.tracefile import TraceFile
from ncgate.gateway.wiring import Runtime, apply_command, build_runtime
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import ProgramError, ProgramNotFoundError
from ncgate.interpreter.engine import run_virtual
from ncgate.interpreter.engine.events import Event
from ncgate.interpreter.engine.trace import EventDict

FORMAT = 1
# What is compared, per process, and the fields that must agree besides the block.
COMPARED: dict[str, tuple[str, ...]] = {
    "start": ("prog", "by"), "wait": ("on",), "resume": ("by",), "snd": ("to",),
    "exe": ("to", "target_prog"), "end": ("how",), "alarm": ("code",),
}
UNBOUNDED = 1 << 62  # a record is never rotated: it must stay whole


def program_files(config: Config) -> list[Path]:
    """Every file on the config's storage devices (the programs a session can run)."""
    out: list[Path] = []
    for folder in dict.fromkeys(config.nc.storage.devices.values()):
        if folder.is_dir():
            out += [path for path in sorted(folder.iterdir())
                    if path.is_file() and not path.name.startswith(".")]
    return out


def program_hashes(config: Config) -> dict[str, str]:
    """sha256 of every program file on the config's storage devices, by path."""
    return {str(path): hashlib.sha256(path.read_bytes()).hexdigest()
            for path in program_files(config)}


class SessionRecorder:
    """Writes one session: the header at once, then inputs and trace events as they come."""

    def __init__(self, path: str | Path, config: Config, overrides: dict[str, Any],
                 loop: asyncio.AbstractEventLoop | None = None) -> None:
        self.path = Path(path)
        self._file = TraceFile(self.path, UNBOUNDED, 0, loop=loop, fresh=True)
        header = {"ncgate_record": FORMAT, "version": __version__,
                  "config": str(config.source) if config.source else None,
                  "overrides": overrides, "time_scale": config.nc.time_scale,
                  "programs": program_hashes(config)}
        self._file.append(json.dumps(header) + "\n")
        self._file.flush()

    def event(self, event: Event) -> None:
        """A trace listener."""
        self._file.write(event)

    def input(self, kind: str, t: float, **fields: Any) -> None:
        self._file.append(json.dumps({"input": kind, "t": round(t, 6), **fields}) + "\n")

    def close(self, t: float) -> None:
        self._file.append(json.dumps({"stop": round(t, 6)}) + "\n")
        self._file.close()


@dataclass
class Recording:
    path: Path
    header: dict[str, Any]
    inputs: list[dict[str, Any]] = field(default_factory=list)
    events: list[EventDict] = field(default_factory=list)
    stop: float | None = None  # None: the session did not stop cleanly (killed)

    @property
    def end(self) -> float:
        """Where the replay stops: the clean stop, else the last thing recorded."""
        if self.stop is not None:
            return self.stop
        times = [i["t"] for i in self.inputs[-1:]] + [e["t"] for e in self.events[-1:]]
        return max(times, default=0.0)


def read_record(path: str | Path) -> Recording:
    """A record file; UsageError naming the file and line when it is not one."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise UsageError(f"{path}: {exc.strerror}") from None
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    recording: Recording | None = None
    for number, line in enumerate(lines, start=1):
        try:
            item = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines) and not text.endswith("\n"):
                break  # a tail cut by a crash of the writer: replay up to it
            raise UsageError(f"{path}:{number}: not a JSON line") from None
        if not isinstance(item, dict):
            raise UsageError(f"{path}:{number}: not a JSON object")
        if recording is None:
            if item.get("ncgate_record") != FORMAT:
                raise UsageError(f"{path}:1: not an ncgate session record (ncgate run "
                                 "--record writes one)")
            recording = Recording(path, item)
        elif "input" in item:
            recording.inputs.append(item)
        elif "seq" in item:
            recording.events.append(item)
        elif "stop" in item:
            recording.stop = float(item["stop"])
        else:
            raise UsageError(f"{path}:{number}: neither an input, an event nor the stop")
    if recording is None:
        raise UsageError(f"{path}: empty: not an ncgate session record")
    return recording


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


def replay(path: str | Path, config: str | Path | None = None,
           tolerance_ms: float = 10.0) -> ReplayResult:
    """Re-run a recorded session on the virtual clock and compare it with the recording.

    ``config``: the config file to use instead of the recorded one (a record taken home,
    where the files lie elsewhere)."""
    if not tolerance_ms >= 0 or math.isinf(tolerance_ms):
        raise UsageError(f"--tolerance-ms: expected a number >= 0, got {tolerance_ms}")
    recording = read_record(path)
    header = recording.header
    overrides = dict(header.get("overrides") or {})
    source = config if config is not None else header.get("config")
    try:
        cfg = load_config(source, overrides=overrides)
    except ConfigError as exc:
        raise UsageError(f"the recorded config: {exc}") from None
    warnings = []
    now = program_hashes(cfg)
    for file, digest in sorted((header.get("programs") or {}).items()):
        name = Path(file).name
        found = now.get(file) or next((d for f, d in now.items() if Path(f).name == name), None)
        if found is None:
            warnings.append(f"{file}: recorded but not found now")
        elif found != digest:
            warnings.append(f"{file}: changed since the recording")
    runtime = build_runtime(cfg, closed=False)  # as in `run`: the fieldbus may start programs
    engine = runtime.engine
    plc = start_plc(cfg, engine, runtime.image, closed=True)
    runtime.plc = plc[0] if plc is not None else None
    end = recording.end
    for item in sorted(recording.inputs, key=lambda i: i["t"]):  # stable: same-time order
        t = float(item["t"])
        run_virtual(engine, t)
        if engine.now < t:
            engine.set_time(t)
        _apply(runtime, item)
        engine.run_until_blocked()
    run_virtual(engine, end)
    engine.finish_stats()
    divergence, compared = compare(recording.events, runtime.trace.events, end,
                                   tolerance_ms / 1000.0, cut=recording.stop is None)
    return ReplayResult(recording, runtime, warnings, divergence, compared)


def _apply(runtime: Runtime, item: dict[str, Any]) -> None:
    engine, kind = runtime.engine, item["input"]
    try:
        if kind == "write":
            runtime.image.write([tuple(c) for c in item["changes"]],
                                item["who"])
        elif kind == "command":
            apply_command(engine, int(item["word"]), runtime.plc)
        elif kind == "snd":
            engine.external_snd(int(item["from"]), int(item["to"]))
        elif kind == "start":
            engine.start(item["prog"], int(item["proc"]), by=item.get("by", "operator"))
        elif kind == "alarm":
            engine.fieldbus_alarm(AlarmCode[item["code"]], item["message"])
    except (ValueError, KeyError, ProgramError, ProgramNotFoundError) as exc:
        # As in the session, where the input was refused and changed nothing; a changed
        # program shows as a divergence, not here.
        engine.note_hazard(0, f"replay: recorded {kind} input not applied: {exc}")


def _key(event: EventDict) -> tuple[Any, ...]:
    own = COMPARED[event["event"]]
    return (event["event"], event.get("prog"), event.get("line"), event.get("n"),
            *(json.dumps(event.get(f), sort_keys=True) for f in own))


def _said(event: EventDict | None) -> str:
    if event is None:
        return "nothing (no such event)"
    where = ""
    if event.get("prog"):
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
    replay does from ``end`` on was never seen, so it cannot diverge."""
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
            if x is None and y is not None and (y["t"] > end or (cut and y["t"] >= end)):
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
