"""The trace's events (spec 4.4), typed: one immutable record per kind of event.

Each event is a ``NamedTuple`` -- typed, immutable and as cheap to build as a tuple, which
matters: every SND and WAI records events.  The first four fields are common: ``seq`` (1, 2,
...), ``t`` (simulated seconds), ``proc`` (0 for the PLC and the fieldbus) and ``where``
(program file, line, N) or None; the rest are the event's own.  Inside ncgate events stay typed
(the CANopen node reads an alarm's :class:`~ncgate.interpreter.codes.AlarmCode`, not a label);
:func:`as_dict` renders one as the JSON object of spec 4.4, and only the edges call it (the
trace file, ``Gateway.trace``, the Gantt picture).

Stdlib only.
"""

from __future__ import annotations

import json
from typing import Any, Final, NamedTuple

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine.states import WaitKind, Where


class Blocked(NamedTuple):
    """A process in a deadlock cycle or a stall: where it is blocked, and why."""

    proc: int
    prog: str
    line: int
    n: int | None
    reason: str


class WaitOn(NamedTuple):
    """What a ``wait`` event waits on: a process, a condition, an SND's target, an EXE's."""

    kind: WaitKind
    target: int = 0
    cond: str | None = None
    value: int | float | None = None
    name: str | None = None  # the condition's variable's I/O name ([symbols])


class SignalOn(NamedTuple):
    """What an ISG ``#WAIT`` waits on (spec 5.6): signal ``signal`` from the channels in
    ``from_`` (or "all": a broadcast), at the decoder ("dec") or the interpolator ("syn")."""

    signal: int
    from_: tuple[int, ...] | str
    level: str


class FlushOn(NamedTuple):
    """A ``#FLUSH WAIT`` (or a synchronous V.E. read): the decoder waits for its
    interpolator."""


class AuxOn(NamedTuple):
    """What an auxiliary function's handshake waits on ([nc.aux]): the PLC's acknowledge
    (``ack``, an SA bit) of ``code`` ("M8"), output with ``handshake``."""

    code: str
    handshake: str
    ack: str
    shown: str = ""  # as people write it ("M08"): the run log's (not in the trace)


