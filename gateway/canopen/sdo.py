"""The node's SDO server (CiA 301 7.2.4) and the LocalNode it serves, with the value checks
of spec 3.3.  The server runs on python-can's receive thread; what it reads and writes goes
through the node's callbacks (``ncgate.gateway.canopen.node``)."""

from __future__ import annotations

import logging
import struct
import threading
from collections.abc import Callable

import canopen
from canopen.nmt import NmtSlave
from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import NUMBER_TYPES, SIGNED_TYPES
from canopen.sdo.constants import (
    EXPEDITED,
    NO_MORE_DATA,
    REQUEST_ABORTED,
    REQUEST_BLOCK_DOWNLOAD,
    REQUEST_BLOCK_UPLOAD,
    REQUEST_DOWNLOAD,
    REQUEST_SEGMENT_DOWNLOAD,
    REQUEST_SEGMENT_UPLOAD,
    REQUEST_UPLOAD,
    RESPONSE_ABORTED,
    RESPONSE_DOWNLOAD,
    RESPONSE_SEGMENT_DOWNLOAD,
    RESPONSE_SEGMENT_UPLOAD,
    RESPONSE_UPLOAD,
    SIZE_SPECIFIED,
    TOGGLE_BIT,
)
from canopen.sdo.exceptions import SdoAbortedError
from canopen.sdo.server import SdoServer

from ncgate.gateway.canopen.clock import Clock, Timer
from ncgate.gateway.canopen.codes import (
    ABORT_GENERAL_ERROR,
    ABORT_INVALID_COMMAND_SPECIFIER,
    ABORT_INVALID_VALUE,
    ABORT_LENGTH_NOT_MATCHED,
    ABORT_LENGTH_TOO_HIGH,
    ABORT_LENGTH_TOO_LOW,
    ABORT_NO_DATA_AVAILABLE,
    ABORT_NO_SDO_CONNECTION,
    ABORT_NO_SUBINDEX,
    ABORT_NOT_IN_OD,
    ABORT_READ_WRITEONLY,
    ABORT_TIMED_OUT,
    ABORT_TOGGLE_NOT_ALTERNATED,
    ABORT_WRITE_READONLY,
)

log = logging.getLogger("ncgate.canopen")

SEGMENTED_TIMEOUT_S = 1.0
# A segmented download to an object that is no number carries at most this many bytes.
MAX_SEGMENTED_BYTES = 1 << 16


CCS_MASK = 0xE0  # the command specifier's bits of an SDO request's first byte

class Deferred(Exception):
    """Raised by a write callback whose work must run on the loop: the answer follows from
    there when the work is done, and the receive thread goes on meanwhile (heartbeats,
    SYNCs, other SDOs are never held up behind the loop)."""

    def __init__(self, work: Callable[[], None]) -> None:
        super().__init__("deferred to the loop")
        self.work = work


