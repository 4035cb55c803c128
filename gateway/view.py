"""The cell as the adapters read it: one immutable :class:`CellView`, and the one encoding of
a process's status that the Modbus map, the CANopen node and the console share.

The loop owns the engine and the image (ARCHITECTURE.md, "The runtime").  An adapter reads
the cell through :attr:`ncgate.gateway.Gateway.view`, which the loop builds when someone asks
for it and something changed since the last one (:class:`ViewPublisher`): once however many
requests read it, and never in ``ncgate sim`` or a gateway nobody reads.  A reader that shows
a part takes that part (:attr:`ncgate.gateway.Gateway.views`: one process's view, the cell's
status beside the processes, the image, the plant), each kept at the same moment as the
whole.  What a view holds never changes, so a view may be handed to another thread (the
CANopen node publishes from one to python-can's receive thread) and kept as long as it is
wanted: the image is a :class:`~ncgate.plc.image.FrozenImage` (copied when read, or before
the next write while something holds it), the plant a :class:`PlantView`.

The encoding, once (spec 2.1, 3.2 and 3.3; README.md's Modbus map, the CANopen dictionary of
``ncgate map``):

- :attr:`ProcessView.record`: state code, block N, source line, wait kind, wait target, alarm
  code, SNDs sent, SNDs received, blocks executed, X, Y and Z in µm.  N, the line and the
  alarm code as 16 bits, the counters as 32, the positions as int32 saturating at its bounds.
  The Modbus status block is this record with each 32-bit value as two registers, high word
  first (:func:`status_registers`); the CANopen status record 0x2500+k-1 is its first eight.
- :attr:`ProcessView.flags`: program loaded, running, waiting, alarm, motion active, hold.
- :attr:`ProcessView.wait` and :attr:`ProcessView.standing`: why it waits or stands, as the
  console says it.
- :func:`plant_status`: the plant (:class:`PlantView`) as the console's ``/api/status``,
  ``Plant.status()`` and the OPC UA plant nodes show it.

Imports the engine's and the PLC's types; nothing of a fieldbus or a web library.
"""

from __future__ import annotations

import asyncio
import weakref
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

from ncgate.gateway.plc import plc_registers
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import Process, ProcessState, ProcessStatus, WaitKind
from ncgate.interpreter.engine.states import Where
from ncgate.plc.image import FrozenImage

if TYPE_CHECKING:
    from ncgate.gateway.plant import Plant
    from ncgate.gateway.plant.models import Model
    from ncgate.gateway.wiring import Backend

# The process flags (Modbus discrete inputs 16(k-1)+0..5), in their order.
FLAGS = ("program loaded", "running", "waiting", "alarm", "motion active", "hold")
# The status record's entries, in their order, with the bits each has on the fieldbus (a
# position is an int32).
RECORD = (("state code", 16), ("block N", 16), ("source line", 16), ("wait kind", 16),
          ("wait target", 16), ("alarm code", 16), ("SNDs sent", 32), ("SNDs received", 32),
          ("blocks executed", 32), ("X µm", 32), ("Y µm", 32), ("Z µm", 32))
CANOPEN_RECORD = 8  # 0x2500+k-1 sub 1..8: the record's first eight
# On the wall clock a model's stroke moves on between the engine's moments: while one moves,
# the plant's view is built again when read this long (machine time) after the last.
PLANT_FRESH_S = 0.01

_RUNNING = frozenset((ProcessState.RUNNING, ProcessState.DWELL))
_WAITING = frozenset((ProcessState.WAIT_PROC, ProcessState.WAIT_COND, ProcessState.WAIT_SND,
                      ProcessState.WAIT_EXE))
# A stop after a block, by its cause (Process.stopped), as the console says it.
STOPPED = {"break": "breakpoint", "single_block": "single block", "step": "step",
           "M00": "M00 (program stop)", "M01": "M01 (optional stop)"}


