"""PDOs as a master configures them (CiA 301 7.2.2, 7.5.2.35-38): RPDO1..4 and TPDO1..4 with
dynamic mapping, the transmission types, inhibit time, event timer and SYNC.

Two halves, on two threads:

- **Checks** (:func:`check_write`), on python-can's receive thread before canopen stores an
  SDO write: the COB-ID rules, the transmission types the node honours, the mapping
  procedure (only while the PDO is disabled and its count is 0; 0x06040041 / 0x06040042).
  A refused write stores nothing.
- **The runtime** (:class:`Pdos`): RPDO frames and SYNC arrive on the receive thread and are
  handed to the loop; TPDOs are built and sent on the loop, where the image and the processes
  live, except a SYNC's: the receive thread sends them at once, built from the snapshot the
  loop publishes (``snapshot``), never from the engine.  The TPDOs' state is changed by both
  threads, each under ``Pdos.lock``.  Timers (inhibit, event timer) run on the node's clock,
  so tests drive them.

Transmission types.  TPDO: 0 (at the next SYNC after a change of its own frame), 1..240
(every n-th SYNC;
the SYNC start value of sub 6 waits for that SYNC counter), 254/255 (on change, spaced by the
inhibit time, and when the event timer runs out).  RPDO: 0..240 (applied at the next SYNC),
254/255 (at once).  252/253 (RTR only) and the reserved 241..251 are refused with 0x06090030:
the node answers no remote frames (canopen's network drops them).

Watching the master (CiA 301 7.5.2.35, 7.5.2.6/7/21): an RPDO's event timer is a deadline
(EMCY 0x8250 and the lost-master reactions), a frame of the wrong length is EMCY
0x8210/0x8220; 0x1006 is the SYNC's deadline (EMCY 0x8100), 0x1007 its window, 0x1019 says
whether a SYNC carries a counter (EMCY 0x8240).  Leaving OPERATIONAL drops synchronous RPDO
data not yet applied.

"On change" means: the image bytes or SYVARs a TPDO maps were written, a process it maps
changed state, or an SND happened.  A TPDO that maps the last-SND record sends one frame per
SND, spaced by its inhibit time (a queue of at most 256; older ones are counted as lost).
Block N and line (and the PLC status) are sampled, not watched: a frame per block would flood
the bus.  A frame the loop builds (the event timer, another change) reads them as they are; a
SYNC sends them as the loop last published them (snapshot.py): at their process's last
event, or after the SYNC before at the oldest.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import (
    INTEGER8,
    INTEGER16,
    INTEGER32,
    UNSIGNED8,
    UNSIGNED16,
    UNSIGNED32,
)
from canopen.sdo.exceptions import SdoAbortedError

from ncgate.gateway.canopen.clock import Clock, Timer
from ncgate.gateway.canopen.codes import (
    ABORT_APPLICATION_DEVICE_STATE,
    ABORT_INVALID_VALUE,
    ABORT_PDO_CANNOT_MAP,
    ABORT_PDO_LENGTH_EXCEEDED,
    ABORT_UNSUPPORTED_ACCESS,
)
from ncgate.gateway.canopen.dictionary import (
    COMMAND,
    CYCLE_PERIOD,
    LAST_SND,
    MAX_MAPPED,
    PDO_COUNT,
    RPDO_COMMUNICATION,
    RPDO_MAPPING,
    STATUS_BASE,
    SYNC_COB_ID,
    SYNC_OVERFLOW,
    SYNC_WINDOW,
    TPDO_COMMUNICATION,
    TPDO_MAPPING,
    image_target,
)
from ncgate.gateway.canopen.sdo import Device
from ncgate.gateway.canopen.snapshot import Snapshot, getter, sampled
from ncgate.gateway.ratelimit import RateLimitedLog
from ncgate.inputs import Source, SourceKind

log = logging.getLogger("ncgate.canopen")

NOT_VALID, NO_RTR, EXTENDED = 0x80000000, 0x40000000, 0x20000000
ID_29_BITS = 0x1FFFF800  # bits 11..28: part of a 29-bit identifier only
EVENT_TYPES = (254, 255)
SND_QUEUE = 256

_FORMAT = {UNSIGNED8: "B", UNSIGNED16: "H", UNSIGNED32: "L", INTEGER8: "b", INTEGER16: "h",
           INTEGER32: "l"}
# CiA 301 7.4.7.1: a data type's index may be mapped into an RPDO to skip its bytes.
_DUMMY_BITS = {0x0002: 8, 0x0003: 16, 0x0004: 32, 0x0005: 8, 0x0006: 16, 0x0007: 32}

# CiA 301 table 3: identifiers no PDO may use (NMT, SYNC/EMCY, TIME, SDO, NMT error control,
# LSS).
_RESTRICTED = ((0x000, 0x07F), (0x101, 0x180), (0x581, 0x5FF), (0x601, 0x67F), (0x6E0, 0x6FF),
               (0x701, 0x77F), (0x780, 0x7FF))


def restricted(can_id: int) -> bool:
    return any(lo <= can_id <= hi for lo, hi in _RESTRICTED)


def param(device: Device, index: int, subindex: int) -> int:
    """A communication parameter as it is now: written (stored) or its default."""
    stored = device.data_store.get(index, {}).get(subindex)
    if stored is not None:
        return int.from_bytes(stored, "little")
    obj = device.object_dictionary[index]
    if isinstance(obj, ODVariable):
        return int(obj.default or 0)
    return int(obj[subindex].default or 0)


# ---- the checks (receive thread, before the write is stored) ------------------------------

def is_pdo_parameter(index: int) -> bool:
    return RPDO_COMMUNICATION <= index < RPDO_COMMUNICATION + PDO_COUNT \
        or RPDO_MAPPING <= index < RPDO_MAPPING + PDO_COUNT \
        or TPDO_COMMUNICATION <= index < TPDO_COMMUNICATION + PDO_COUNT \
        or TPDO_MAPPING <= index < TPDO_MAPPING + PDO_COUNT


def check_write(device: Device, index: int, subindex: int, value: int) -> None:
    """Refuse (SdoAbortedError) a write to a PDO parameter that CiA 301 forbids now."""
    transmit = index >= TPDO_COMMUNICATION
    comm = index if index & 0x200 == 0 else index - 0x200  # 0x16xx -> 0x14xx, 0x1Axx -> 0x18xx
    valid = not param(device, comm, 1) & NOT_VALID
    if comm == index:
        if subindex == 1:
            _check_cob_id(param(device, index, 1), value)
        elif subindex == 2:
            if not (value <= 240 or value in EVENT_TYPES):
                raise SdoAbortedError(ABORT_INVALID_VALUE)  # RTR-only or reserved: not honoured
        elif subindex in (3, 6) and valid and value != param(device, index, subindex):
            # inhibit time and SYNC start value: only while the PDO does not exist
            raise SdoAbortedError(ABORT_INVALID_VALUE)
        return
    # A mapping parameter: the procedure of CiA 301 7.5.2.37/38.
    if valid:
        raise SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)
    if subindex == 0:
        if value > MAX_MAPPED:
            raise SdoAbortedError(ABORT_PDO_LENGTH_EXCEEDED)
        entries = [param(device, index, s) for s in range(1, value + 1)]
        if 0 in entries:
            # more objects than entries written: CiA 301 7.5.2.37 "number and length of
            # the objects to be mapped would exceed PDO length" (CANopenNode answers so)
            raise SdoAbortedError(ABORT_PDO_LENGTH_EXCEEDED)
        bits = sum(mapped_bits(device, entry, transmit) for entry in entries)
        if bits > 64:
            raise SdoAbortedError(ABORT_PDO_LENGTH_EXCEEDED)
        return
    if param(device, index, 0) != 0:
        raise SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)  # disable the mapping first
    if value:
        mapped_bits(device, value, transmit)


def mapped_bits(device: Device, entry: int, transmit: bool) -> int:
    """The size of a mapping entry; 0x06040041 if it names nothing this PDO can carry."""
    index, subindex, bits = entry >> 16, entry >> 8 & 0xFF, entry & 0xFF
    if index in _DUMMY_BITS and subindex == 0 and not transmit:
        if bits != _DUMMY_BITS[index]:
            raise SdoAbortedError(ABORT_PDO_CANNOT_MAP)
        return bits
    try:
        obj = device.object_for(index, subindex)
    except SdoAbortedError:
        raise SdoAbortedError(ABORT_PDO_CANNOT_MAP) from None
    if not obj.pdo_mappable or bits != len(obj) \
            or not (obj.readable if transmit else obj.writable):
        raise SdoAbortedError(ABORT_PDO_CANNOT_MAP)
    return bits


def _check_cob_id(current: int, cob: int) -> None:
    """CiA 301 7.5.2.35/36: the PDO COB-ID rules (abort 0x06090030 otherwise).  A TPDO's
    bit 30 written clear (RTR allowed) is accepted and stored set (:func:`stored_form`)."""
    if cob & (EXTENDED | ID_29_BITS):
        # 29-bit identifiers are not supported; with bit 29 clear, bits 11..28 are 0
        # (stored, they would be masked away: the PDO would go out on another id).
        raise SdoAbortedError(ABORT_INVALID_VALUE)
    valid_now, valid_then = not current & NOT_VALID, not cob & NOT_VALID
    if valid_now and valid_then and (cob ^ current) & 0x1FFFFFFF:
        raise SdoAbortedError(ABORT_INVALID_VALUE)  # the id changes only while the PDO is off
    if valid_then and restricted(cob & 0x7FF):
        raise SdoAbortedError(ABORT_INVALID_VALUE)


def check_sync_overflow(value: int, period_us: int) -> None:
    """0x1019: 0 (SYNC without counter) or 2..240; written only while 0x1006 is 0
    (CiA 301 7.5.2.21: 0x08000022 otherwise)."""
    if value == 1 or value > 240:
        raise SdoAbortedError(ABORT_INVALID_VALUE)
    if period_us:
        raise SdoAbortedError(ABORT_APPLICATION_DEVICE_STATE)


def check_sync_cob_id(cob: int) -> None:
    """0x1005: the node consumes SYNC and produces none (bit 30), 11-bit ids only (bits
    11..29 clear), and no identifier CiA 301 table 3 restricts (7.3.5): a SYNC on 0x610
    would make every SDO request a SYNC."""
    if cob & (NO_RTR | EXTENDED | ID_29_BITS) or restricted(cob & 0x7FF):
        raise SdoAbortedError(ABORT_INVALID_VALUE)


def stored_form(index: int, subindex: int, data: bytes) -> bytes:
    """What the node stores for an accepted write: a TPDO COB-ID always with bit 30 set,
    since the node answers no RTR (written clear by a master's ``PdoMap.save()`` that did
    not read the map first; CANopenNode stores it so too)."""
    if TPDO_COMMUNICATION <= index < TPDO_COMMUNICATION + PDO_COUNT and subindex == 1:
        return (int.from_bytes(data, "little") | NO_RTR).to_bytes(4, "little")
    return data


# ---- the runtime --------------------------------------------------------------------------

# A SYNC handled later than one SYNC period (and at least this) after it arrived is stale.
SYNC_WINDOW_MIN_S = 0.1
# The node counts the SYNCs it answered later than each of these (seconds).
SYNC_LATENCY_BOUNDS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05)

class Host(Protocol):
    """What the PDOs need of the node."""

    node: Device

    @property
    def clock(self) -> Clock: ...

    @property
    def operational(self) -> bool: ...

    def send(self, cob: int, data: bytes) -> None: ...

    def subscribe(self, cob: int, callback: Callable[[int, bytearray, float], None]) -> None: ...

    def unsubscribe(self, cob: int,
                    callback: Callable[[int, bytearray, float], None]) -> None: ...

    @property
    def view(self) -> Snapshot: ...

    def current(self, statuses: bool = True) -> Snapshot: ...

    def getter(self, index: int, subindex: int) -> Callable[[], int]: ...

    def sample(self) -> Snapshot: ...

    def sample_later(self) -> None: ...

    def call_soon(self, fn: Callable[[], None]) -> None: ...

    def apply(self, changes: Sequence[tuple[str, int, str, int]], source: Source) -> None: ...

    def rpdo_timeout(self, n: int, ms: int) -> None: ...

    def rpdo_back(self, n: int) -> None: ...

    def rpdo_length(self, n: int, emcy: int) -> None: ...

    def sync_error(self, emcy: int, on: bool) -> None: ...


@dataclass(frozen=True)
class Layout:
    """A mapping compiled: the frame's struct, and what each value is."""

    frame: struct.Struct
    objects: tuple[tuple[int, int], ...]  # (index, sub-index) of each value, dummies skipped
    image: bool  # maps SA, K or SYVAR
    status: bool  # maps a process status
    snd: bool  # maps the last SND
    only_snd: bool  # maps nothing else (TPDO2's default): nothing to say before an SND
    sampled: bool  # maps a value that changes without an event (block N, line, the PLC)

    @classmethod
    def of(cls, device: Device, mapping: int) -> Layout:
        fmt, objects = "<", []
        for sub in range(1, param(device, mapping, 0) + 1):
            entry = param(device, mapping, sub)
            index, subindex = entry >> 16, entry >> 8 & 0xFF
            if index in _DUMMY_BITS:
                fmt += f"{_DUMMY_BITS[index] // 8}x"
                continue
            data_type = device.object_for(index, subindex).data_type
            fmt += _FORMAT[data_type or UNSIGNED8]
            objects.append((index, subindex))
        return cls(struct.Struct(fmt), tuple(objects),
                   image=any(i < COMMAND for i, _ in objects),
                   status=any(STATUS_BASE <= i < LAST_SND for i, _ in objects),
                   snd=any(i == LAST_SND for i, _ in objects),
                   only_snd=bool(objects) and all(i == LAST_SND for i, _ in objects),
                   sampled=any(sampled(i, s) for i, s in objects))


