"""The gateway's CANopen node (spec 3.3): canopen's LocalNode over python-can, and what it
does not do by itself.

canopen runs its SDO server, NMT and PDO callbacks on python-can's receive thread.  Nothing
here touches the image or the processes from that thread: writes and status reads are handed
to the asyncio loop and their result (or abort code) awaited (:meth:`CanopenNode._on_loop`);
image reads use an immutable snapshot that the loop publishes after every write, once all of
the write's values are stored (so never half a request), which keeps SDO reads of the image
prompt however busy the loop is.

What this module adds to ``canopen.LocalNode``:

- SDO: a server of our own (:class:`_SdoServer`: one transfer at a time, closed by every
  abort); no service in STOPPED; an abandoned segmented transfer is aborted after 1 s
  (0x05040000); a value out of range, also one carried in a wider type, is 0x06090030; the
  COB-ID rules of CiA 301; the command word answered before it runs;
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
    """The SDO server (CiA 301 7.2.4) with the transfer state of its own.

    canopen's server keeps the state of the last transfer whatever happened to it, so an
    aborted download went on accepting segments and a stray upload segment replayed the last
    buffer.  Here one transfer at most is open (``_mode``), every abort closes it, and a
    segment with no transfer open is 0x05040001.  Block transfers are not served (0x05040001:
    a master falls back to segmented).  Silent in STOPPED; an open transfer abandoned for
    1 s is aborted with 0x05040000 (silently dropped in STOPPED).  canopen's ``upload`` and
    ``download`` for local access stay as they are.
    """

    def __init__(self, rx_cobid: int, tx_cobid: int, node: _Node) -> None:
        super().__init__(rx_cobid, tx_cobid, node)
        self._gateway_node = node
        self._lock = threading.Lock()
        self._mode: str | None = None  # "upload" | "download" while a transfer is open
        self._buffer_: bytearray = bytearray()
        self._toggle_ = 0
        self._size: int | None = None  # the size a segmented download announced
        self._where = (0, 0)  # the open (or last) transfer's index and sub-index
        self._timer: threading.Timer | None = None

    def on_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self._gateway_node.nmt._state == NMT_STOPPED:
            return  # no SDO service in STOPPED (CiA 301)
        request = bytes(data).ljust(8, b"\0")
        with self._lock:
            self._stop_timer()
            try:
                self._serve(request)
            except SdoAbortedError as exc:
                self._abort_transfer(exc.code)
            except Exception:  # a bug of ours must not leave a transfer half open
                log.exception("SDO request %s failed", request.hex())
                self._abort_transfer(0x08000000)
            if self._mode is not None:
                self._timer = threading.Timer(SEGMENTED_TIMEOUT_S, self._expire)
                self._timer.daemon = True
                self._timer.start()

    def _serve(self, request: bytes) -> None:
        command = request[0]
        ccs = command & 0xE0
        if ccs == 0x80:  # the client aborts: close, no answer
            self._mode = None
            return
        if ccs in (0x20, 0x40):  # initiate download / upload: a new transfer
            self._mode = None
            index, subindex = struct.unpack_from("<HB", request, 1)
            self._where = (index, subindex)
            if ccs == 0x40:
                self._initiate_upload(index, subindex)
            else:
                self._initiate_download(command, request, index, subindex)
            return
        if ccs == 0x60 and self._mode == "upload":
            self._upload_segment(command)
            return
        if ccs == 0x00 and self._mode == "download":
            self._download_segment(command, request)
            return
        # A segment with no such transfer open, a block transfer, or no such command.
        if ccs in (0xA0, 0xC0, 0xE0):  # these carry an index: name it
            self._where = struct.unpack_from("<HB", request, 1)
        self._mode = None
        raise SdoAbortedError(ABORT_COMMAND)

    def _initiate_upload(self, index: int, subindex: int) -> None:
        data = self._gateway_node.get_data(index, subindex, check_readable=True)
        if not data:
            raise SdoAbortedError(0x08000024)  # no data available
        if len(data) <= 4:
            self.send_response(struct.pack("<BHB", 0x43 | (4 - len(data)) << 2, index,
                                           subindex) + data.ljust(4, b"\0"))
            return
        self._mode, self._buffer_, self._toggle_ = "upload", bytearray(data), 0
        self.send_response(struct.pack("<BHBL", 0x41, index, subindex, len(data)))

    def _upload_segment(self, command: int) -> None:
        if command & 0x10 != self._toggle_:
            raise SdoAbortedError(0x05030000)  # toggle bit not alternated
        chunk = bytes(self._buffer_[:7])
        del self._buffer_[:7]
        last = not self._buffer_
        self.send_response(bytes((self._toggle_ | (7 - len(chunk)) << 1 | int(last),))
                           + chunk.ljust(7, b"\0"))
        self._toggle_ ^= 0x10
        if last:
            self._mode = None

    def _initiate_download(self, command: int, request: bytes, index: int,
                           subindex: int) -> None:
        node = self._gateway_node
        obj = node.object_for(index, subindex)
        if not obj.writable:
            raise SdoAbortedError(0x06010002)
        if command & 0x02:  # expedited
            size = 4 - (command >> 2 & 0x3) if command & 0x01 else 4
            node.set_data(index, subindex, request[4:4 + size], check_writable=True)
            self.send_response(struct.pack("<BHB4x", 0x60, index, subindex))
            return
        self._size = struct.unpack_from("<L", request, 4)[0] if command & 0x01 else None
        if self._size is not None:
            node.check_size(obj, self._size)  # a number of the wrong size: refused now
        self._mode, self._buffer_, self._toggle_ = "download", bytearray(), 0
        self.send_response(struct.pack("<BHB4x", 0x60, index, subindex))

    def _download_segment(self, command: int, request: bytes) -> None:
        if command & 0x10 != self._toggle_:
            raise SdoAbortedError(0x05030000)  # toggle bit not alternated
        self._buffer_ += request[1:8 - (command >> 1 & 0x7)]
        if command & 0x01:  # the last segment
            data = bytes(self._buffer_)
            if self._size is not None and len(data) != self._size:
                raise SdoAbortedError(ABORT_LENGTH)  # not what it announced
            index, subindex = self._where
            node = self._gateway_node
            node.check_size(node.object_for(index, subindex), len(data))
            node.set_data(index, subindex, data, check_writable=True)
            self._mode = None
        self.send_response(bytes((0x20 | self._toggle_,)) + bytes(7))
        self._toggle_ ^= 0x10

    def _abort_transfer(self, code: int) -> None:
        """Answer with an abort naming the transfer's object, and close it."""
        self._mode = None
        index, subindex = self._where
        self.send_response(struct.pack("<BHBL", 0x80, index, subindex, code))

    def _stop_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _expire(self) -> None:
        with self._lock:
            if self._mode is None:
                return
            if self._gateway_node.nmt._state == NMT_STOPPED:
                self._mode = None  # nothing is sent in STOPPED
                return
            log.info("SDO %s of 0x%04X:%02X abandoned: abort after %g s", self._mode,
                     *self._where, SEGMENTED_TIMEOUT_S)
            self._abort_transfer(ABORT_TIMEOUT)

    def close(self) -> None:
        with self._lock:
            self._stop_timer()