class SdoService(SdoServer):
    """The SDO server (CiA 301 7.2.4) with the transfer state of its own.

    canopen's server keeps the state of the last transfer whatever happened to it, so an
    aborted download went on accepting segments and a stray upload segment replayed the last
    buffer.  Here one transfer at most is open (``_mode``), every abort closes it, and a
    segment with no transfer open is 0x05040001.  Block transfers are not served (0x05040001:
    a master falls back to segmented).  Silent in STOPPED; an open transfer abandoned for
    1 s is aborted with 0x05040000 (silently dropped in STOPPED).  canopen's ``upload`` and
    ``download`` for local access stay as they are.
    """

    def __init__(self, rx_cobid: int, tx_cobid: int, node: Device) -> None:
        super().__init__(rx_cobid, tx_cobid, node)
        self._gateway_node = node
        self._lock = threading.Lock()
        self._mode: str | None = None  # "upload" | "download" while a transfer is open
        self._buffer_: bytearray = bytearray()
        self._toggle_ = 0
        self._size: int | None = None  # the size a segmented download announced
        self._room = 0  # the most bytes the segmented download open may carry
        self._requests = 0  # requests served: a deferred answer is for the latest only
        self._where = (0, 0)  # the open (or last) transfer's index and sub-index
        self._timer: Timer | None = None

    def on_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self._gateway_node.nmt.state == "STOPPED":
            return  # no SDO service in STOPPED (CiA 301)
        request = bytes(data).ljust(8, b"\0")
        with self._lock:
            self._requests += 1  # a write still waiting for the loop is not answered now
            self._stop_timer()
            try:
                self._serve(request)
            except SdoAbortedError as exc:
                self._abort_transfer(exc.code)
            except Exception:  # a bug of ours must not leave a transfer half open
                log.exception("SDO request %s failed", request.hex())
                self._abort_transfer(ABORT_GENERAL_ERROR)
            if self._mode is not None:
                self._timer = self._gateway_node.clock.call_later(SEGMENTED_TIMEOUT_S,
                                                                  self._expire)

    def _serve(self, request: bytes) -> None:
        command = request[0]
        ccs = command & CCS_MASK
        if ccs == REQUEST_ABORTED:  # the client aborts: close, no answer
            self._mode = None
            return
        if ccs in (REQUEST_DOWNLOAD, REQUEST_UPLOAD):  # initiate: a new transfer
            self._mode = None
            index, subindex = struct.unpack_from("<HB", request, 1)
            self._where = (index, subindex)
            if ccs == REQUEST_UPLOAD:
                self._initiate_upload(index, subindex)
            else:
                self._initiate_download(command, request, index, subindex)
            return
        if ccs == REQUEST_SEGMENT_UPLOAD and self._mode == "upload":
            self._upload_segment(command)
            return
        if ccs == REQUEST_SEGMENT_DOWNLOAD and self._mode == "download":
            self._download_segment(command, request)
            return
        # A segment with no such transfer open, a block transfer, or no such command.
        if ccs in (REQUEST_BLOCK_UPLOAD, REQUEST_BLOCK_DOWNLOAD, CCS_MASK):  # with an index
            self._where = struct.unpack_from("<HB", request, 1)
        self._mode = None
        raise SdoAbortedError(ABORT_INVALID_COMMAND_SPECIFIER)

    def _initiate_upload(self, index: int, subindex: int) -> None:
        data = self._gateway_node.get_data(index, subindex, check_readable=True)
        if not data:
            raise SdoAbortedError(ABORT_NO_DATA_AVAILABLE)  # no data available
        if len(data) <= 4:
            command = RESPONSE_UPLOAD | EXPEDITED | SIZE_SPECIFIED | (4 - len(data)) << 2
            self.send_response(struct.pack("<BHB", command, index, subindex)
                               + data.ljust(4, b"\0"))
            return
        self._mode, self._buffer_, self._toggle_ = "upload", bytearray(data), 0
        self.send_response(struct.pack("<BHBL", RESPONSE_UPLOAD | SIZE_SPECIFIED, index,
                                       subindex, len(data)))

    def _upload_segment(self, command: int) -> None:
        if command & TOGGLE_BIT != self._toggle_:
            raise SdoAbortedError(ABORT_TOGGLE_NOT_ALTERNATED)
        chunk = bytes(self._buffer_[:7])
        del self._buffer_[:7]
        last = not self._buffer_
        self.send_response(bytes((RESPONSE_SEGMENT_UPLOAD | self._toggle_
                                  | (7 - len(chunk)) << 1 | (NO_MORE_DATA if last else 0),))
                           + chunk.ljust(7, b"\0"))
        self._toggle_ ^= TOGGLE_BIT
        if last:
            self._mode = None

    def _initiate_download(self, command: int, request: bytes, index: int,
                           subindex: int) -> None:
        node = self._gateway_node
        obj = node.object_for(index, subindex)
        if not obj.writable:
            raise SdoAbortedError(ABORT_WRITE_READONLY)
        if command & EXPEDITED:
            if command & SIZE_SPECIFIED:
                size = 4 - (command >> 2 & 0x3)
            elif obj.data_type in NUMBER_TYPES and len(obj) <= 32:
                size = len(obj) // 8  # size not indicated: the object's own (CiA 301 7.2.4.3.3)
            else:
                size = 4
            answer = struct.pack("<BHB4x", RESPONSE_DOWNLOAD, index, subindex)
            try:
                node.set_data(index, subindex, request[4:4 + size], check_writable=True)
            except Deferred as deferred:
                self._answer_later(deferred, answer)
                return
            self.send_response(answer)
            return
        self._size = (struct.unpack_from("<L", request, 4)[0] if command & SIZE_SPECIFIED
                      else None)
        if self._size is not None:
            node.check_size(obj, self._size)  # a number of the wrong size: refused now
        # The most it may carry: what it announced, else the number's own size (every
        # writable object here is a number; else a cap).  Past it, the transfer is aborted at
        # that segment: an unsized one took 20,000 segments into memory before its last one's
        # abort (CiA 301 lets a server abort as soon as the data passes the object's size).
        self._room = (self._size if self._size is not None else len(obj) // 8
                      if obj.data_type in NUMBER_TYPES else MAX_SEGMENTED_BYTES)
        self._mode, self._buffer_, self._toggle_ = "download", bytearray(), 0
        self.send_response(struct.pack("<BHB4x", RESPONSE_DOWNLOAD, index, subindex))

    def _download_segment(self, command: int, request: bytes) -> None:
        if command & TOGGLE_BIT != self._toggle_:
            raise SdoAbortedError(ABORT_TOGGLE_NOT_ALTERNATED)
        self._buffer_ += request[1:8 - (command >> 1 & 0x7)]
        if len(self._buffer_) > self._room:
            raise SdoAbortedError(ABORT_LENGTH_NOT_MATCHED if self._size is not None
                                  else ABORT_LENGTH_TOO_HIGH)
        if command & NO_MORE_DATA:  # the last segment
            data = bytes(self._buffer_)
            if self._size is not None and len(data) != self._size:
                raise SdoAbortedError(ABORT_LENGTH_NOT_MATCHED)  # not what it announced
            index, subindex = self._where
            node = self._gateway_node
            node.check_size(node.object_for(index, subindex), len(data))
            answer = bytes((RESPONSE_SEGMENT_DOWNLOAD | self._toggle_,)) + bytes(7)
            self._mode = None
            self._toggle_ ^= TOGGLE_BIT
            try:
                node.set_data(index, subindex, data, check_writable=True)
            except Deferred as deferred:
                self._answer_later(deferred, answer)
                return
            self.send_response(answer)
            return
        self.send_response(bytes((RESPONSE_SEGMENT_DOWNLOAD | self._toggle_,)) + bytes(7))
        self._toggle_ ^= TOGGLE_BIT

    def _answer_later(self, deferred: Deferred, answer: bytes) -> None:
        """The write's work runs on the loop; its answer (or abort) is sent from there --
        unless the master has moved on meanwhile (a new request, its own abort), when
        nothing of it is done and nothing answered."""
        request = self._requests
        where = self._where

        def current() -> bool:
            return self._requests == request

        def done(code: int | None) -> None:
            with self._lock:
                if not current():
                    return
                if code is None:
                    self.send_response(answer)
                else:
                    self.send_response(struct.pack("<BHBL", RESPONSE_ABORTED, *where, code))

        self._gateway_node.defer(deferred.work, done, current)

    def _abort_transfer(self, code: int) -> None:
        """Answer with an abort naming the transfer's object, and close it."""
        self._mode = None
        index, subindex = self._where
        self.send_response(struct.pack("<BHBL", RESPONSE_ABORTED, index, subindex, code))

    def _stop_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _expire(self) -> None:
        # On the loop's thread: never wait for the lock there.  A request holding it may be
        # waiting for the loop itself (a write), and it re-arms or closes the transfer anyway.
        if not self._lock.acquire(blocking=False):
            return
        try:
            if self._mode is None:
                return
            if self._gateway_node.nmt.state == "STOPPED":
                self._mode = None  # nothing is sent in STOPPED
                return
            log.info("SDO %s of 0x%04X:%02X abandoned: abort after %g s", self._mode,
                     *self._where, SEGMENTED_TIMEOUT_S)
            self._abort_transfer(ABORT_TIMED_OUT)
        finally:
            self._lock.release()

    def reset(self) -> None:
        """An NMT reset (node or communication): every transfer ends, silently -- no
        abort now, none at the timeout, no answer to a write still waiting for the loop
        (nor is its work done: ``_answer_later``'s ``current()`` is false from now on)."""
        with self._lock:
            self._requests += 1
            self._stop_timer()
            self._mode = None

    def close(self) -> None:
        with self._lock:
            self._stop_timer()