class WaitView(NamedTuple):
    """Why a process waits (spec 2.2.6), as of the view: the condition's value and its last
    writer as they were when the view was built."""

    kind: WaitKind
    code: str
    target: int
    cond: str | None
    value: float | None
    writer: str | None
    since: float
    reason: str
    where: Where


class AlarmView(NamedTuple):
    code: int
    message: str  # with the alarm's place first
    where: Where | None

    @property
    def label(self) -> str:
        return AlarmCode(self.code).label


class ProcessView(NamedTuple):
    """One process as every adapter shows it.  (A NamedTuple, not a frozen dataclass: a view
    is built on the path of a fieldbus read after a change, and a frozen dataclass's 24
    fields took 4 us of its 12 to set.)"""

    number: int
    state: ProcessState
    external: bool
    program: str | None
    line: int
    n: int | None
    block: str  # the source line's text ("" none)
    blocks: int
    snd_sent: int
    snd_received: int
    position: tuple[float, ...]  # X, Y, Z (mm)
    moving: bool
    held: bool
    loaded: bool
    stopped: str | None  # why it stands after a block (Process.stopped)
    standing: str | None  # why it stands until a cycle start, as the console says it
    single_block: bool
    feed: float | None  # the modal feed (mm/min)
    feed_override: int
    rapid_override: int
    wait: WaitView | None  # None also while IDLE (a wait left from before means nothing)
    alarm: AlarmView | None
    record: tuple[int, ...]  # the status record (module docstring)
    flags: tuple[bool, ...]  # FLAGS

    @property
    def canopen_record(self) -> tuple[int, ...]:
        """0x2500+k-1 sub 1..8."""
        return self.record[:CANOPEN_RECORD]


class PlcView(NamedTuple):
    """The PLC logic's status, copied (the runtime's own record changes every scan)."""

    state: str
    scans: int
    last_scan_us: int
    max_scan_us: int
    overruns: int
    last_lateness_us: int
    max_lateness_us: int
    fault: str | None


class ModelView(NamedTuple):
    """One plant model (docs/plant.md) as of the view: what it is doing and since when, in
    words (``detail``: its why-record, ``Model.describe``), the faults on it, the variables
    it reads and writes (key -> variable)."""

    name: str
    kind: str
    state: str
    since: float
    detail: str
    fault: str | None  # the kinds of the faults on it, comma-separated
    reads: tuple[tuple[str, str], ...]
    writes: tuple[tuple[str, str], ...]


class FaultView(NamedTuple):
    """A fault in force (``ActiveFault``): its parameters as it was given them."""

    target: str
    kind: str
    params: tuple[tuple[str, Any], ...]
    by: str
    since: float


class PlantLogicView(NamedTuple):
    """The plant's own ST logic ([plant] logic)."""

    state: str
    scans: int
    max_scan_us: int
    fault: str | None


class PlantView(NamedTuple):
    """The plant as of the view (what ``Plant.status()`` encodes: :func:`plant_status`)."""

    models: tuple[ModelView, ...]
    faults: tuple[FaultView, ...]
    scan_ms: int
    stretch: int  # the tick's period in scans (run: stretched by the budget)
    logic: PlantLogicView | None


class CellStatus(NamedTuple):
    """What the cell shows beside its processes, as of one moment of the loop: the
    :class:`CellView` without ``processes`` (a reader of the PLC status block builds no
    process's view)."""

    t: float
    last_snd: tuple[int, int, int, int]
    snd_seq: int
    snd_log: tuple[tuple[int, int, int, int, int], ...]
    events: int
    plc: PlcView | None
    plc_registers: tuple[int, ...]
    forced: tuple[tuple[tuple[str, int, str], int], ...]
    lag_s: float


