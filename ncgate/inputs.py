"""The one typed interface into the cell: every input from outside the engine.

Modbus, CANopen, the web console, the PLC logic, the sim script, a replayed record and a
Python program all translate what they receive into one of these frozen values and hand it to
:meth:`ncgate.gateway.Gateway.apply` (on the virtual clock: the same
:class:`ncgate.gateway.door.Door`).  Each carries its :class:`Source`; ``str(source)`` --
the kind, then a detail after a space -- is what the trace's ``by``/``who``, the run log, the
session record and the console show for it::

    from ncgate.inputs import Command, CommandKind, Source, Write
    gw.apply(Write("SA10", 1))                          # source: api
    gw.apply(Command(CommandKind.CYCLE_START, source=Source.parse("web 127.0.0.1")))

A refusal raises :class:`ncgate.errors.InputRefused` with a :class:`ncgate.errors.Reason`;
nothing of a refused input is applied.  Imports only ``ncgate.errors`` and the command table
(``ncgate.commands``); the gateway and users import it (the engine, the PLC and the config
stay below it: tests/test_layering.py).
"""

from __future__ import annotations

import enum
import functools
import re
from dataclasses import dataclass, field
from typing import Final

from ncgate.commands import BY_WORD, COMMANDS, CommandWord
from ncgate.errors import InputRefused, Reason


class SourceKind(enum.StrEnum):
    """Who an input comes from: the first word of every attribution."""

    MODBUS = "modbus"
    MODBUS_TLS = "modbus-tls"
    MODBUS_RTU = "modbus-rtu"  # a serial line (its device) or RTU over TCP (the peer)
    CANOPEN = "canopen"
    WEB = "web"
    PLC = "plc"
    SCRIPT = "script"
    REPLAY = "replay"
    API = "api"
    PLANT = "plant"  # a plant model's write (``plant clamp``), or the ST plant logic's
    OPCUA = "opcua"  # an OPC UA client's write (``opcua 127.0.0.1:50312``, ``opcua alice``)


@dataclass(frozen=True, slots=True)
class Source:
    """An input's origin: ``kind`` and a ``detail`` (the peer address, the TLS role, the
    PLC's file:line, the script entry...).  ``peer`` is the network address when the detail
    does not say it (a TLS client named by its role), for the record and the log."""

    kind: SourceKind
    detail: str = ""
    peer: str | None = field(default=None, compare=False)
    text: str = field(default="", init=False, repr=False, compare=False)  # str(), made once

    def __post_init__(self) -> None:
        try:
            kind = SourceKind(self.kind)
        except ValueError:
            raise InputRefused(Reason.BAD_VALUE, f"{self.kind!r} is not a source kind ("
                               f"{', '.join(k.value for k in SourceKind)})") from None
        if not isinstance(self.detail, str):
            raise InputRefused(Reason.BAD_VALUE, f"a source's detail is a text, not "
                               f"{self.detail!r}")
        object.__setattr__(self, "kind", kind)
        object.__setattr__(self, "text", f"{kind.value} {self.detail}" if self.detail
                           else kind.value)

    def __str__(self) -> str:
        return self.text

    @classmethod
    def parse(cls, text: str, peer: str | None = None) -> Source:
        """The inverse of ``str()``: ``"modbus 127.0.0.1:40312"`` -> Source(MODBUS, ...)."""
        if not isinstance(text, str):
            raise InputRefused(Reason.BAD_VALUE, f"{text!r}: a source is a text such as "
                               "\"modbus 127.0.0.1:40312\"")
        kind, _, detail = text.strip().partition(" ")
        try:
            return cls(SourceKind(kind), detail.strip(), peer)
        except ValueError:
            known = ", ".join(k.value for k in SourceKind)
            raise InputRefused(Reason.BAD_VALUE, f"{text!r}: not a source (the first word "
                               f"is one of {known})") from None


API: Final = Source(SourceKind.API)

_VAR = re.compile(r"(SYVAR|SA|SK)([0-9]{1,9})(?:\.(BY|IN|BL))?", re.IGNORECASE)


