"""The Modbus server's fault table: the fieldbus faults a test or a commissioning engineer
puts on the machine that isn't there yet (a busy device, a slow one, one that went silent).

:class:`ModbusFault` is one row; ``ModbusServer.set_faults`` puts a table in force and
``ModbusServer.faults`` reads it back.  Matching and the counts live in :class:`FaultTable`,
which the connections consult for each request (only while a table is set: with none, the
request path pays one attribute test).  Protocol-free but for the PDU's address layout
(``framer.address_ranges``); it imports neither asyncio nor pymodbus.

What each kind does on the wire (the connection does it, ``server._Connection``):

- ``exception``: the request is answered with exception ``code`` (default 06, Server Device
  Busy) and not executed: nothing of a write is stored;
- ``delay``: the request is executed and answered ``ms`` later.  The connection's later
  requests wait behind it, in order (a Modbus TCP server may answer out of order, a device
  that is slow is slow for every request it has queued); other connections are served
  meanwhile;
- ``no_reply``: the request is read and never answered, and from then on that connection
  answers nothing more: its later requests are read and dropped (counted as ``silenced``)
  until the client closes it (or the idle timeout does, once the client is quiet), even
  after the fault is cleared.  A Modbus server that stops
  answering stops answering on that connection.  On TCP an answer is never lost on the wire,
  so a server that skipped one request and answered the next would be a fault no device has;
  clients (libmodbus, pymodbus) meet a timeout by reconnecting, and a new connection is
  served by the table then in force.

Of the rows that match a request, the strongest decides: a ``no_reply``, else an
``exception``, else the longest ``delay`` (of equals, the first).  (The first row in the
table decided: a delay injected before an exception let a write the exception covers through,
stored.)  A row matches a request of its ``unit`` (None: every unit) whose addresses, in any
table, meet its ``addresses`` range (None: every request, those without addresses too: FC43).
A clear, or a table whose delays no longer match a held request, answers that request at
once (``server._Connection.faults_changed``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal, get_args

from ncgate.gateway.errors import GatewayError
from ncgate.gateway.modbus.framer import address_ranges

FaultKind = Literal["exception", "delay", "no_reply"]
KINDS: Final[tuple[str, ...]] = get_args(FaultKind)
# The counters ``FaultTable.counts`` keeps: one per kind, and the requests a silent
# connection dropped after its no_reply.
COUNTERS: Final = (*KINDS, "silenced")


class FaultError(GatewayError, ValueError):
    """A fault row the server cannot put in force (a bad code, unit, range or delay)."""


@dataclass(frozen=True, slots=True)
class ModbusFault:
    """One row of the fault table.

    ``kind``: ``exception`` answers exception ``code`` (1..255, default 06 Server Device
    Busy); ``delay`` answers ``ms`` milliseconds late; ``no_reply`` never answers, nor does
    its connection from then on.  ``unit``: the unit id it applies to (None: every unit).
    ``addresses``: an inclusive range of protocol (0-based) addresses met by the request's
    range in any table (None: every request)."""

    kind: FaultKind
    code: int = 6
    ms: float = 0
    unit: int | None = None
    addresses: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise FaultError(f"fault kind {self.kind!r}: one of {', '.join(KINDS)}")
        if isinstance(self.code, bool) or not isinstance(self.code, int) \
                or not 1 <= self.code <= 255:
            raise FaultError(f"exception code {self.code!r}: 1..255 (0 is no exception)")
        if not isinstance(self.ms, int | float) or not math.isfinite(self.ms) or self.ms < 0:
            raise FaultError(f"delay {self.ms!r} ms: a finite number >= 0")
        if self.unit is not None and (isinstance(self.unit, bool) or not isinstance(
                self.unit, int) or not 0 <= self.unit <= 255):
            raise FaultError(f"unit {self.unit!r}: 0..255, or None for every unit")
        if self.addresses is not None:
            try:
                first, last = self.addresses
            except (TypeError, ValueError):
                raise FaultError(f"addresses {self.addresses!r}: (first, last)") from None
            if not all(isinstance(a, int) and not isinstance(a, bool) for a in (first, last)) \
                    or not 0 <= first <= last <= 0xFFFF:
                raise FaultError(f"addresses {self.addresses!r}: 0 <= first <= last <= 65535")
            # A list from TOML or JSON ([first, last]) is kept as the tuple: a row is a value.
            object.__setattr__(self, "addresses", (first, last))

    def matches(self, unit: int, pdu: bytes) -> bool:
        """Whether this row applies to the request ``pdu`` for ``unit``."""
        if self.unit is not None and unit != self.unit:
            return False
        if self.addresses is None:
            return True
        first, last = self.addresses
        return any(lo <= last and first <= hi for lo, hi in address_ranges(pdu))


class FaultTable:
    """The rows in force and the requests each kind caught (counted across tables)."""

    __slots__ = ("counts", "rows")

    def __init__(self) -> None:
        self.rows: tuple[ModbusFault, ...] = ()
        self.counts: dict[str, int] = dict.fromkeys(COUNTERS, 0)

    def set(self, rows: Sequence[ModbusFault]) -> None:
        """Put ``rows`` in force, all or none (FaultError)."""
        for row in rows:
            if not isinstance(row, ModbusFault):
                raise FaultError(f"{row!r} is not a ModbusFault")
        self.rows = tuple(rows)

    def match(self, unit: int, pdu: bytes) -> ModbusFault | None:
        """The strongest row that applies to the request (module doc), counted; None: answer
        it as usual."""
        found: ModbusFault | None = None
        for row in self.rows:
            if row.matches(unit, pdu) and (found is None or (_RANK[row.kind], row.ms) > (
                    _RANK[found.kind], found.ms)):
                found = row
        if found is not None:
            self.counts[found.kind] += 1
        return found


_RANK: Final = {"delay": 0, "exception": 1, "no_reply": 2}


def held_delay(table: FaultTable | None, unit: int, pdu: bytes) -> float:
    """Seconds the longest delay of ``table`` that matches a request holds it (0: none)."""
    if table is None:
        return 0.0
    return max((row.ms for row in table.rows if row.kind == "delay" and row.matches(unit, pdu)),
               default=0.0) / 1000


def row_status(row: ModbusFault) -> dict[str, object]:
    """A row as the status shows it: its kind and scope, and the key its kind has (an
    exception's ``code``, a delay's ``ms``; a no_reply's neither)."""
    shown: dict[str, object] = {"kind": row.kind}
    if row.kind == "exception":
        shown["code"] = row.code
    elif row.kind == "delay":
        shown["ms"] = row.ms
    shown["unit"] = row.unit
    shown["addresses"] = list(row.addresses) if row.addresses else None
    return shown