class CellView(NamedTuple):
    """The cell as of one moment of the loop (a NamedTuple, as :class:`ProcessView`): its
    :class:`CellStatus` with the processes after ``t``, and the image and the plant."""

    t: float  # machine time
    processes: tuple[ProcessView, ...]  # process k at [k - 1]
    last_snd: tuple[int, int, int, int]  # sender, target, block N, event number (0s: none)
    snd_seq: int  # the newest SND's sequence number (0: none yet)
    # The last SNDs, oldest first: (sequence, sender, target, block N, id).
    snd_log: tuple[tuple[int, int, int, int, int], ...]
    events: int  # the event counter (COUNTED events, 32 bits)
    plc: PlcView | None  # None: no logic
    plc_registers: tuple[int, ...]  # the PLC status block (gateway.plc.PLC_REGISTERS)
    forced: tuple[tuple[tuple[str, int, str], int], ...]  # ((area, index, view), value), sorted
    lag_s: float  # machine seconds behind the clock
    # The image's values and last writers, taken when read (or before the next write while
    # this view is held); never copied for a view whose image nobody reads.
    image: FrozenImage
    plant: PlantView | None  # None: no plant


def status_registers(p: ProcessView) -> list[int]:
    """The Modbus status block of a process (spec 3.2): the record, each 32-bit value as two
    registers, high word first."""
    out: list[int] = []
    for value, (_, bits) in zip(p.record, RECORD, strict=True):
        if bits == 32:
            value &= 0xFFFFFFFF
            out += (value >> 16, value & 0xFFFF)
        else:
            out.append(value)
    return out


def int32(value: float) -> int:
    """A value as an int32 holds it: rounded, and saturated at the bounds rather than wrapped
    (a position past +-2,147 m reads as the bound, never as a position of the other sign, and
    an infinite one does not fail the read); NaN is 0."""
    if value != value:  # NaN: no position to show
        return 0
    return round(min(max(value, -0x8000_0000), 0x7FFF_FFFF))


def build(backend: Backend, processes: tuple[ProcessView, ...] | None = None,
          cell: CellStatus | None = None, plant: PlantView | None = None) -> CellView:
    """The view of the cell as it is now (on the loop); ``processes``, ``cell`` and
    ``plant``: built already (:meth:`ViewPublisher.process`, :meth:`ViewPublisher.status`,
    :meth:`ViewPublisher.plant`)."""
    if processes is None:
        processes = tuple(_process(backend, p) for p in backend.engine.processes.values())
    if cell is None:
        cell = cell_status(backend)
    if plant is None and backend.runtime.plant is not None:
        plant = plant_view(backend.runtime.plant)
    return CellView(cell.t, processes, *cell[1:], backend.image.frozen(), plant)


# What each plant model reads and writes, as the view shows it (fixed when the plant is
# built: made once, not with every view -- it was two thirds of a model's 2.7 us).
_MODEL_IO: weakref.WeakKeyDictionary[Model, tuple[tuple[tuple[str, str], ...],
                                                  tuple[tuple[str, str], ...]]]
_MODEL_IO = weakref.WeakKeyDictionary()


def plant_view(plant: Plant, now: float | None = None) -> PlantView:
    """The plant as it is at ``now`` (on the loop; None: now, the driver's clock's on the
    wall clock, which a stroke's progress follows between the engine's moments)."""
    if now is None:
        now = plant.runtime.engine.read_time()
    faults = plant.faults
    on: dict[str, list[str]] = {}  # model -> the kinds of the faults on it
    for f in faults:
        on.setdefault(f.target.split(".")[0], []).append(f.kind)
    models = []
    for name, model in plant.models.items():
        io = _MODEL_IO.get(model)
        if io is None:
            variables = plant.variables[name]
            io = _MODEL_IO[model] = (
                tuple((k, str(v)) for k, v in variables.items() if k in model.inputs),
                tuple((k, str(v)) for k, v in variables.items() if k in model.outputs_keys))
        kinds = on.get(name)
        models.append(ModelView(name, model.kind, model.state, model.since,
                                model.describe(now), ", ".join(kinds) if kinds else None,
                                *io))
    logic = None
    if plant.logic is not None:
        st = plant.logic.status
        logic = PlantLogicView(st.state.name, st.scans, st.max_scan_us,
                               None if st.fault is None else str(st.fault))
    return PlantView(
        tuple(models), tuple(FaultView(f.target, f.kind, tuple(f.params.items()), f.who,
                                       f.since) for f in faults),
        plant.runtime.config.plant.scan_ms, plant.stretch, logic)