def _run_now(work: Callable[[], None], done: Callable[[int | None], None],
             wanted: Callable[[], bool]) -> None:
    try:
        work()
    except SdoAbortedError as exc:
        done(exc.code)
        return
    done(None)


class Nmt(NmtSlave):
    """canopen's NMT slave, whose heartbeat producer a fault can silence: while
    ``silenced``, nothing starts it -- not a write of 0x1017, not an NMT reset (its boot-up
    message still goes) -- and the period asked for is kept for when it ends."""

    silenced = False

    def start_heartbeat(self, heartbeat_time_ms: int) -> None:
        if self.silenced:
            self._heartbeat_time_ms = heartbeat_time_ms
            self.stop_heartbeat()
            return
        super().start_heartbeat(heartbeat_time_ms)


class Device(canopen.LocalNode):
    """A LocalNode with our SDO server and the value-range checks of spec 3.3."""

    clock: Clock  # the node's (set before the node joins the bus)

    def __init__(self, node_id: int, od: canopen.ObjectDictionary) -> None:
        super().__init__(node_id, od)
        self._write_callbacks.remove(self.nmt.on_write)
        self.nmt: Nmt = Nmt(node_id, self)
        self.add_write_callback(self.nmt.on_write)
        self.sdo = SdoService(0x600 + node_id, 0x580 + node_id, self)
        # Called (on the CAN thread) once a write is stored: the node reconfigures what the
        # value controls (a PDO, the SYNC, the heartbeat consumer).
        self.stored: Callable[[int, int], None] = lambda index, subindex: None
        self.read_hooks: list[Callable[..., int | None]] = []  # add_read_callback's, for get_data
        # Runs a deferred write's work (the gateway: on its loop) and reports the outcome:
        # defer(work, done(abort code or None), still_wanted()).
        self.defer: Callable[[Callable[[], None], Callable[[int | None], None],
                              Callable[[], bool]], None] = _run_now
        # What an accepted write stores (the node: a TPDO COB-ID with bit 30 set).
        self.stored_form: Callable[[int, int, bytes], bytes] = lambda index, sub, data: data

    def add_read_callback(self, callback: Callable[..., int | None]) -> None:
        super().add_read_callback(callback)
        self.read_hooks.append(callback)

    def object_for(self, index: int, subindex: int) -> ODVariable:
        """The object an SDO names, or the abort: 0x06020000 no object, 0x06090011 no such
        sub-index (a VAR has only 0)."""
        if index not in self.object_dictionary:
            raise SdoAbortedError(ABORT_NOT_IN_OD)
        obj = self.object_dictionary[index]
        if isinstance(obj, ODVariable):
            if subindex != 0:
                raise SdoAbortedError(ABORT_NO_SUBINDEX)
            return obj
        # canopen's ODArray makes up any sub-index 1..255 from its first member: only the
        # ones the dictionary defines exist here.
        if subindex not in obj.subindices:
            raise SdoAbortedError(ABORT_NO_SUBINDEX)
        return obj[subindex]

    @staticmethod
    def check_size(obj: ODVariable, size: int) -> None:
        """A segmented transfer to a number must carry exactly its size (CiA 301: 0x06070012
        too long, 0x06070013 too short); only an expedited one may use a wider type."""
        if obj.data_type in NUMBER_TYPES and 8 * size != len(obj):
            raise SdoAbortedError(ABORT_LENGTH_TOO_HIGH if 8 * size > len(obj)
                                  else ABORT_LENGTH_TOO_LOW)

    def get_data(self, index: int, subindex: int, check_readable: bool = False) -> bytes:
        # LocalNode.get_data's steps, with our lookup: canopen's tests `subindex in array`,
        # which (ODArray has no __contains__) sorts every sub-index on every access.
        obj = self.object_for(index, subindex)
        if check_readable and not obj.readable:
            raise SdoAbortedError(ABORT_READ_WRITEONLY)
        for callback in self.read_hooks:
            result = callback(index=index, subindex=subindex, od=obj)
            if result is not None:
                return obj.encode_raw(result)
        stored = self.data_store.get(index, {}).get(subindex)
        if stored is not None:
            return stored
        for value in (obj.value, obj.default):
            if value is not None:
                return obj.encode_raw(value)
        raise SdoAbortedError(ABORT_NO_SDO_CONNECTION)  # resource not available

    def set_data(self, index: int, subindex: int, data: bytes,
                 check_writable: bool = False) -> None:
        obj = self.object_for(index, subindex)
        if check_writable and not obj.writable:
            raise SdoAbortedError(ABORT_WRITE_READONLY)
        if obj.data_type in NUMBER_TYPES and 8 * len(data) != len(obj):
            # A value too big for the object, sent in a wider type, is out of range (spec
            # 3.3); any other size mismatch is a length error.
            if 8 * len(data) > len(obj) and 0 < len(data) <= 8 and obj.max is not None:
                value = int.from_bytes(data, "little", signed=obj.data_type in SIGNED_TYPES)
                if not (obj.min or 0) <= value <= obj.max:
                    raise SdoAbortedError(ABORT_INVALID_VALUE)
            raise SdoAbortedError(ABORT_LENGTH_NOT_MATCHED)
        super().set_data(index, subindex, self.stored_form(index, subindex, data),
                         check_writable)
        self.stored(index, subindex)