class Tpdo:
    """One TPDO's configuration and transmission state: changed on the loop, and by a SYNC
    on the receive thread, each under :attr:`Pdos.lock`."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.cob = NOT_VALID
        self.type = 255
        self.inhibit_s = 0.0
        self.event_s = 0.0
        self.sync_start = 0
        self.layout: Layout | None = None
        self.getters: tuple[Callable[[Snapshot], int], ...] = ()  # from a snapshot
        self.live: tuple[Callable[[], int], ...] = ()  # as they are now (on the loop)
        self.last: bytes | None = None  # the last frame sent
        self.last_t = -1e18
        self.pending: bytes | None = None  # a change waiting for the inhibit time
        self.queue: deque[bytes] = deque()  # one frame per SND
        self.force = False  # the event timer ran out: send what is there now
        self.inhibit_timer: Timer | None = None
        self.event_timer: Timer | None = None
        self.sync_count = 0
        self.started = False  # a SYNC start value was met
        self.sync_due = False  # type 0: a change since the last SYNC
        # type 0: the frame as of its last transmission (or when it came to life); a SYNC
        # sends it again only when what it maps differs from this
        self.reference: bytes | None = None

    @property
    def valid(self) -> bool:
        return not self.cob & NOT_VALID

    def frame(self, view: Snapshot) -> bytes:
        """The frame of what it maps, from the values the loop published."""
        assert self.layout is not None
        return self.layout.frame.pack(*[get(view) for get in self.getters])

    def live_frame(self) -> bytes:
        """The frame of what it maps as it is now (on the loop)."""
        assert self.layout is not None
        return self.layout.frame.pack(*[get() for get in self.live])

    def idle(self) -> None:
        """Nothing pending, no timer armed."""
        for timer in (self.inhibit_timer, self.event_timer):
            if timer is not None:
                timer.cancel()
        self.inhibit_timer = self.event_timer = None
        self.pending, self.force, self.sync_due = None, False, False
        self.reference = None
        self.last = None  # the next frame is news, whatever went before
        self.queue.clear()
        self.sync_count, self.started = 0, False


# EMCY codes of an RPDO (CiA 301 table 21): not processed due to length error, length
# exceeded, RPDO timeout (its deadline monitoring).
EMCY_RPDO_SHORT, EMCY_RPDO_LONG, EMCY_RPDO_TIMEOUT = 0x8210, 0x8220, 0x8250
# SYNC errors: no SYNC within 1.5 communication cycle periods (as CANopenNode), a SYNC
# whose length disagrees with 0x1019 (a counter byte, or none).
EMCY_SYNC_TIMEOUT, EMCY_SYNC_LENGTH = 0x8100, 0x8240
SYNC_TIMEOUT_PERIODS = 1.5


class Deadline:
    """Something expected again within ``timeout_s`` (an RPDO with an event timer, the SYNC
    with a cycle period; CiA 301 7.5.2.35, 7.5.2.6): armed by the first arrival, moved on by
    each (not re-armed); once run out, ``lost()`` is called once (on the loop), and the next
    arrival calls ``back()`` (on the loop, through ``call_soon``).  Watched only while
    ``watching()`` holds (OPERATIONAL)."""

    def __init__(self, timeout_s: float, clock: Clock,
                 call_soon: Callable[[Callable[[], None]], None], watching: Callable[[], bool],
                 lost: Callable[[], None], back: Callable[[], None]) -> None:
        self.timeout_s, self.clock, self._call_soon = timeout_s, clock, call_soon
        self._watching, self._lost, self._back = watching, lost, back
        self.last = 0.0
        self.lost = False
        self.timer: Timer | None = None
        self.closed = False

    def seen(self) -> None:
        """An arrival (receive thread)."""
        self.last = self.clock.monotonic()
        if self.lost:
            self.lost = False
            self._call_soon(self._back)
        if self.timer is None:
            self.timer = self.clock.call_later(self.timeout_s, self._due)

    def _due(self) -> None:
        """The deadline as armed: if something came since, it moves on."""
        self.timer = None
        if self.closed or not self._watching():
            return
        left = self.last + self.timeout_s - self.clock.monotonic()
        if left > 1e-9:
            self.timer = self.clock.call_later(left, self._due)
            return
        self.lost = True
        self._lost()

    def stop(self) -> None:
        """Not watched until the next arrival (leaving OPERATIONAL)."""
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None

    def close(self) -> None:
        """No longer wanted (reconfigured): a loss it reported is over."""
        self.stop()
        self.closed = True
        if self.lost:
            self._call_soon(self._back)


class Rpdo:
    """One RPDO's configuration, swapped whole on the receive thread."""

    def __init__(self, n: int, cob: int, sync: bool, layout: Layout) -> None:
        self.n, self.cob, self.sync, self.layout = n, cob, sync, layout
        self.targets = tuple(image_target(i, s) for i, s in layout.objects)