def plant_status(view: PlantView) -> dict[str, Any]:
    """The plant as JSON has it: the console's and ``/api/status``'s ``plant``, and
    ``Plant.status()`` -- each model, the faults in force, the tick and the plant's logic."""
    logic = view.logic
    return {
        "models": [{"name": m.name, "kind": m.kind, "state": m.state,
                    "since": round(m.since, 6), "detail": m.detail, "fault": m.fault,
                    "reads": dict(m.reads), "writes": dict(m.writes)} for m in view.models],
        "faults": [{"target": f.target, "kind": f.kind, "params": dict(f.params), "by": f.by,
                    "since": round(f.since, 6)} for f in view.faults],
        "scan_ms": view.scan_ms, "stretch": view.stretch,
        "logic": None if logic is None else {
            "state": logic.state, "scans": logic.scans, "max_scan_us": logic.max_scan_us,
            "fault": logic.fault}}


def cell_status(backend: Backend) -> CellStatus:
    """The cell's status beside its processes, as it is now (on the loop)."""
    engine = backend.engine
    status = backend.plc_status
    plc = None if status is None else PlcView(
        status.state.name, status.scans, status.last_scan_us, status.max_scan_us,
        status.overruns, status.last_lateness_us, status.max_lateness_us,
        str(status.fault) if status.fault is not None else None)
    forced = backend.image.forced
    return CellStatus(
        engine.now, engine.last_snd or (0, 0, 0, 0), engine.snd_seq, tuple(engine.snd_log),
        engine.trace.counter, plc, tuple(plc_registers(status)),
        tuple(sorted(forced.items())) if forced else (), backend.lag_s)


def _signature(p: Process) -> tuple[object, ...] | None:
    """What a process's view is made of, cheaply (a tenth of building it): the same signature,
    the same view.  None when the view may change with nothing here changing: while it moves
    (its position follows the clock), while a feed hold is on (the interlock input says why)
    and in a wait whose why-record reads something live (a condition's value and writer, a
    dialect's own wording)."""
    item = p.int_move
    if (item is not None and item.move is not None and p.int_remaining is None) or p.held:
        return None  # (a dwell or a paused move stands where it is)
    for wait in (p.int_wait, p.dec_wait):
        if wait is not None and (wait.kind is WaitKind.COND or wait.probe is not None
                                 or callable(wait.text)):
            return None
    stats = p.stats
    return (p.state, p.where, p.alarm, stats.blocks, stats.snd_sent, stats.snd_received,
            p.int_wait, p.dec_wait, p.stopped, p.single_block, p.feed_override,
            p.rapid_override, p.loaded, p.modal.feed_mm_min, p.motion_active, item,
            p.int_remaining)


def _process(backend: Backend, p: Process) -> ProcessView:
    s = backend.engine.status(p.number)
    state = s.state
    block = ""
    lines = p.loaded.program.lines if p.loaded is not None else ()
    if 1 <= s.line <= len(lines):
        block = lines[s.line - 1].strip()
    wait = None
    w = s.wait
    if w is not None and state is not ProcessState.IDLE:
        value, writer = w.probe() if w.probe is not None else (w.value, w.writer)
        wait = WaitView(w.kind, w.code, w.target, w.cond, value, writer, w.since, w.reason(),
                        w.where)
    alarm = (AlarmView(s.alarm_code, s.alarm_message, s.alarm_where)
             if s.alarm_message is not None else None)
    loaded = p.loaded is not None
    record, flags = encode(s, loaded)
    # (positional: a view is built on the path of a fieldbus read after a change)
    return ProcessView(
        p.number, state, s.external, s.program, s.line, s.n, block, s.blocks, s.snd_sent,
        s.snd_received, tuple(s.position[:3]), s.motion_active, s.held, loaded, p.stopped,
        _standing(backend, p), p.single_block, p.modal.feed_mm_min, p.feed_override,
        p.rapid_override, wait, alarm, record, flags)


