"""What the OPC UA nodes show, read on the gateway's loop and handed whole to the server's
process (ARCHITECTURE.md, "The runtime"): the same rule as the CANopen node's snapshot, the
server never touches the engine or the image.

Pure data and the loop's side only; no asyncua here (``server.py`` owns the nodes).  The
mappings from a process's state to the companion specifications' enumerations are here, once:

- OPC 40501-1 ``ChannelState`` (Active 0, Interrupted 1, Reset 2): IDLE is Reset; HOLD, STEP
  (single block, a step, M00/M01, a breakpoint) and ALARM are Interrupted; the rest -- it runs,
  waits or dwells -- is Active.
- OPC 40502 ``CncChannelProgramStatus`` (Stopped 0, Running 1, Waiting 2, Interrupted 3,
  Canceled 4): IDLE Stopped; a wait (WAI, ``#WAIT``, an SND, an EXE, an auxiliary function's
  acknowledge) and a dwell (DLY, G4) Waiting; HOLD and a stop after a block Interrupted; ALARM
  Canceled (the program is abandoned until a reset); RUNNING Running.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from ncgate.inputs import Var
from ncgate.interpreter.engine import ProcessState

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.interpreter.engine import Process

ACTIVE, INTERRUPTED, RESET = 0, 1, 2  # ChannelState (OPC 40501-1)
STOPPED, RUNNING, WAITING, PROGRAM_INTERRUPTED, CANCELED = 0, 1, 2, 3, 4  # 40502


class Enumeration(NamedTuple):
    """A companion specification's enumeration DataType: its browse name and its values'
    names by value 0, 1, ... (tests/integration/opcua/test_nodesets.py holds them to the
    published nodesets).  A variable of it is typed by it and holds an Int32."""

    name: str
    names: tuple[str, ...]

    def values(self) -> str:
        """``0 Active, 1 Interrupted, 2 Reset``."""
        return ", ".join(f"{i} {name}" for i, name in enumerate(self.names))


CHANNEL_STATE = Enumeration("ChannelState", ("Active", "Interrupted", "Reset"))  # 40501-1
CHANNEL_MODE = Enumeration("ChannelMode", (
    "Automatic", "MdaMdi", "JogManual", "JogIncrement", "TeachingHandle", "Remote",
    "Reference", "Other"))  # 40501-1; ncgate's channels are always Automatic
CNC_CHANNEL_STATUS = Enumeration("CncChannelStatus", CHANNEL_STATE.names)  # 40502 ActStatus
CNC_PROGRAM_STATUS = Enumeration("CncChannelProgramStatus", (
    "Stopped", "Running", "Waiting", "Interrupted", "Canceled"))  # 40502 ActProgramStatus

_CHANNEL_STATE = {ProcessState.IDLE: RESET, ProcessState.HOLD: INTERRUPTED,
                  ProcessState.STEP: INTERRUPTED, ProcessState.ALARM: INTERRUPTED}
_PROGRAM_STATUS = {ProcessState.IDLE: STOPPED, ProcessState.RUNNING: RUNNING,
                   ProcessState.WAIT_PROC: WAITING, ProcessState.WAIT_COND: WAITING,
                   ProcessState.WAIT_SND: WAITING, ProcessState.WAIT_EXE: WAITING,
                   ProcessState.DWELL: WAITING, ProcessState.HOLD: PROGRAM_INTERRUPTED,
                   ProcessState.STEP: PROGRAM_INTERRUPTED, ProcessState.ALARM: CANCELED}


def channel_state(state: ProcessState) -> int:
    return _CHANNEL_STATE.get(state, ACTIVE)


def program_status(state: ProcessState, stopped: bool) -> int:
    if stopped and state is not ProcessState.ALARM:
        return PROGRAM_INTERRUPTED  # M00/M01, a breakpoint, single block
    return _PROGRAM_STATUS[state]


class ProcessView(NamedTuple):
    """One process as its nodes show it (a NamedTuple: compared whole to see a change)."""

    number: int
    state: str  # ProcessState's name (the vendor node ``State``, as /api/status says it)
    channel_state: int
    program_status: int
    program: str
    line: int
    n: int
    blocks: tuple[str, str, str]  # the previous, current and next block's text
    feed: float
    feed_override: int
    rapid_override: int
    position: tuple[float, float, float]


class StateView(NamedTuple):
    """What a process's change of state shows at once: its state's nodes and its program's
    name.  The rest of its view (line, blocks, feed, position) is sampled (``SAMPLE_S``):
    building the whole of it at every change cost the loop a fifth of its time under an
    SND/WAI loop at a kilohertz (bench/storm.py's OPC UA phase)."""

    number: int
    state: str
    channel_state: int
    program_status: int
    program: str


def state_view(process: Process) -> StateView:
    """``process``'s state as its nodes show it, read from the engine's process: what
    :func:`process_view` says of its state, without the rest."""
    loaded = process.loaded
    return _state(process.number, process.state, process.stopped is not None,
                  loaded.program.name if loaded is not None else "")


def _state(number: int, state: ProcessState, stopped: bool, program: str) -> StateView:
    """The one encoding of a process's state for its nodes (a ProcessView begins with it)."""
    return StateView(number, state.name, channel_state(state), program_status(state, stopped),
                     program)


class EventView(NamedTuple):
    """An alarm (an ``AlertType`` event) or a part program's message (DIS: a
    ``CncMessageType`` event)."""

    alarm: bool
    process: int
    code: str  # ``AL141``; "" for a message
    message: str
    severity: int


class PlcView(NamedTuple):
    state: str
    scans: int
    fault: str


# The view of each area that is a node of the image namespace (a bit, a byte, a word).
SHOWN_VIEW = {"SA": "bit", "SK": "BY", "SYVAR": "IN"}

ALARM_SEVERITY = 700  # OPC 10000-5 6.4.2 ranges: 667..800 is "high"
MESSAGE_SEVERITY = 300  # "medium low": information for the operator


def process_view(gw: Gateway, number: int) -> ProcessView:
    """Process ``number`` as its nodes show it: the cell's read model (``gw.views``), and the
    program's text around its block."""
    v = gw.views.process(number)
    loaded = gw.engine.processes[number].loaded
    lines: Sequence[str] = loaded.program.lines if loaded is not None else ()
    i = v.line - 1

    def text(j: int) -> str:
        return lines[j].strip() if 0 <= j < len(lines) else ""

    position = tuple(round(x, 4) for x in v.position[:3]) + (0.0,) * (3 - len(v.position[:3]))
    return ProcessView(*_state(number, v.state, v.stopped is not None, v.program or ""),
                       v.line, v.n if v.n is not None else -1, (text(i - 1), text(i), text(i + 1)),
                       float(v.feed or 0.0), v.feed_override, v.rapid_override,
                       position)  # type: ignore[arg-type]


class PlantView(NamedTuple):
    """A plant model (docs/plant.md) as its nodes show it."""

    name: str
    state: str
    fault: str  # the faults in force on it, by kind ("" none)


SND_LOG = 16  # the SNDs the log node keeps, as the Modbus SND log does


def snd_text(t: float, sender: int, to: int, where: str) -> str:
    """One SND log line: ``t=1.250 P1 -> P2 PROG91.nc:7 N24``."""
    return f"t={t:.3f} P{sender} -> P{to}" + (f" {where}" if where else "")


def plant_views(gw: Gateway) -> tuple[PlantView, ...]:
    plant = gw.runtime.plant
    if plant is None:
        return ()
    return tuple(PlantView(m["name"], str(m["state"]), m["fault"] or "")
                 for m in plant.status()["models"])


def plc_view(gw: Gateway) -> PlcView:
    status = gw.plc_status
    if status is None:
        return PlcView("NONE", 0, "")
    return PlcView(status.state.name, status.scans,
                   str(status.fault) if status.fault is not None else "")


def machine_name(source: Path | None) -> str:
    """The machine's name under ``Objects/Machines`` (docs/opcua.md): the config file's name
    without ``.toml``; for ``ncgate.toml``, the name every example and ``ncgate init`` give
    it, the name of its folder, so that two cells' servers do not both show a machine
    ``ncgate`` on one dashboard; ``ncgate`` for the built-in config.  The application URI
    keeps the file's name (``urn:ncgate:<stem>``): the server's certificate names it."""
    if source is None:
        return "ncgate"
    if source.stem == "ncgate" and source.resolve().parent.name:
        return source.resolve().parent.name
    return source.stem


def node_rows(cell: str, processes: list[int], sizes: dict[str, int],
              writable: frozenset[str], symbols: dict[str, str]) -> list[tuple[str, ...]]:
    """The UA nodes as ``ncgate map`` lists them beside the registers (docs/opcua.md):
    (browse path, node id, type, access, what)."""
    rw = {area: "read/write" if region in writable else "read"
          for area, region in (("SA", "sa_bits"), ("SK", "k_bytes"), ("SYVAR", "syvars"))}
    machine = f"Objects/Machines/{cell}"
    rows: list[tuple[str, ...]] = [
        (machine, f"ns=urn:ncgate:ua;s=Machines/{cell}", "MachineToolType", "read", "the cell"),
        (f"{machine}/Notification/Messages", "ns=urn:ncgate:ua;s=Messages", "events", "read",
         "AlertType conditions (alarms), CncMessageType (DIS)"),
        ("Objects/Server", "ns=0;i=2253", "events", "read",
         "the same events as Messages (HasNotifier: Server, the cell, Notification, Messages)")]
    for k in processes:
        p = f"Process {k}"
        for name, kind, what in (
                ("ChannelState", _typed(CHANNEL_STATE), CHANNEL_STATE.values()),
                ("ChannelMode", _typed(CHANNEL_MODE), "0 Automatic (always)"),
                ("FeedOverride", "Double", "percent"),
                ("RapidOverride", "Double", "percent")):
            rows.append((f"{machine}/Monitoring/{p}/{name}", f"ns=urn:ncgate:ua;s=P{k}/{name}",
                         kind, "read", what))
        for name, kind, what in (
                ("ActStatus", _typed(CNC_CHANNEL_STATUS), CNC_CHANNEL_STATUS.values()),
                ("ActProgramStatus", _typed(CNC_PROGRAM_STATUS), CNC_PROGRAM_STATUS.values()),
                ("ActProgramName", "String", "the program"),
                ("ActMainProgramName", "String", "the program"),
                ("ActProgramBlock", "String[3]", "previous, current, next block"),
                ("ActProgramLine", "String", "the source line"),
                ("ActFeedrate", "Double", "mm/min"), ("ActOverride", "Double", "percent"),
                ("X", "Double", "mm"), ("Y", "Double", "mm"), ("Z", "Double", "mm")):
            rows.append((f"Objects/CncInterface/CncChannelList/{p}/{name}",
                         f"ns=urn:ncgate:ua;s=P{k}/{name}", kind, "read", what))
        rows.append((f"Objects/Image/Processes/{p}/State", f"ns=urn:ncgate:image;s={p}.State",
                     "String", "read", "the state as /api/status names it"))
    for area, kind, size in (("SA", "Boolean", sizes["sa_bits"]),
                             ("SK", "Byte", sizes["k_bytes"]),
                             ("SYVAR", "Int16", sizes["syvars"])):
        rows.append((f"Objects/Image/{area}/{area}0 .. {area}{size - 1}",
                     f"ns=urn:ncgate:image;s={area}<i>", kind, rw[area], f"{size} variables"))
    for name, text in symbols.items():
        var = Var.parse(text)
        if var.view != SHOWN_VIEW[var.area]:
            continue  # a byte or word view of SA, a word of SK: no node (its variables have)
        rows.append((f"Objects/Image/Symbols/{name}", f"ns=urn:ncgate:image;s={name}",
                     f"as {var}", rw[var.area], f"the I/O name of {var}"))
    return rows


def _typed(enumeration: Enumeration) -> str:
    """The map's type of a variable of an enumeration: its DataType is the enumeration."""
    return f"{enumeration.name} (enumeration)"