@dataclass(frozen=True, slots=True)
class Var:
    """An image variable (spec 1.3): area ``SA``/``SK``/``SYVAR``, index, view ``bit``/``BY``/
    ``IN``.  ``str()`` is its name as programs write it (``SA10``, ``SK2.IN``, ``SYVAR1``)."""

    area: str
    index: int
    view: str

    @classmethod
    def parse(cls, text: str) -> Var:
        """``"SA10"``, ``"sa1.by"``, ``"SK2"``, ``"SK2.IN"``, ``"SYVAR5"``; InputRefused
        (UNKNOWN_VARIABLE) otherwise.  Whether it lies inside the image is the door's to
        say (the image's size is the config's)."""
        m = _VAR.fullmatch(text.strip()) if isinstance(text, str) else None
        if m is None:
            raise InputRefused(Reason.UNKNOWN_VARIABLE,
                               f"{text!r} is not an image variable (SA10, SA1.BY, SA2.IN, "
                               "SK3, SK4.IN, SYVAR5)")
        area, index, view = m.group(1).upper(), int(m.group(2)), (m.group(3) or "").upper()
        if area == "SYVAR":
            if view not in ("", "IN"):
                raise InputRefused(Reason.UNKNOWN_VARIABLE,
                                   f"{text!r}: a SYVAR is a 16-bit word, it has no .{view}")
            return cls(area, index, "IN")
        if area == "SA":
            return cls(area, index, "bit" if view in ("", "BL") else view)
        if view == "BL":
            raise InputRefused(Reason.UNKNOWN_VARIABLE,
                               f"{text!r}: the K packet has no bits (SK3, SK3.IN)")
        return cls(area, index, view or "BY")

    def __post_init__(self) -> None:
        if (self.area not in ("SA", "SK", "SYVAR") or self.view not in ("bit", "BY", "IN")
                or type(self.index) is not int):
            raise InputRefused(Reason.UNKNOWN_VARIABLE, f"({self.area!r}, {self.index!r}, "
                               f"{self.view!r}) is not an image variable")

    @classmethod
    def of(cls, var: Var | str) -> Var:
        return var if isinstance(var, Var) else cls.parse(var)

    @staticmethod
    @functools.lru_cache(maxsize=8192)
    def at(area: str, index: int, view: str) -> Var:
        """The variable at (area, index, view), made once: a fieldbus names the same few
        thousand variables in every request."""
        return Var(area, index, view)

    def __str__(self) -> str:
        return var_name(self.area, self.index, self.view)

    @property
    def address(self) -> tuple[str, int, str]:
        """(area, index, view), as :class:`ncgate.plc.image.IOImage` takes it."""
        return (self.area, self.index, self.view)


def var_name(area: str, index: int, view: str) -> str:
    """A variable's name as programs write it: ``SA10``, ``SK2.IN``, ``SYVAR1``."""
    if area == "SYVAR" or (area == "SA" and view == "bit") or (area == "SK" and view == "BY"):
        return f"{area}{index}"
    return f"{area}{index}.{view}"


def _var(value: Var | str) -> Var:
    return Var.of(value)


@dataclass(frozen=True, slots=True)
class Write:
    """One image variable written to a value."""

    var: Var
    value: int
    source: Source = API

    def __post_init__(self) -> None:
        if not isinstance(self.var, Var):
            object.__setattr__(self, "var", _var(self.var))


@dataclass(frozen=True, slots=True)
class Writes:
    """Several image variables written as one (one fieldbus request): all or nothing."""

    changes: tuple[tuple[Var, int], ...]
    source: Source = API

    def __post_init__(self) -> None:
        try:
            changes = self.changes
            if type(changes) is tuple and (
                    (len(changes) == 1 and type(changes[0][0]) is Var)
                    or all(type(var) is Var for var, _ in changes)):
                return  # the fieldbus's way (Var.at): nothing to convert
            changes = tuple((Var.of(var), value) for var, value in self.changes)
        except (TypeError, ValueError):
            raise InputRefused(Reason.BAD_VALUE, "changes: expected (variable, value) "
                               "pairs") from None
        object.__setattr__(self, "changes", changes)

    @classmethod
    def of(cls, changes: dict[str, int] | list[tuple[Var | str, int]],
           source: Source = API) -> Writes:
        items = changes.items() if isinstance(changes, dict) else changes
        return cls(tuple((_var(v), value) for v, value in items), source)