def state_code(state: ProcessState) -> int:
    """A state's code on the fieldbus (docs/runtime.md): its value."""
    return state.value


def encode(s: ProcessStatus, loaded: bool) -> tuple[tuple[int, ...], tuple[bool, ...]]:
    """A process's status record and flags (the module docstring), from its status and
    whether a program is loaded."""
    state, w = s.state, s.wait
    x, y, z = s.position[:3]
    record = (state_code(state), (s.n or 0) & 0xFFFF, s.line & 0xFFFF,
              w.kind.value if w is not None else 0, w.target if w is not None else 0,
              s.alarm_code & 0xFFFF, s.snd_sent & 0xFFFFFFFF, s.snd_received & 0xFFFFFFFF,
              s.blocks & 0xFFFFFFFF, int32(x * 1000), int32(y * 1000), int32(z * 1000))
    flags = (loaded, state in _RUNNING, state in _WAITING, state is ProcessState.ALARM,
             s.motion_active, s.held)
    return record, flags


def _standing(backend: Backend, p: Process) -> str | None:
    """Why process ``p`` stands until a cycle start: a breakpoint, single block, a step,
    M00/M01, the PLC's interlock input (``nc.feed_hold_input``) or a feed hold; None when it
    does not stand for any of them."""
    if p.stopped is not None:
        return STOPPED.get(p.stopped, p.stopped)
    if not p.held:
        return None
    image = backend.image
    for what, var in backend.runtime.interlocks:
        if what == "feed hold" and image.read(*var.address):
            return f"interlock {var}"
    return "feed hold"


