"""The gateway's CANopen node (spec 3.3): canopen's LocalNode over python-can, and what it
does not do by itself.

canopen runs its SDO server, NMT and PDO callbacks on python-can's receive thread.  Nothing
here touches the image or the processes from that thread: writes and status reads are handed
to the asyncio loop and their result (or abort code) awaited (:meth:`CanopenNode._on_loop`);
image reads use an immutable snapshot that the loop publishes after every write, once all of
the write's values are stored (so never half a request), which keeps SDO reads of the image
prompt however busy the loop is.

What this module adds to ``canopen.LocalNode``:

- SDO: no service in STOPPED; an abandoned segmented transfer is aborted after 1 s
  (0x05040000); a value out of range, also one carried in a wider type, is 0x06090030;
- NMT: boot-up and PRE-OPERATIONAL (or OPERATIONAL with ``nmt_autostart``) at start and after
  a reset node / reset communication, which also restores the communication parameters;
- PDOs, only in OPERATIONAL: TPDO1 (process states) sent on change, TPDO2 (last SND) on every
  SND, both with the inhibit time of 0x1800/0x1801 sub 3; RPDO1/RPDO2 stored into SA and K;
- EMCY 0x6200 on every alarm (process number, alarm code in the manufacturer bytes), an
  error-reset EMCY on reset; 0x1001 follows the alarms.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import TypeVar

import canopen
from can_remote import RemoteServer
from canopen.objectdictionary import ODRecord, ODVariable
from canopen.objectdictionary.datatypes import NUMBER_TYPES, SIGNED_TYPES
from canopen.sdo.exceptions import SdoAbortedError
from canopen.sdo.server import SdoServer

from ncgate.config import Config
from ncgate.gateway.canopen.dictionary import (
    CHUNK,
    COMMAND,
    K_BASE,
    LAST_SND,
    MAX_PROCESS_STATES_IN_TPDO1,
    SA_BYTES,
    STATUS_BASE,
    SYVAR_BASE,
    build_dictionary,
)
from ncgate.gateway.wiring import Backend
from ncgate.interpreter.engine import Engine, Process, ProcessState
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.events import Event

log = logging.getLogger("ncgate.canopen")

ABORT_TIMEOUT = 0x05040000
ABORT_COMMAND = 0x05040001
ABORT_LENGTH = 0x06070010
ABORT_RANGE = 0x06090030
ABORT_DEVICE_STATE = 0x08000022
SEGMENTED_TIMEOUT_S = 1.0
EMCY_SOFTWARE = 0x6200
NMT_OPERATIONAL, NMT_STOPPED, NMT_PRE_OPERATIONAL = 5, 4, 127

T = TypeVar("T")


class _SdoServer(SdoServer):
    """canopen's SDO server, silent in STOPPED, with a timeout for segmented downloads."""

    def __init__(self, rx_cobid: int, tx_cobid: int, node: _Node) -> None:
        super().__init__(rx_cobid, tx_cobid, node)
        self._gateway_node = node
        self._lock = threading.Lock()
        self._segmented = False
        self._timer: threading.Timer | None = None

    def on_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self._gateway_node.nmt._state == NMT_STOPPED:
            return  # no SDO service in STOPPED (CiA 301)
        with self._lock:
            command = data[0]
            ccs = command & 0xE0
            # canopen aborts these with the index of the last transfer (None before the first
            # one, which fails): answer them here with the request's own index.
            if ccs in (0xE0, 0xC0) or (ccs == 0x00 and not self._segmented):
                self._refuse(data, ABORT_COMMAND)  # no such command, or no transfer open
                return
            super().on_request(can_id, data, timestamp)
            if ccs == 0x20:  # initiate download: segmented unless expedited
                self._segmented = not command & 0x02
            elif ccs == 0x00:  # download segment: open until the last one
                self._segmented = not command & 0x01
            else:
                self._segmented = False
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
            if self._segmented:
                self._timer = threading.Timer(SEGMENTED_TIMEOUT_S, self._expire)
                self._timer.daemon = True
                self._timer.start()

    def _refuse(self, request: bytes | bytearray, code: int) -> None:
        index, subindex = struct.unpack_from("<HB", bytes(request).ljust(4, b"\0"), 1)
        self.send_response(struct.pack("<BHBL", 0x80, index, subindex, code))

    def _expire(self) -> None:
        with self._lock:
            if self._segmented:
                self._segmented = False
                log.info("SDO segmented transfer abandoned: abort after %g s",
                         SEGMENTED_TIMEOUT_S)
                self.abort(ABORT_TIMEOUT)

    def close(self) -> None:
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None