class CommandKind(enum.IntEnum):
    """The command word of the fieldbus maps (spec 3.2): its number is the word's value.
    What each does, and everything else about it, is its row of ``ncgate.commands.COMMANDS``
    (``spec``); the members are spelled out for the type checker, and checked against that
    table as this module loads: every row without an N number, by its word and its name.
    (13..15 carry an N number and become other inputs: ``gateway.door.search_inputs``.)"""

    CYCLE_START = 1
    FEED_HOLD = 2
    RESET = 3
    RESTART_PLC = 4
    STEP = 5
    SINGLE_BLOCK_ON = 6
    SINGLE_BLOCK_OFF = 7
    OPTIONAL_STOP_ON = 8
    OPTIONAL_STOP_OFF = 9
    BLOCK_SKIP_ON = 10
    BLOCK_SKIP_OFF = 11
    RUN_TO_SYNC = 12
    RELOAD_PLC = 16

    @property
    def label(self) -> str:
        """Its name as a script, the console and the record write it (``cycle_start``)."""
        return self.name.lower()

    @property
    def spec(self) -> CommandWord:
        """Its row of the command table."""
        return BY_WORD[self.value]


def _check_command_kinds() -> None:
    table = {(c.word, c.name) for c in COMMANDS if not c.with_n}
    kinds = {(k.value, k.label) for k in CommandKind}
    if table != kinds:
        raise AssertionError(f"CommandKind differs from ncgate.commands.COMMANDS: only in "
                             f"the table {sorted(table - kinds)}, only in the enum "
                             f"{sorted(kinds - table)}")


_check_command_kinds()


def command_word(word: int) -> tuple[CommandKind, int | None] | None:
    """A fieldbus command word (Modbus holding 2000, CANopen 0x2400:1): the command in the low
    byte, the process in the high byte (0: the cell, as 1/2/3 always meant; ``0x0201``:
    cycle start of process 2).  None: not a command."""
    try:
        kind = CommandKind(word & 0xFF)
    except ValueError:
        return None
    return kind, (word >> 8) or None


@dataclass(frozen=True, slots=True)
class Command:
    """Cycle start, feed hold, reset or a restart of the PLC logic; ``process=None``: the
    whole cell (a PLC restart is always the cell's)."""

    kind: CommandKind
    process: int | None = None
    source: Source = API


@dataclass(frozen=True, slots=True)
class Snd:
    """An SND in the name of an external process ``sender`` (the fieldbus's mailbox)."""

    sender: int
    target: int
    source: Source = API


@dataclass(frozen=True, slots=True)
class Start:
    """The operator's program start: ``program`` (None: the config's main) in ``process``;
    ``at`` a label or an N number: a block search (the program starts there, with the modal
    state the blocks before it set; ``with_calc``: their E parameters too)."""

    program: str | None = None
    process: int = 1
    source: Source = API
    at: str | None = None
    with_calc: bool = False


@dataclass(frozen=True, slots=True)
class FieldbusAlarm:
    """An alarm of the fieldbus side (process 0 in the trace), e.g. a lost CANopen master.
    ``code`` is an alarm number of docs/diagnostics.md (150: master lost)."""

    code: int
    message: str
    source: Source = API


FEED_OVERRIDE_MAX: Final = 200  # percent: the feed override's range is 0..this
RAPID_OVERRIDE_MAX: Final = 100  # percent: the rapid override's


@dataclass(frozen=True, slots=True)
class Override:
    """The feed override (0..200 %) and/or the rapid override (0..100 %) of one process or,
    ``process=None``, of the cell: in force from the next interpolation step."""

    feed: int | None = None
    rapid: int | None = None
    process: int | None = None
    source: Source = API