class Pdos:
    def __init__(self, host: Host) -> None:
        self.host = host
        self.tpdos = {n: Tpdo(n) for n in range(1, PDO_COUNT + 1)}
        # The TPDOs' state: the loop changes it (configuration, NMT, changes, timers), and a
        # SYNC on the receive thread (its counters, type 0's reference, the frame sent).
        # Held for a frame's building and sending, never across a wait for the loop: the
        # receive thread waits at most that long.  Reentrant: a change sends at once.
        self.lock = threading.RLock()
        # Whether a valid TPDO is synchronous (0..240): only then the node keeps the
        # processes' status in the snapshot up to date (configured on the loop).
        self.synchronous = False
        self.rpdos: dict[int, Rpdo] = {}
        self._subscribed: dict[int, int] = {}  # RPDO n -> the COB-ID it listens on
        self._rpdo_callbacks = {n: self._rpdo_callback(n) for n in range(1, PDO_COUNT + 1)}
        self._sync_cob: int | None = None
        self._sync_pending: dict[int, tuple[list[tuple[str, int, str, int]], Source]] = {}
        self._deadlines: dict[int, Deadline] = {}  # RPDOs with an event timer
        self._sync_watch: Deadline | None = None  # 0x1006: the SYNC's own deadline
        self._sync_length_error = False
        self._last_sync_at: float | None = None  # the node's clock at the last SYNC
        self.sync_late_rpdos = 0  # synchronous RPDOs dropped: outside the window (0x1007)
        self._length_error: dict[int, int] = {}  # RPDO n -> its length EMCY (0: none)
        self._short = RateLimitedLog(log)  # RPDOs shorter than their mapping
        # RPDO writes handed to the loop (counted on the receive thread) and done (on the
        # loop): the node's SDO reads of the image go through the loop while they differ.
        self.handed = 0
        self.done = 0
        self.sent = 0  # TPDO frames
        self.lost_snds = 0  # SND frames that fell out of a full queue
        self.sync_dropped = 0  # synchronous TPDOs not sent: their SYNC was handled too late
        # From a SYNC frame's time stamp (its arrival on our bus) to its TPDOs sent: the
        # node's own share of the master's SYNC->TPDO delay, over the SYNCs that sent any.
        self.sync_answered = 0
        self.sync_latency_max = 0.0  # seconds
        self.sync_latency_over = [0] * len(SYNC_LATENCY_BOUNDS)  # answered later than each
        self._last_sync_stamp = 0.0
        self._sync_period = 0.0  # between the last two SYNCs (their frames' time stamps)
        self._lost_logged = 0.0

    # -- configuration (receive thread for RPDOs and SYNC, loop for TPDOs) ------------------

    def configure_all(self) -> None:
        """From the parameters as they are now (start, reset communication)."""
        for n in self.tpdos:
            self.configure_rpdo(n)
        self.configure_sync()
        self.configure_sync_period()
        self.host.call_soon(self._configure_tpdos)

    def _configure_tpdos(self) -> None:
        for n in self.tpdos:
            self.configure_tpdo(n)

    def configure_rpdo(self, n: int) -> None:
        device = self.host.node
        cob = param(device, RPDO_COMMUNICATION + n - 1, 1)
        sync = param(device, RPDO_COMMUNICATION + n - 1, 2) <= 240
        self.rpdos[n] = Rpdo(n, cob, sync, Layout.of(device, RPDO_MAPPING + n - 1))
        self._sync_pending.pop(n, None)
        self._configure_deadline(n, param(device, RPDO_COMMUNICATION + n - 1, 5))
        old = self._subscribed.get(n)
        if old == cob:
            return
        callback = self._rpdo_callbacks[n]
        if old is not None and not old & NOT_VALID:
            self.host.unsubscribe(old & 0x7FF, callback)
        if not cob & NOT_VALID:
            self.host.subscribe(cob & 0x7FF, callback)
        self._subscribed[n] = cob

    def _configure_deadline(self, n: int, ms: int) -> None:
        """Deadline monitoring as 0x14xx:5 says now (0: none)."""
        old = self._deadlines.pop(n, None)
        if old is not None and round(old.timeout_s * 1000) == ms:
            self._deadlines[n] = old
            return
        if old is not None:
            old.close()
        if ms:
            host = self.host
            self._deadlines[n] = Deadline(ms / 1000, host.clock, host.call_soon,
                                          lambda: host.operational,
                                          lambda: host.rpdo_timeout(n, ms),
                                          lambda: host.rpdo_back(n))

    def configure_sync_period(self) -> None:
        """0x1006 as it is now: SYNC timeout monitoring (1.5 periods) from the next SYNC on,
        or none."""
        period_us = param(self.host.node, CYCLE_PERIOD, 0)
        if self._sync_watch is not None:
            self._sync_watch.close()
            self._sync_watch = None
        if period_us:
            host = self.host
            self._sync_watch = Deadline(period_us * SYNC_TIMEOUT_PERIODS / 1e6, host.clock,
                                        host.call_soon, lambda: host.operational,
                                        lambda: host.sync_error(EMCY_SYNC_TIMEOUT, True),
                                        lambda: host.sync_error(EMCY_SYNC_TIMEOUT, False))

    def configure_sync(self) -> None:
        cob = param(self.host.node, SYNC_COB_ID, 0) & 0x7FF
        if cob == self._sync_cob:
            return
        if self._sync_cob is not None:
            self.host.unsubscribe(self._sync_cob, self._on_sync)
        self.host.subscribe(cob, self._on_sync)
        self._sync_cob = cob

    def configure_tpdo(self, n: int) -> None:
        """On the loop, after a write to TPDO n's parameters was stored."""
        device, t = self.host.node, self.tpdos[n]
        comm = TPDO_COMMUNICATION + n - 1
        layout = Layout.of(device, TPDO_MAPPING + n - 1)
        with self.lock:
            t.idle()
            t.cob = param(device, comm, 1)
            t.type = param(device, comm, 2)
            t.inhibit_s = param(device, comm, 3) * 100e-6
            t.event_s = param(device, comm, 5) / 1000
            t.sync_start = param(device, comm, 6)
            t.layout = layout
            t.getters = tuple(getter(i, s) for i, s in layout.objects)
            t.live = tuple(self.host.getter(i, s) for i, s in layout.objects)
            synchronous = any(x.valid and x.type <= 240 for x in self.tpdos.values())
            if synchronous and not self.synchronous:
                self.host.sample()  # not kept up to date meanwhile: all of it, now
            self.synchronous = synchronous
            if self.host.operational and t.valid:
                self._begin(t)

    def close(self) -> None:
        """The node closes: nothing the PDOs armed runs any more -- the TPDOs' timers, and
        the deadlines watched in OPERATIONAL (the RPDOs' event timers, the SYNC's cycle
        period), which run out into AL150 and its EMCY."""
        self.left_operational()

    # -- NMT (loop) -------------------------------------------------------------------------

    def entered_operational(self) -> None:
        with self.lock:
            for t in self.tpdos.values():
                t.idle()
                if t.valid:
                    self._begin(t)

    def discard_sync_rpdos(self) -> None:
        """Leaving OPERATIONAL (receive thread): synchronous RPDO data not yet applied is
        dropped, as CANopenNode's CO_RPDO_process does; the next SYNC applies nothing of it."""
        self._sync_pending.clear()

    def left_operational(self) -> None:
        with self.lock:
            for t in self.tpdos.values():
                t.idle()
        for deadline in self._deadlines.values():
            deadline.stop()  # no RPDO is expected outside OPERATIONAL
        if self._sync_watch is not None:
            self._sync_watch.stop()  # nor a SYNC handled
        self._last_sync_at = None

    def _begin(self, t: Tpdo) -> None:
        """A TPDO comes to life: an event-driven one says where things stand (unless all it
        maps is the last SND: it speaks of SNDs only), and its event timer starts."""
        assert t.layout is not None
        if t.type == 0:
            t.reference = self._frame(t)  # what a change is a change from
        if t.type in EVENT_TYPES:
            if not t.layout.only_snd:
                t.pending = self._frame(t)
                self._ready(t)
            self._arm_event_timer(t)

    # -- changes (loop) -----------------------------------------------------------------------

    def image_changed(self) -> None:
        self._changed(lambda layout: layout.image)

    def status_changed(self) -> None:
        self._changed(lambda layout: layout.status)

    def snd(self) -> None:
        """An SND happened: one frame each for the TPDOs that map the last SND."""
        if not self.host.operational:
            return
        with self.lock:
            for t in self.tpdos.values():
                if not t.valid or t.layout is None:
                    continue
                if t.layout.snd and t.type in EVENT_TYPES:
                    if len(t.queue) == SND_QUEUE:
                        t.queue.popleft()
                        self._lost_snd(t)
                    t.queue.append(self._frame(t))
                    self._ready(t)
                elif t.layout.snd or t.layout.status:
                    self._change(t)

    def _changed(self, uses: Callable[[Layout], bool]) -> None:
        if not self.host.operational:
            return
        with self.lock:
            for t in self.tpdos.values():
                if t.valid and t.layout is not None and uses(t.layout):
                    self._change(t)

    def _frame(self, t: Tpdo) -> bytes:
        """A frame the loop builds.  An event-driven TPDO's: of the values as they are now
        (only the loop sends it).  A synchronous one's (type 0's reference): from the
        snapshot with what the loop heard published, so the SYNC after it compares what it
        saw, and the values that change without an event sampled now if it maps any (as a
        SYNC samples them)."""
        layout = t.layout
        assert layout is not None
        if t.type in EVENT_TYPES:
            return t.live_frame()
        return t.frame(self.host.sample() if layout.sampled
                       else self.host.current(statuses=layout.status))

    def _change(self, t: Tpdo) -> None:
        if t.type == 0:
            # A write of the same value, or of bytes this TPDO does not map, is no change of
            # its data (CiA 301 7.2.2.2: acyclic synchronous, "after an event").
            if self._frame(t) != t.reference:
                t.sync_due = True
        elif t.type in EVENT_TYPES:
            data = self._frame(t)
            if data != (t.pending if t.pending is not None else t.last):
                t.pending = data
                self._ready(t)

    def _lost_snd(self, t: Tpdo) -> None:
        self.lost_snds += 1
        now = time.monotonic()
        if now - self._lost_logged > 10:
            self._lost_logged = now
            log.warning("TPDO%d: more than %d SNDs wait for the inhibit time; the oldest are "
                        "dropped (%d so far)", t.n, SND_QUEUE, self.lost_snds)

    # -- transmission (loop) ----------------------------------------------------------------

    def _ready(self, t: Tpdo) -> None:
        """Send now, or when the inhibit time has passed."""
        if t.inhibit_timer is not None:
            return
        wait = t.last_t + t.inhibit_s - self.host.clock.monotonic()
        if wait <= 0:
            self._transmit(t)
        else:
            t.inhibit_timer = self.host.clock.call_later(wait, lambda: self._inhibit_over(t))

    def _inhibit_over(self, t: Tpdo) -> None:
        with self.lock:
            t.inhibit_timer = None
            # A loop whose timers have a millisecond's resolution (uvloop) may fire a hair
            # early: the inhibit time is kept on the clock's own (nanosecond) reckoning.
            wait = t.last_t + t.inhibit_s - self.host.clock.monotonic()
            if wait > 0:
                t.inhibit_timer = self.host.clock.call_later(wait,
                                                              lambda: self._inhibit_over(t))
                return
            self._transmit(t)

    def _transmit(self, t: Tpdo) -> None:
        if not (self.host.operational and t.valid):
            t.idle()
            return
        if t.queue:
            data = t.queue.popleft()
        elif t.pending is not None:
            data, t.pending = t.pending, None
            if data == t.last and not t.force:
                return  # changed and changed back within the inhibit time
        elif t.force:
            data = self._frame(t)
        else:
            return
        t.force = False
        self._send(t, data)
        self._arm_event_timer(t)
        if t.queue or t.pending is not None:
            self._ready(t)

    def _send(self, t: Tpdo, data: bytes) -> None:
        self.host.send(t.cob & 0x7FF, data)
        t.last = data
        t.last_t = self.host.clock.monotonic()
        self.sent += 1

    def _arm_event_timer(self, t: Tpdo) -> None:
        if t.event_timer is not None:
            t.event_timer.cancel()
            t.event_timer = None
        if t.event_s > 0 and t.type in EVENT_TYPES:
            t.event_timer = self.host.clock.call_later(t.event_s, lambda: self._event_due(t))

    def _event_due(self, t: Tpdo) -> None:
        with self.lock:
            t.event_timer = None
            wait = t.last_t + t.event_s - self.host.clock.monotonic()
            if wait > 0:  # fired early (a coarse loop clock): not yet
                t.event_timer = self.host.clock.call_later(wait, lambda: self._event_due(t))
                return
            t.force = True
            self._ready(t)

    # -- RPDOs and SYNC (receive thread, then loop) -------------------------------------------

    def _rpdo_callback(self, n: int) -> Callable[[int, bytearray, float], None]:
        return lambda can_id, data, timestamp: self._on_rpdo(n, can_id, data)

    def _on_rpdo(self, n: int, can_id: int, data: bytearray) -> None:
        if not self.host.operational:
            return  # PDOs only in OPERATIONAL
        r = self.rpdos[n]
        deadline = self._deadlines.get(n)
        if deadline is not None:
            deadline.seen()
        size = r.layout.frame.size
        # CiA 301 7.2.2.x: a shorter frame is not processed (EMCY 0x8210); of a longer one
        # the first bytes are used (EMCY 0x8220).  One EMCY when the error begins, an error
        # reset when a frame of the right length comes.
        self._length(n, EMCY_RPDO_SHORT if len(data) < size else
                     EMCY_RPDO_LONG if len(data) > size else 0)
        if len(data) < size:
            self._short.note(f"RPDO{n} 0x{can_id:03X} with {len(data)} bytes ignored "
                             f"({size} mapped)")
            return
        values = r.layout.frame.unpack_from(bytes(data))
        changes = [(area, i, view, v) for (area, i, view), v in zip(r.targets, values,
                                                                   strict=True)]
        if not changes:
            return
        who = Source(SourceKind.CANOPEN, f"RPDO{n} 0x{can_id:03X}")
        if r.sync:
            window_us = param(self.host.node, SYNC_WINDOW, 0)
            if window_us and self._last_sync_at is not None and \
                    self.host.clock.monotonic() - self._last_sync_at > window_us / 1e6:
                self.sync_late_rpdos += 1  # outside the synchronous window: discarded
                return
            self._sync_pending[n] = (changes, who)  # applied at the next SYNC; the last wins
            return
        self.handed += 1
        self.host.call_soon(lambda: self._apply([(changes, who)]))

    def _length(self, n: int, emcy: int) -> None:
        if self._length_error.get(n, 0) != emcy:
            self._length_error[n] = emcy
            self.host.call_soon(lambda: self.host.rpdo_length(n, emcy))

    def _apply(self, batches: list[tuple[list[tuple[str, int, str, int]], Source]]) -> None:
        for changes, who in batches:
            try:
                self.host.apply(changes, who)
            finally:
                self.done += 1

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """At a SYNC (receive thread): the synchronous TPDOs send what they sample now --
        here, from the values the loop published, so a busy loop never delays them -- then
        the RPDO data received since the last SYNC is handed to the loop (inputs sampled,
        outputs actuated).  A SYNC this thread got to only after the next one was due (it
        was held up), and at least SYNC_WINDOW_MIN_S late, sends nothing: its TPDOs are
        dropped and counted (``sync_dropped``), never sent late in a burst."""
        if not self.host.operational:
            return
        self._last_sync_at = self.host.clock.monotonic()
        if self._sync_watch is not None:
            self._sync_watch.seen()
        overflow = param(self.host.node, SYNC_OVERFLOW, 0)
        wrong = len(data) != (1 if overflow else 0)  # a counter byte iff 0x1019 > 0
        if wrong != self._sync_length_error:
            self._sync_length_error = wrong
            self.host.call_soon(lambda: self.host.sync_error(EMCY_SYNC_LENGTH, wrong))
        now = time.time()  # python-can stamps frames with the wall clock
        period = self._sync_period
        if self._last_sync_stamp and timestamp > self._last_sync_stamp:
            self._sync_period = timestamp - self._last_sync_stamp
        self._last_sync_stamp = timestamp
        counter = data[0] if data else None
        stale = bool(timestamp) and now - timestamp > max(period, SYNC_WINDOW_MIN_S)
        window_us = param(self.host.node, SYNC_WINDOW, 0)
        if window_us and timestamp and now - timestamp > window_us / 1e6:
            stale = True  # handled after the synchronous window closed (0x1007)
        answered = sampled = False
        view = self.host.view  # one snapshot for all of this SYNC's TPDOs
        with self.lock:
            for t in self.tpdos.values():
                if t.valid and t.layout is not None and t.type <= 240 \
                        and self._sync_tpdo(t, view, counter, send=not stale):
                    answered = True
                    sampled |= t.layout.sampled
        if sampled:
            self.host.sample_later()  # block N, line, the PLC: as of this SYNC for the next
        if answered:  # (a frame without a time stamp: counted, its latency unknown)
            self._answered(time.time() - timestamp if timestamp else 0.0)
        batches = list(self._sync_pending.values())
        self._sync_pending.clear()
        self.handed += len(batches)
        if batches:
            self.host.call_soon(lambda: self._apply(batches))

    def _answered(self, latency: float) -> None:
        self.sync_answered += 1
        if latency > self.sync_latency_max:
            self.sync_latency_max = latency
        for i, bound in enumerate(SYNC_LATENCY_BOUNDS):
            if latency <= bound:
                break
            self.sync_latency_over[i] += 1

    def _sync_tpdo(self, t: Tpdo, view: Snapshot, counter: int | None,
                   send: bool = True) -> bool:
        """Whether this SYNC sent a frame of ``t`` (receive thread, under the lock)."""
        if t.type == 0:
            if t.sync_due:
                t.sync_due = False
                return self._sync_send(t, view, send, unless=t.reference)  # unless changed back
            return False
        if not t.started:
            if t.sync_start and counter is not None:
                if counter != t.sync_start:
                    return False
                t.started, t.sync_count = True, t.type - 1  # the first frame now
            else:
                t.started = True
        t.sync_count += 1
        if t.sync_count >= t.type:
            t.sync_count = 0
            return self._sync_send(t, view, send)
        return False

    def _sync_send(self, t: Tpdo, view: Snapshot, send: bool,
                   unless: bytes | None = None) -> bool:
        if not send:
            self.sync_dropped += 1
            return False
        data = t.frame(view)  # the loop's snapshot: nothing here reads the engine
        if unless is not None and data == unless:
            return False
        self._send(t, data)
        if t.type == 0:
            t.reference = data
        return True