class Start(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    prog: str
    by: int | str  # a process number (an EXE), or the input's source ("web 127.0.0.1", ...)

    @property
    def kind(self) -> str:
        return "start"


class Wait(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    on: WaitOn

    @property
    def kind(self) -> str:
        return "wait"


class Resume(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    by: int | str  # a process number, "cond" or "fieldbus"
    writer: str | None = None  # "cond": who wrote the value that released it ("plc", …)

    @property
    def kind(self) -> str:
        return "resume"


class Snd(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    to: int

    @property
    def kind(self) -> str:
        return "snd"


class Exe(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    to: int
    target_prog: str

    @property
    def kind(self) -> str:
        return "exe"


class End(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    how: str  # "REL", "M30", "M02", "eof", "reset"

    @property
    def kind(self) -> str:
        return "end"


class Write(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    var: str
    value: int
    who: str

    @property
    def kind(self) -> str:
        return "write"


class Alarm(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    code: AlarmCode
    message: str

    @property
    def kind(self) -> str:
        return "alarm"


class Deadlock(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    cycle: tuple[Blocked, ...]
    message: str

    @property
    def kind(self) -> str:
        return "deadlock"


class Stall(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    blocked: tuple[Blocked, ...]

    @property
    def kind(self) -> str:
        return "stall"


class Hazard(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    message: str

    @property
    def kind(self) -> str:
        return "hazard"


class Display(NamedTuple):
    seq: int
    t: float
    proc: int
    where: Where | None
    text: str

    @property
    def kind(self) -> str:
        return "display"


class Signal(NamedTuple):
    """An ISG ``#SIGNAL`` as it is sent (spec 5.6): to channels, or "all" (a broadcast)."""

    seq: int
    t: float
    proc: int
    where: Where | None
    id: int
    to: tuple[int, ...] | str
    count: int | None  # type: ignore[assignment]  # the spec's name; shadows tuple.count
    params: dict[int, float]
    level: str  # "dec" or "syn"

    @property
    def kind(self) -> str:
        return "signal"


class Remove(NamedTuple):
    """``#SIGNAL REMOVE``: how many stored signals it cleared."""

    seq: int
    t: float
    proc: int
    where: Where | None
    removed: int

    @property
    def kind(self) -> str:
        return "remove"


class Override(NamedTuple):
    """The process's overrides changed (percent): in force from the next interpolation step."""

    seq: int
    t: float
    proc: int
    where: Where | None
    feed: int
    rapid: int

    @property
    def kind(self) -> str:
        return "override"


class Break(NamedTuple):
    """A breakpoint was hit: the cell stops (feed-hold semantics; a cycle start goes on)."""

    seq: int
    t: float
    proc: int
    where: Where | None
    breakpoint: str

    @property
    def kind(self) -> str:
        return "break"


class Force(NamedTuple):
    """A variable forced (``value``) or released (``value`` None; ``var`` None: every one)."""

    seq: int
    t: float
    proc: int
    where: Where | None
    var: str | None
    value: int | None
    who: str

    @property
    def kind(self) -> str:
        return "force"


class Forced(NamedTuple):
    """A write a force overrode: ``value`` is what ``who`` tried to store."""

    seq: int
    t: float
    proc: int
    where: Where | None
    var: str
    value: int
    who: str

    @property
    def kind(self) -> str:
        return "forced"


class PlcReload(NamedTuple):
    """An online change of the PLC logic (``reload_plc``, ``run --watch``): ``ok`` False
    when the files did not load (``diagnostics``; the old logic runs on); else how many
    variables kept their value and the paths that start anew (``initial``) or are gone."""

    seq: int
    t: float
    proc: int
    where: Where | None
    ok: bool
    by: str
    files: list[str]
    kept: int
    initial: list[str]
    dropped: list[str]
    diagnostics: list[str]

    @property
    def kind(self) -> str:
        return "plc_reload"


class Aux(NamedTuple):
    """An auxiliary function output to the PLC ([nc.aux]): ``code`` ("M8", "T5"), its
    handshake ("none", "before_motion", "after_motion"), and where its value and strobe
    are."""

    seq: int
    t: float
    proc: int
    where: Where | None
    code: str
    handshake: str
    value: str  # its value's variable ("SYVAR192")
    strobe: str | None  # its strobe bit ("SA896"); None: a handshake of "none"

    @property
    def kind(self) -> str:
        return "aux"


class AuxAck(NamedTuple):
    """The PLC acknowledged an auxiliary function (``by``: who set the acknowledge); the NC
    drops its strobe next, then waits for the acknowledge to drop."""

    seq: int
    t: float
    proc: int
    where: Where | None
    code: str
    by: str | None

    @property
    def kind(self) -> str:
        return "aux_ack"


class Fault(NamedTuple):
    """A fault injected (docs/plant.md): its ``target`` (a plant model, an output, a
    variable, ``modbus``, ``canopen``), its kind (``kind`` in the trace: the field is named
    apart from the event's own ``kind``), its parameters, and who injected it."""

    seq: int
    t: float
    proc: int
    where: Where | None
    target: str
    fault_kind: str
    params: dict[str, Any]
    who: str

    @property
    def kind(self) -> str:
        return "fault"


class FaultClear(NamedTuple):
    """A fault cleared: by ``who``, or by its own ``for_s`` (``who`` names the fault)."""

    seq: int
    t: float
    proc: int
    where: Where | None
    target: str
    fault_kind: str
    who: str

    @property
    def kind(self) -> str:
        return "fault_clear"


class Stop(NamedTuple):
    """The process stopped after a block (``where``), until a cycle start (or a step):
    ``cause`` "single_block", "step", "M00", "M01" or "break" (a breakpoint's stop: at the
    block before the breakpoint's, or, for the other processes, after the block each was in)."""

    seq: int
    t: float
    proc: int
    where: Where | None
    cause: str

    @property
    def kind(self) -> str:
        return "stop"


class Step(NamedTuple):
    """A step was given to the process: it runs one more block and stops again."""

    seq: int
    t: float
    proc: int
    where: Where | None

    @property
    def kind(self) -> str:
        return "step"


class Hold(NamedTuple):
    """A feed hold of the process went on (``on``) or off (a cycle start): ``where`` is where
    its decoder stands (None: no program)."""

    seq: int
    t: float
    proc: int
    where: Where | None
    on: bool

    @property
    def kind(self) -> str:
        return "hold"


Event = (Start | Wait | Resume | Snd | Exe | End | Write | Alarm | Deadlock | Stall | Hazard
         | PlcReload
         | Display | Signal | Remove | Override | Break | Force | Forced | Aux | AuxAck
         | Fault | FaultClear | Stop | Step | Hold)
# A field whose JSON key differs from its name (an event's own ``kind`` is its type's).
_KEYS: Final = {"fault_kind": "kind"}
# Events that count on the fieldbus event counter (spec 3.2: input registers 2, 3); a signal
# counts like an SND (spec 5.6).
COUNTED: Final = frozenset({Start, End, Wait, Resume, Snd, Alarm, Signal})
_ON_KEY: Final = {WaitKind.PROC: "proc", WaitKind.SND: "snd", WaitKind.EXE: "exe"}


def as_dict(event: Event) -> dict[str, Any]:
    """The JSON object of spec 4.4 (``t`` rounded to 6 decimals), keys in the spec's order."""
    out: dict[str, Any] = {"seq": event.seq, "t": round(event.t, 6), "event": event.kind,
                           "proc": event.proc}
    where = event.where
    if where is not None:
        out["prog"], out["line"], out["n"] = where
    for name in event._fields[4:]:
        value = getattr(event, name)
        if value is None and name == "writer":
            continue  # only a condition's resume names the writer
        out[_KEYS.get(name, name)] = _json(value)
    return out


def as_line(event: Event) -> str:
    """``to_jsonl(as_dict(event))`` (interpreter/engine/trace.py), the trace file's line
    without its newline, made without the dict and the JSON encoder's machinery: the trace
    file and the console's streams render every event (4-5x faster; the tests compare the
    two on every kind of event)."""
    kind = type(event)
    names = _NAMES.get(kind)
    if names is None:
        names = _NAMES[kind] = [(n, f', "{_KEYS.get(n, n)}": ') for n in kind._fields[4:]]
    parts = [f'{{"seq": {event[0]}, "t": {round(event[1], 6):.6f}, "event": "{event.kind}", '
             f'"proc": {event[2]}']
    where = event[3]
    if where is not None:
        parts.append(f', "prog": {_text(where[0])}, "line": {_text(where[1])}, '
                     f'"n": {_text(where[2])}')
    for index, (name, key) in enumerate(names, 4):
        value = event[index]
        if value is None and name == "writer":
            continue
        parts.append(key)
        parts.append(_text(value))
    parts.append("}")
    return "".join(parts)


_NAMES: dict[type, list[tuple[str, str]]] = {}
_encode_string = json.encoder.encode_basestring  # the C one: what json.dumps uses
_DUMPS = json.JSONEncoder(separators=(", ", ": "), ensure_ascii=False).encode


def _text(value: Any) -> str:
    """``value`` as json.dumps(_json(value)) renders it in a trace line."""
    kind = type(value)
    if kind is str:
        return _encode_string(value)
    if kind is int:
        return int.__repr__(value)
    if value is None:
        return "null"
    if kind is float and value - value == 0.0:  # finite (nan and inf: as json.dumps has them)
        return float.__repr__(value)
    return _DUMPS(_json(value))


def _json(value: Any) -> Any:
    if isinstance(value, SignalOn):
        return {"signal": value.signal, "from": _json(value.from_), "level": value.level}
    if isinstance(value, FlushOn):
        return {"flush": True}
    if isinstance(value, AuxOn):
        return {"aux": value.code, "handshake": value.handshake, "ack": value.ack}
    if isinstance(value, WaitOn):
        if value.kind is WaitKind.COND:
            number = value.value
            if isinstance(number, float) and number == int(number):
                number = int(number)
            if value.name is not None:
                return {"cond": value.cond, "value": number, "name": value.name}
            return {"cond": value.cond, "value": number}
        return {_ON_KEY[value.kind]: value.target}
    if isinstance(value, AlarmCode):
        return value.label
    if isinstance(value, tuple) and value and isinstance(value[0], Blocked):
        return [b._asdict() for b in value]
    if isinstance(value, tuple):  # a signal's channels
        return list(value)
    if isinstance(value, dict):  # a signal's parameters: index -> value
        return {str(k): (int(v) if isinstance(v, float) and v.is_integer() else v)
                for k, v in value.items()}
    return value