@dataclass(frozen=True, slots=True)
class Break:
    """Set (``on``) or clear a breakpoint, as an engineer writes it: ``PROG92:8``, ``N40``,
    ``P2 wait``, ``P2 wait EXE``, ``sync`` (run to sync)."""

    at: str
    on: bool = True
    source: Source = API


@dataclass(frozen=True, slots=True)
class PlcVar:
    """A variable of the PLC logic, by its path: ``main.n``, ``main.t[2]``, ``main.s.x``."""

    path: str

    def __post_init__(self) -> None:
        if not isinstance(self.path, str) or _PLC_PATH.fullmatch(self.path.strip()) is None:
            raise InputRefused(Reason.UNKNOWN_VARIABLE, f"{self.path!r} is neither an image "
                               "variable (SA10, SK3, SYVAR5) nor a PLC variable (main.n)")

    def __str__(self) -> str:
        return self.path.strip()


_PLC_PATH = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*(\[-?\d+\])*|\[-?\d+\])+")


@dataclass(frozen=True, slots=True)
class Force:
    """Force ``var`` to ``value`` (kept whatever writes it) or, ``value`` None, release it;
    ``var`` None (and ``value`` None): release every forced variable.  ``var`` is an image
    variable or a PLC variable (a string is the one it spells: ``"SA10"``, ``"main.n"``)."""

    var: Var | PlcVar | None
    value: int | float | None = None
    source: Source = API

    def __post_init__(self) -> None:
        var: object = self.var
        if var is not None and type(var) is not Var and type(var) is not PlcVar:
            try:
                var = Var.of(var)  # type: ignore[arg-type]  # (a str; else refused)
            except InputRefused:
                if not isinstance(var, str) or "." not in var:
                    raise
                var = PlcVar(var)
            object.__setattr__(self, "var", var)


FAULT_KINDS: Final = ("stuck", "wire_break", "chatter", "slow", "never", "exception", "delay",
                      "no_reply", "heartbeat_stop", "emcy", "pdo_stop")


@dataclass(frozen=True, slots=True)
class Fault:
    """Inject a fault (docs/plant.md): ``target`` a plant model (``clamp``), one of its
    outputs (``clamp.extended``), an image variable or I/O name (``SA30``, ``door_closed``),
    ``modbus`` or ``canopen``; ``kind`` one of :data:`FAULT_KINDS`; ``params`` its keys
    (``value``, ``period_ms``, ``factor``, ``live_zero``, ``code``, ``ms``, ``unit``,
    ``addresses``) as sorted (key, value) pairs; ``for_s`` clears it after that long (None:
    until cleared).  ``Fault.of("clamp", "slow", factor=3)`` builds one from keywords."""

    target: str
    kind: str
    params: tuple[tuple[str, object], ...] = ()
    for_s: float | None = None
    source: Source = API

    @classmethod
    def of(cls, target: str, kind: str, *, for_s: float | None = None,
           source: Source = API, **params: object) -> Fault:
        items = ((k, tuple(v) if isinstance(v, list) else v) for k, v in params.items())
        return cls(target, kind, tuple(sorted(items)), for_s, source)

    def param(self, name: str, default: object = None) -> object:
        return next((v for k, v in self.params if k == name), default)


@dataclass(frozen=True, slots=True)
class ClearFault:
    """Clear the faults of ``target`` (as :class:`Fault` names it), or every fault (None)."""

    target: str | None = None
    source: Source = API


Input = (Write | Writes | Command | Snd | Start | FieldbusAlarm | Override | Break | Force
         | Fault | ClearFault)

__all__ = [
    "API",
    "FAULT_KINDS",
    "Break",
    "ClearFault",
    "Command",
    "CommandKind",
    "Fault",
    "FieldbusAlarm",
    "Force",
    "Input",
    "InputRefused",
    "Override",
    "PlcVar",
    "Reason",
    "Snd",
    "Source",
    "SourceKind",
    "Start",
    "Var",
    "Write",
    "Writes",
]