class _Node(canopen.LocalNode):
    """A LocalNode with our SDO server and the value-range checks of spec 3.3."""

    def __init__(self, node_id: int, od: canopen.ObjectDictionary) -> None:
        super().__init__(node_id, od)
        self.sdo = _SdoServer(0x600 + node_id, 0x580 + node_id, self)

    def _object(self, index: int, subindex: int) -> ODVariable:
        if index not in self.object_dictionary:
            raise SdoAbortedError(0x06020000)
        obj = self.object_dictionary[index]
        if not isinstance(obj, ODVariable):
            # canopen's ODArray makes up any sub-index 1..255 from its first member: only the
            # ones the dictionary defines exist here.
            if subindex not in obj.subindices:
                raise SdoAbortedError(0x06090011)
            obj = obj[subindex]
        return obj

    def get_data(self, index: int, subindex: int, check_readable: bool = False) -> bytes:
        # LocalNode.get_data's steps, with our lookup: canopen's tests `subindex in array`,
        # which (ODArray has no __contains__) sorts every sub-index on every access.
        obj = self._object(index, subindex)
        if check_readable and not obj.readable:
            raise SdoAbortedError(0x06010001)
        for callback in self._read_callbacks:
            result = callback(index=index, subindex=subindex, od=obj)
            if result is not None:
                return obj.encode_raw(result)
        stored = self.data_store.get(index, {}).get(subindex)
        if stored is not None:
            return stored
        for value in (obj.value, obj.default):
            if value is not None:
                return obj.encode_raw(value)
        raise SdoAbortedError(0x060A0023)  # resource not available

    def set_data(self, index: int, subindex: int, data: bytes,
                 check_writable: bool = False) -> None:
        obj = self._object(index, subindex)
        if check_writable and not obj.writable:
            raise SdoAbortedError(0x06010002)
        if obj.data_type in NUMBER_TYPES and 8 * len(data) != len(obj):
            # A value too big for the object, sent in a wider type, is out of range (spec
            # 3.3); any other size mismatch is a length error.
            if 8 * len(data) > len(obj) and 0 < len(data) <= 8 and obj.max is not None:
                value = int.from_bytes(data, "little", signed=obj.data_type in SIGNED_TYPES)
                if not (obj.min or 0) <= value <= obj.max:
                    raise SdoAbortedError(ABORT_RANGE)
            raise SdoAbortedError(ABORT_LENGTH)
        super().set_data(index, subindex, data, check_writable)