class ViewPublisher:
    """Builds the :class:`CellView` on the loop when it is asked for and the cell changed.

    A change is one of: a turn of the engine's driver ended (blocks run, timers fired: N,
    the line, the counters, the PLC's scans, the plant), an event was recorded (an SND, a
    wait, an alarm, an image write, a force), or a process changed its state (a state
    listener: a TPDO built inside the change sees it).  Reading those is three integers; a
    view is built at most once between two changes, however many requests read it.  While a
    process moves, its position changes with the clock alone: a view that shows one moving
    lasts until the loop's next iteration.

    A reader inside the engine's turn that wants one process or the last SND (the CANopen
    node's event-driven TPDOs, built inside each state change and each SND) takes just that
    (:meth:`process`, :meth:`last_snd`): the whole view after every event cost the SND ->
    TPDO2 path 63 us at p50 (bench/canopen_node.py).  A process's view is kept while its
    signature (:func:`_signature`) is the same.

    The image is the image's own frozen one (:meth:`~ncgate.plc.image.IOImage.frozen`: the
    same object until the next write, copied only when read, or before that write while a
    view holding it is held elsewhere); before a write the publisher drops the view it keeps,
    whose moment is over, so that a view nobody holds is never copied."""

    def __init__(self, backend: Backend, turns: Callable[[], int]) -> None:
        self._backend = backend
        self._engine = backend.engine
        self._turns = turns
        self._trace = backend.engine.trace
        self._changes = 0
        self._key: tuple[int, int, int] | None = None
        self._view: CellView | None = None  # the whole view at _key, once built
        self._status: CellStatus | None = None  # the cell's status at _key, once built
        self._plant: tuple[PlantView | None] | None = None  # the plant's view at _key, once
        self._plant_at = 0.0  # the time it shows
        self._processes: dict[int, ProcessView] = {}  # those built at _key
        # Each process's last view and what it was built from (its signature).
        self._kept: dict[int, tuple[tuple[object, ...], ProcessView]] = {}
        self._loop = asyncio.get_running_loop()
        self._expiring = False
        self._listeners = backend.engine.state_listeners
        # First of them: a listener that reads the view (the CANopen node building a TPDO
        # on a state change) must find it stale, whenever it subscribed.
        self._listeners.insert(0, self._changed)
        self._unfreeze = backend.image.before_freeze(self._drop)

    def _drop(self) -> None:
        """The image is about to be written: what is kept is of the moment before."""
        self._key = None
        self._view = None

    def _changed(self, process: Process | None, old: ProcessState) -> None:
        self._changes += 1

    def _expire(self) -> None:
        self._expiring = False
        self._key = None

    def close(self) -> None:
        if self._changed in self._listeners:
            self._listeners.remove(self._changed)
        self._unfreeze()
        self._unfreeze = lambda: None

    def _fresh(self) -> None:
        """Forget what was built before the cell changed."""
        key = (self._turns(), self._trace.seq, self._changes)
        if key != self._key:
            self._key = key
            self._view = None
            self._status = None
            self._plant = None
            self._processes = {}

    def current(self) -> CellView:
        self._fresh()
        view = self._view
        plant = self.plant()
        if view is None or view.plant is not plant:
            view = self._view = build(self._backend, tuple(
                self.process(k) for k in self._engine.processes), self.status(), plant)
        return view

    def status(self) -> CellStatus:
        """The cell's status beside its processes as of now (what :meth:`current` shows)."""
        self._fresh()
        cell = self._status
        if cell is None:
            cell = self._status = cell_status(self._backend)
        return cell

    def plant(self) -> PlantView | None:
        """The plant's view as of now (:attr:`CellView.plant`; None: no plant)."""
        self._fresh()
        kept = self._plant
        plant = self._backend.runtime.plant
        now = self._engine.read_time()
        if kept is not None and plant is not None and self._engine.clock is not None and (
                now - self._plant_at >= PLANT_FRESH_S and plant.moving):
            kept = None  # a stroke went on since, with no event of the engine's to say so
        if kept is None:
            self._plant_at = now
            kept = self._plant = (None if plant is None else plant_view(plant, now),)
        return kept[0]

    def image(self) -> FrozenImage:
        """The image as of now (:attr:`CellView.image`): taken when read."""
        return self._backend.image.frozen()

    def process(self, k: int) -> ProcessView:
        """Process ``k``'s view as of now (what :meth:`current` would show of it)."""
        self._fresh()
        view = self._processes.get(k)
        if view is not None:
            return view
        p = self._engine.processes[k]
        signature = _signature(p)
        kept = self._kept.get(k)
        if signature is not None and kept is not None and kept[0] == signature:
            view = kept[1]
        else:
            view = _process(self._backend, p)
            if signature is not None:
                self._kept[k] = (signature, view)
            else:
                self._kept.pop(k, None)
                if view.moving and not self._expiring:
                    self._expiring = True
                    self._loop.call_soon(self._expire)
        self._processes[k] = view
        return view

    def record(self, k: int) -> tuple[int, ...]:
        """Process ``k``'s status record as of now (:attr:`ProcessView.record`), from its
        view when one was built since the last change, else encoded alone: the CANopen node
        publishes the records of the processes it heard change after every engine turn,
        and building their whole views there put a quarter more on the quiet storm's CPU
        (bench/storm.py: 31-33 -> 40-43 %)."""
        self._fresh()
        view = self._processes.get(k)
        if view is not None:
            return view.record
        return encode(self._engine.status(k), self._engine.processes[k].loaded is not None)[0]

    def state(self, k: int) -> int:
        """Process ``k``'s state code as of now (its record's first entry), without building
        its view: a TPDO of the states is built inside every state change, and building
        the changing process's view there cost the SND -> TPDO2 path 50 us at p50."""
        return state_code(self._engine.processes[k].state)

    def last_snd(self) -> tuple[int, int, int, int]:
        """The last SND as of now: sender, target, block N, event number (0s: none)."""
        return self._engine.last_snd or (0, 0, 0, 0)

    def plc_registers(self) -> list[int]:
        """The PLC status block as of now (:attr:`CellView.plc_registers`)."""
        return plc_registers(self._backend.plc_status)