class _Node(canopen.LocalNode):
    """A LocalNode with our SDO server and the value-range checks of spec 3.3."""

    def __init__(self, node_id: int, od: canopen.ObjectDictionary) -> None:
        super().__init__(node_id, od)
        self.sdo = _SdoServer(0x600 + node_id, 0x580 + node_id, self)

    def object_for(self, index: int, subindex: int) -> ODVariable:
        """The object an SDO names, or the abort: 0x06020000 no object, 0x06090011 no such
        sub-index (a VAR has only 0)."""
        if index not in self.object_dictionary:
            raise SdoAbortedError(0x06020000)
        obj = self.object_dictionary[index]
        if isinstance(obj, ODVariable):
            if subindex != 0:
                raise SdoAbortedError(0x06090011)
            return obj
        # canopen's ODArray makes up any sub-index 1..255 from its first member: only the
        # ones the dictionary defines exist here.
        if subindex not in obj.subindices:
            raise SdoAbortedError(0x06090011)
        return obj[subindex]

    @staticmethod
    def check_size(obj: ODVariable, size: int) -> None:
        """A segmented transfer to a number must carry exactly its size (CiA 301: 0x06070012
        too long, 0x06070013 too short); only an expedited one may use a wider type."""
        if obj.data_type in NUMBER_TYPES and 8 * size != len(obj):
            raise SdoAbortedError(0x06070012 if 8 * size > len(obj) else 0x06070013)

    def get_data(self, index: int, subindex: int, check_readable: bool = False) -> bytes:
        # LocalNode.get_data's steps, with our lookup: canopen's tests `subindex in array`,
        # which (ODArray has no __contains__) sorts every sub-index on every access.
        obj = self.object_for(index, subindex)
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
        obj = self.object_for(index, subindex)
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
            if command == 0x81:
                # Reset node also restores the node's own application values: the SND sender
                # written to 0x2400:2.  The image behind 0x2000..0x23FF is the soft PLC's, not
                # the node's (docs/decisions.md): it is left as it is.
                self.node.data_store.pop(COMMAND, None)
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
        # On the CAN thread, before canopen stores the value and answers: an abort raised
        # here refuses the write.
        if index in (0x1400, 0x1401, 0x1800, 0x1801) and subindex == 1:
            cob = int.from_bytes(data, "little")
            self._check_cob_id(index, cob)
            if index < 0x1800:  # in effect before the answer goes out
                self._subscribe_rpdo(index - 0x1400 + 1, cob)
            return
        if index < 0x2000:
            return
        value = od.decode_raw(data)
        assert isinstance(value, int)
        if index == COMMAND and subindex == 1:
            # Accepted at once; the work (a cycle start may parse a long program) runs on,
            # and its outcome shows in the status objects, the EMCY and the trace.
            if value not in (1, 2, 3):
                raise SdoAbortedError(ABORT_RANGE)
            self._call_soon(lambda: self._run_command(value))
            return
        who = f"canopen SDO 0x{0x600 + self.node_id:03X}"
        self._on_loop(lambda: self._write(index, subindex, value, who))

    def _run_command(self, word: int) -> None:
        try:
            self.backend.command(word)
        except Exception:  # answered already: say it in the log
            log.exception("command %d written through 0x2400:1 failed", word)

    def _check_cob_id(self, index: int, cob: int) -> None:
        """CiA 301 7.5.2.35/36: the PDO COB-ID rules (abort 0x06090030 otherwise)."""
        current = self._comm(index, 1)
        if cob & 0x20000000:
            raise SdoAbortedError(ABORT_RANGE)  # 29-bit identifiers are not supported
        if index >= 0x1800 and not cob & 0x40000000:
            # canopen drops remote frames, so the node cannot answer an RTR: it says so.
            raise SdoAbortedError(ABORT_RANGE)
        valid_now, valid_then = not current & 0x80000000, not cob & 0x80000000
        if valid_now and valid_then and (cob ^ current) & 0x1FFFFFFF:
            raise SdoAbortedError(ABORT_RANGE)  # the id changes only while the PDO is off
        if valid_then and _restricted(cob & 0x7FF):
            raise SdoAbortedError(ABORT_RANGE)

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
            self._subscribe_rpdo(n, self._comm(0x1400 + n - 1, 1))

    def _subscribe_rpdo(self, n: int, cob: int) -> None:
        """RPDO n listens on ``cob`` (bit 31: not at all) from now on."""
        old = self._rpdo_cobs.get(n)
        if old == cob:
            return
        callback = self._rpdo_callbacks[n]
        if old is not None and not old & 0x80000000:
            self.network.unsubscribe(old & 0x7FF, callback)
        if not cob & 0x80000000:
            self.network.subscribe(cob & 0x7FF, callback)
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
        stopped = self.node.nmt._state == NMT_STOPPED  # no EMCY in STOPPED (CiA 301)
        if isinstance(event, ev.Alarm):
            self._alarmed = True
            register = self._error_register()
            if not stopped:
                self.node.emcy.send(EMCY_SOFTWARE, register,
                                    struct.pack("<BH2x", event.proc & 0xFF,
                                                int(event.code) & 0xFFFF))
        elif isinstance(event, ev.End) and event.how == "reset" and self._alarmed:
            # A reset clears the alarms one process at a time: when none is left, say so.
            if self._error_register() == 0:
                self._alarmed = False
                if not stopped:
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


# CiA 301 table 3: identifiers no PDO may use (NMT, SYNC/EMCY, TIME, SDO, NMT error control,
# LSS).
_RESTRICTED = ((0x000, 0x07F), (0x101, 0x180), (0x581, 0x5FF), (0x601, 0x67F), (0x6E0, 0x6FF),
               (0x701, 0x77F), (0x780, 0x7FF))


def _restricted(can_id: int) -> bool:
    return any(lo <= can_id <= hi for lo, hi in _RESTRICTED)


def _last_snd(engine: Engine) -> tuple[int, int, int, int]:
    sender, target, n, number = engine.last_snd or (0, 0, 0, 0)
    return number & 0xFFFFFFFF, sender, target, n & 0xFFFF