class CanopenNode:
    """The node on the bus, wired to the gateway's image and processes."""

    def __init__(self, config: Config, backend: Backend) -> None:
        self.config = config
        self.backend = backend
        self.node_id = config.canopen.node_id
        self.od = build_dictionary(config)
        self.node = _Node(self.node_id, self.od)
        self.network = canopen.Network()
        # The notifier thread wakes this often when the bus is quiet; shutting down waits for
        # it, so the default of 1 s would make every stop last a second.
        self.network.NOTIFIER_CYCLE = 0.05
        self.loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: int | None = None
        self._tpdo_last: dict[int, float] = {}
        self._tpdo1_pending: bytes | None = None
        self._tpdo1_sent: bytes | None = None
        self._tpdo2_queue: deque[bytes] = deque()
        self._tpdo_timer: dict[int, asyncio.TimerHandle] = {}
        self._alarmed = False
        self._rpdo_cobs: dict[int, int] = {}  # RPDO number -> subscribed COB-ID
        self._rpdo_callbacks: dict[int, Callable[[int, bytearray, float], None]] = {
            1: self._on_rpdo1, 2: self._on_rpdo2}
        self._hub: RemoteServer | None = None
        # (SA bytes, K bytes, SYVARs) as of the last write: published by the loop, read by
        # the CAN thread.  A tuple of immutable values, swapped in one assignment.
        self._view: tuple[bytes, bytes, tuple[int, ...]] = (b"", b"", ())
        # RPDO writes handed to the loop (counted by the CAN thread) and done (by the loop):
        # while one is on its way, an SDO read goes through the loop too, behind it, so that
        # what the bus said first is seen first.
        self._rpdo_handed = 0
        self._rpdo_done = 0
        self.hub_address: tuple[str, int] | None = None

    # -- life cycle -----------------------------------------------------------------------

    def start(self) -> None:
        cfg = self.config.canopen
        self.loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        self.network.connect(interface=cfg.interface, channel=cfg.channel, bitrate=cfg.bitrate)
        self.network.add_node(self.node)
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self.network.subscribe(0, self._on_nmt)  # after canopen's own NMT handler
        self._subscribe_rpdos()
        engine = self.backend.engine
        engine.state_listeners.append(self._on_state)
        engine.trace.subscribe(self._on_event)
        self._publish()
        self._unsubscribe_image = self.backend.image.subscribe(lambda values, who:
                                                               self._publish())
        self._boot()
        log.info("CANopen node %d on %s/%s (%s)", self.node_id, cfg.interface, cfg.channel,
                 self.node.nmt.state)
        if cfg.hub:
            self._start_hub()

    def _start_hub(self) -> None:
        """Serve our bus to other processes: each websocket client of the hub gets a bus of
        its own on our interface and channel (python-can-remote)."""
        cfg = self.config.canopen
        hub = RemoteServer(host=cfg.hub_host, port=cfg.hub_port, interface=cfg.interface,
                           channel=cfg.channel, bitrate=cfg.bitrate)
        thread = threading.Thread(target=hub.serve_forever, name="ncgate can-remote hub",
                                  daemon=True)
        thread.start()
        self._hub = hub
        host, port = hub.server_address[:2]
        self.hub_address = (str(host), int(port))
        log.info("CANopen hub for other processes: interface 'remote', channel "
                 "'ws://%s:%d/'", host, port)

    def close(self) -> None:
        if self._hub is not None:
            self._hub.shutdown()
            self._hub.server_close()
            self._hub = None
        for handle in self._tpdo_timer.values():
            handle.cancel()
        self.node.nmt.stop_heartbeat()
        self.node.sdo.close()  # type: ignore[attr-defined]
        engine = self.backend.engine
        if self._on_state in engine.state_listeners:
            engine.state_listeners.remove(self._on_state)
        self._unsubscribe_image()
        self.network.disconnect()

    def _boot(self) -> None:
        """Boot-up message, then PRE-OPERATIONAL (or OPERATIONAL with nmt_autostart)."""
        self.network.send_message(0x700 + self.node_id, b"\x00")
        self.node.nmt.send_command(0x80)  # starts the heartbeat producer (0x1017)
        if self.config.canopen.nmt_autostart:
            self.node.nmt.send_command(0x01)
            self._call_soon(self._entered_operational)

    @property
    def operational(self) -> bool:
        return self.node.nmt._state == NMT_OPERATIONAL

    # -- threads ----------------------------------------------------------------------------

    def _on_loop(self, fn: Callable[[], T], timeout_s: float = 2.0) -> T:
        """Run ``fn`` on the asyncio loop and wait for its result (from the CAN thread)."""
        if threading.get_ident() == self._loop_thread:
            return fn()
        assert self.loop is not None
        future: concurrent.futures.Future[T] = concurrent.futures.Future()

        def run() -> None:
            try:
                future.set_result(fn())
            except BaseException as exc:  # handed back to the CAN thread
                future.set_exception(exc)

        self.loop.call_soon_threadsafe(run)
        return future.result(timeout=timeout_s)

    def _call_soon(self, fn: Callable[[], None]) -> None:
        assert self.loop is not None
        if threading.get_ident() == self._loop_thread:
            self.loop.call_soon(fn)
        else:
            self.loop.call_soon_threadsafe(fn)

    # -- NMT --------------------------------------------------------------------------------

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        command, node = data[0], data[1]
        if node not in (0, self.node_id):
            return
        if command in (0x81, 0x82):  # reset node / reset communication
            self._reset_communication()
            self._boot()
        elif command == 0x01:
            self._call_soon(self._entered_operational)

    def _reset_communication(self) -> None:
        """Communication parameters (0x1000..0x1FFF) back to their defaults."""
        for index in [i for i in self.node.data_store if i < 0x2000]:
            del self.node.data_store[index]
        self._subscribe_rpdos()

    def _entered_operational(self) -> None:
        self._tpdo1_sent = None
        self._on_state(None, ProcessState.IDLE)  # the states as they are now

    # -- SDO: the live image and status -------------------------------------------------------

    def _publish(self) -> None:
        image = self.backend.image
        self._view = (bytes(image.sa), bytes(image.k), tuple(image.syvar))

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> int | None:
        if index == 0x1001:
            return self._on_loop(self._error_register)
        if index < 0x2000 or subindex == 0:
            return None  # the dictionary's own value (stored or default)
        if index < COMMAND and self._rpdo_done == self._rpdo_handed:
            return self._image_value(index, subindex)  # the snapshot, from this thread
        return self._on_loop(lambda: self._read(index, subindex))

    def _image_value(self, index: int, subindex: int) -> int:
        sa, k, syvar = self._view
        if index == SA_BYTES:
            return sa[subindex - 1]
        if index < SYVAR_BASE:
            return k[(index - K_BASE) * CHUNK + subindex - 1]
        return syvar[(index - SYVAR_BASE) * CHUNK + subindex - 1]

    def _error_register(self) -> int:
        return int(any(p.alarm is not None for p in self.backend.engine.processes.values()))

    def _read(self, index: int, subindex: int) -> int:
        """Any manufacturer object, on the loop."""
        engine = self.backend.engine
        if index < COMMAND:
            return self._image_value(index, subindex)
        if STATUS_BASE <= index < LAST_SND:
            s = engine.status(index - STATUS_BASE + 1)
            return [int(s.state), (s.n or 0) & 0xFFFF, s.line & 0xFFFF, int(s.wait_kind),
                    s.wait_target, s.alarm_code & 0xFFFF, s.snd_sent & 0xFFFFFFFF,
                    s.snd_received & 0xFFFFFFFF][subindex - 1]
        if index == LAST_SND:
            return list(_last_snd(engine))[subindex - 1]
        raise SdoAbortedError(0x06010001)  # 0x2400: write-only

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        if index in (0x1400, 0x1401) and subindex == 1:
            self._call_soon(self._subscribe_rpdos)
            return
        if index < 0x2000:
            return
        value = od.decode_raw(data)
        assert isinstance(value, int)
        who = f"canopen SDO 0x{0x600 + self.node_id:03X}"
        self._on_loop(lambda: self._write(index, subindex, value, who))

    def _write(self, index: int, subindex: int, value: int, who: str) -> None:
        backend = self.backend
        if index == SA_BYTES:
            backend.apply_writes([("SA", subindex - 1, "BY", value)], who)
        elif K_BASE <= index < SYVAR_BASE:
            backend.apply_writes([("SK", (index - K_BASE) * CHUNK + subindex - 1, "BY", value)],
                                 who)
        elif SYVAR_BASE <= index < COMMAND:
            backend.apply_writes(
                [("SYVAR", (index - SYVAR_BASE) * CHUNK + subindex - 1, "IN", value)], who)
        elif index == COMMAND:
            self._command(subindex, value)

    def _command(self, subindex: int, value: int) -> None:
        nc = self.config.nc
        if subindex == 1:
            if value not in (1, 2, 3):
                raise SdoAbortedError(ABORT_RANGE)
            self.backend.command(value)
        elif subindex == 2:
            if value not in nc.external:
                raise SdoAbortedError(ABORT_RANGE)  # only an external process sends
        else:
            if not 1 <= value <= nc.processes:
                raise SdoAbortedError(ABORT_RANGE)  # an unknown SND target
            stored = self.node.data_store.get(COMMAND, {}).get(2)
            if stored is None:
                raise SdoAbortedError(ABORT_DEVICE_STATE)  # no sender written yet
            try:
                self.backend.send(stored[0], value)
            except ValueError:
                raise SdoAbortedError(ABORT_DEVICE_STATE) from None  # runs no program

    # -- PDOs -------------------------------------------------------------------------------

    def _comm(self, index: int, subindex: int) -> int:
        stored = self.node.data_store.get(index, {}).get(subindex)
        if stored is not None:
            return int.from_bytes(stored, "little")
        obj = self.od[index]
        assert isinstance(obj, ODRecord)
        return int(obj[subindex].default or 0)

    def _subscribe_rpdos(self) -> None:
        for n in (1, 2):
            cob = self._comm(0x1400 + n - 1, 1)
            old = self._rpdo_cobs.get(n)
            if old == cob:
                continue
            if old is not None:
                self.network.unsubscribe(old, self._rpdo_callbacks[n])
            if not cob & 0x80000000:
                self.network.subscribe(cob & 0x7FF, self._rpdo_callbacks[n])
            self._rpdo_cobs[n] = cob

    def _on_rpdo1(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._on_rpdo("SA", can_id, data)

    def _on_rpdo2(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._on_rpdo("SK", can_id, data)

    def _on_rpdo(self, area: str, can_id: int, data: bytes | bytearray) -> None:
        if not self.operational:
            return  # PDOs only in OPERATIONAL
        if len(data) < 8:
            log.warning("RPDO 0x%03X with %d bytes ignored (8 mapped)", can_id, len(data))
            return
        changes = [(area, i, "BY", b) for i, b in enumerate(bytes(data[:8]))]
        who = f"canopen 0x{can_id:03X}"

        def apply() -> None:
            try:
                self.backend.apply_writes(changes, who)
            finally:
                self._rpdo_done += 1

        self._rpdo_handed += 1
        self._call_soon(apply)

    def _on_state(self, process: Process | None, old: ProcessState) -> None:
        if not self.operational:
            return
        engine = self.backend.engine
        states = bytes(int(engine.processes[k].state) for k in
                       range(1, min(len(engine.processes), MAX_PROCESS_STATES_IN_TPDO1) + 1))
        if states == self._tpdo1_sent:
            return
        self._tpdo1_pending = states
        self._tpdo_ready(1)

    def _on_event(self, event: Event) -> None:
        if isinstance(event, ev.Alarm):
            self._alarmed = True
            register = self._error_register()
            self.node.emcy.send(EMCY_SOFTWARE, register,
                                struct.pack("<BH2x", event.proc & 0xFF, int(event.code) & 0xFFFF))
        elif isinstance(event, ev.End) and event.how == "reset" and self._alarmed:
            # A reset clears the alarms one process at a time: when none is left, say so.
            if self._error_register() == 0:
                self._alarmed = False
                self.node.emcy.reset(0)
        elif isinstance(event, ev.Snd) and self.operational:
            n = event.where[2] if event.where is not None else None
            record = struct.pack("<LBBH", self.backend.engine.trace.counter, event.proc,
                                 event.to, (n or 0) & 0xFFFF)
            self._tpdo2_queue.append(record)
            self._tpdo_ready(2)

    def _tpdo_ready(self, n: int) -> None:
        """Send TPDO n now, or when its inhibit time has passed."""
        if n in self._tpdo_timer:
            return  # a send is already scheduled
        inhibit_s = self._comm(0x1800 + n - 1, 3) * 100e-6
        wait = self._tpdo_last.get(n, -1e9) + inhibit_s - time.monotonic()
        if wait <= 0:
            self._send_tpdo(n)
        else:
            assert self.loop is not None
            self._tpdo_timer[n] = self.loop.call_later(wait, self._inhibit_over, n)

    def _inhibit_over(self, n: int) -> None:
        del self._tpdo_timer[n]
        self._send_tpdo(n)

    def _send_tpdo(self, n: int) -> None:
        if not self.operational:
            self._tpdo2_queue.clear()
            return
        cob = self._comm(0x1800 + n - 1, 1)
        if n == 1:
            data, self._tpdo1_pending = self._tpdo1_pending, None
            if data is None:
                return
            self._tpdo1_sent = data
        else:
            if not self._tpdo2_queue:
                return
            data = self._tpdo2_queue.popleft()
        if not cob & 0x80000000:
            self.network.send_message(cob & 0x7FF, data)
        self._tpdo_last[n] = time.monotonic()
        if n == 2 and self._tpdo2_queue:
            self._tpdo_ready(2)  # every SND goes out, spaced by the inhibit time


def _last_snd(engine: Engine) -> tuple[int, int, int, int]:
    sender, target, n, number = engine.last_snd or (0, 0, 0, 0)
    return number & 0xFFFFFFFF, sender, target, n & 0xFFFF

