"""Modbus framing without I/O: bytes in, requests out; answers in, bytes out (as h11 does for
HTTP).  A transport (``server._Connection`` for TCP and TLS, later a serial line) feeds a
:class:`Framer` what it reads, takes whole requests from it and writes what it encodes.

Two frame formats share one interface:

- :class:`MbapFramer`, Modbus TCP (Modbus Messaging on TCP/IP Implementation Guide V1.0b, 3.1):
  an MBAP header -- transaction id, protocol id 0, length (unit id and PDU, 2..254), unit id
  -- then the PDU.  A stream whose header is bad cannot be resynchronised (the length is the
  only delimiter): :class:`FramingError`, and the transport closes that connection;
- :class:`RtuFramer`, Modbus RTU (Modbus over Serial Line V1.02, 2.5.1): unit id, PDU,
  CRC-16 (low byte first).  The frame's length follows from its function code; a frame whose
  length the code does not give (a function code we do not know) ends at the line's silence
  of 3.5 characters, which the transport reports with :meth:`RtuFramer.gap`.  A bad CRC drops
  the frame silently (the slave discards it and does not answer, 2.5.1.2) and is counted.

The framer pulls: ``feed`` only keeps the bytes, ``next_request`` cuts one request at a time.
A connection answers a bounded number of requests in one loop turn (fairness) and stops
taking them while its client does not read its answers (backpressure); what is not yet taken
stays bytes in the buffer, which is what the backlog is measured in.  A framer that cut every
request of a 256 KiB read at once would hold the loop for thousands of them.

This module also knows the PDU layouts the framing and the fault table need
(:func:`request_pdu_length`, :func:`address_ranges`).  It imports nothing of the gateway but
its error root: no asyncio, no sockets, no pymodbus.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Final, Protocol, TypeAlias

from ncgate.gateway.errors import GatewayError


class FramingError(GatewayError, ValueError):
    """A stream the framer cannot cut into frames any more (a bad MBAP header)."""


# One request as framed: (unit id, PDU -- function code first --, transaction id), the last
# the id its answer must carry on TCP, 0 on RTU, which has none.  A plain tuple: a NamedTuple's
# instance (a tuple subclass, allocated apart from the tuple free lists) cost the pollers' path
# 0.2-0.35 us a request (bench/modbus.py 4., the server's CPU for one: 2.85-3.04 -> 2.65 us).
Request: TypeAlias = tuple[int, bytes, int]


class Framer(Protocol):
    """What a transport needs of a frame format.  Bytes that are fed stay buffered until
    ``next_request`` takes them as a whole request, in the order they came."""

    def feed(self, data: bytes) -> None:
        """Keep ``data`` (any part of any number of frames)."""

    def next_request(self) -> Request | None:
        """The next whole request, or None until more bytes come.  Raises
        :class:`FramingError` when the stream cannot be cut into frames any more."""

    def whole(self, data: bytes) -> Request | None:
        """``data`` as exactly one whole, valid request when nothing is buffered -- the
        common case, taken without the buffer's bookkeeping -- else None and nothing kept
        (then ``feed`` it)."""

    def encode(self, request: Request, answer: bytes) -> bytes:
        """The frame of ``answer`` (a response PDU) to ``request``."""

    @property
    def buffered(self) -> int:
        """Bytes fed and not yet taken as requests (a frame begun, or frames waiting)."""


# -- PDUs --------------------------------------------------------------------------------------

def exception_pdu(fc: int, code: int) -> bytes:
    """An exception answer (Modbus application protocol 7): the function code with its high
    bit set, then the exception code."""
    return bytes(((fc | 0x80) & 0xFF, code))


def _byte_count(offset: int, fixed: int) -> Callable[[bytes | bytearray, int], int | None]:
    """A request whose byte count is its PDU's byte ``offset``: ``fixed`` + that count."""
    def length(data: bytes | bytearray, start: int) -> int | None:
        at = start + offset
        return fixed + data[at] if at < len(data) else None
    return length


# Function code -> the request PDU's length (Modbus application protocol 6): a number, or a
# function of the bytes after the PDU's start (None: not enough of them yet).
_REQUEST_LENGTH: Final[dict[int, int | Callable[[bytes | bytearray, int], int | None]]] = {
    1: 5, 2: 5, 3: 5, 4: 5, 5: 5, 6: 5,
    7: 1, 11: 1, 12: 1, 17: 1,  # serial line only: exception status, event counter/log, id
    8: 5,  # diagnostics: sub-function and one data word (the only form a request has)
    15: _byte_count(5, 6), 16: _byte_count(5, 6),
    20: _byte_count(1, 2), 21: _byte_count(1, 2),  # file records
    22: 7, 23: _byte_count(9, 10), 24: 3,
}
_MEI_READ_DEVICE_ID: Final = 0x0E


def request_pdu_length(data: bytes | bytearray, start: int = 0) -> int | None:
    """The length of the request PDU at ``data[start:]`` from its function code (and byte
    count), or None while too few bytes say it, or -1 when its function code does not say it
    (a code we do not know, or FC43 with an MEI type other than 0x0E)."""
    if start >= len(data):
        return None
    rule = _REQUEST_LENGTH.get(data[start])
    if rule is None:
        if data[start] != 43:
            return -1
        if start + 1 >= len(data):
            return None
        return 4 if data[start + 1] == _MEI_READ_DEVICE_ID else -1
    return rule if isinstance(rule, int) else rule(data, start)


_ADDRESS_COUNT: Final = struct.Struct(">HH")
_RANGED: Final = frozenset({1, 2, 3, 4, 15, 16})  # address, then quantity


def address_ranges(pdu: bytes) -> tuple[tuple[int, int], ...]:
    """The protocol addresses a request PDU reads or writes, as inclusive ranges of any
    table: () for a PDU without addresses (FC43, an unknown code, one too short to say)."""
    fc = pdu[0] if pdu else 0
    if len(pdu) < 5:
        return ()
    address, count = _ADDRESS_COUNT.unpack_from(pdu, 1)
    if fc in _RANGED:
        return ((address, address + max(count, 1) - 1),)
    if fc in (5, 6, 22):  # a single coil or register (count is its value, or the AND mask)
        return ((address, address),)
    if fc == 23 and len(pdu) >= 9:  # the read range, then the write range
        write_address, write_count = _ADDRESS_COUNT.unpack_from(pdu, 5)
        return ((address, address + max(count, 1) - 1),
                (write_address, write_address + max(write_count, 1) - 1))
    return ()


# -- Modbus TCP --------------------------------------------------------------------------------

_MBAP: Final = struct.Struct(">HHHB")
# Bound once: the fast path pays no attribute lookups for them (bench/modbus.py).
_unpack_mbap: Final = _MBAP.unpack_from
_pack_mbap: Final = _MBAP.pack
MBAP_LENGTH_MIN: Final = 2  # the unit id and a function code
MBAP_LENGTH_MAX: Final = 254  # the unit id and a PDU of 253 bytes (application protocol 4.1)
_pack_tail: Final = struct.Struct(">HHB").pack


def mbap_tail(unit: int, pdu: bytes) -> bytes:
    """A Modbus TCP frame of ``pdu`` after its transaction id: protocol id 0, length, unit id,
    the PDU.  A whole request's bytes after its first two are its tail; an answer is the
    request's transaction id followed by the answer's tail."""
    return _pack_tail(0, len(pdu) + 1, unit) + pdu


class MbapFramer:
    """Modbus TCP framing: any number of requests in one segment, a request split over any
    number of segments, each answer with its request's transaction id and unit id.  A protocol
    id other than 0 or a length outside 2..254 is a :class:`FramingError`."""

    __slots__ = ("buffer",)

    def __init__(self) -> None:
        self.buffer = bytearray()  # the transport reads its size (and tests its backlog)

    def feed(self, data: bytes) -> None:
        self.buffer += data

    @property
    def buffered(self) -> int:
        return len(self.buffer)

    def next_request(self) -> Request | None:
        buffer = self.buffer
        if len(buffer) < 7:  # the header is checked as soon as it is whole
            return None
        tid, protocol, length, unit = _unpack_mbap(buffer)
        if protocol or not MBAP_LENGTH_MIN <= length <= MBAP_LENGTH_MAX:
            raise FramingError(f"bad MBAP header (protocol id {protocol}, length {length})")
        end = 6 + length
        if len(buffer) < end:
            return None
        pdu = bytes(buffer[7:end])
        del buffer[:end]
        return unit, pdu, tid

    def whole(self, data: bytes) -> Request | None:
        # The pollers' case: one request in one segment.  Without the buffer's copies it is
        # worth 10 % of poller throughput (bench/modbus.py, 16 connections).
        if self.buffer or len(data) < 8:
            return None
        tid, protocol, length, unit = _unpack_mbap(data)
        if len(data) != 6 + length or protocol or length > MBAP_LENGTH_MAX:
            return None
        return unit, data[7:], tid

    def encode(self, request: Request, answer: bytes) -> bytes:
        return _pack_mbap(request[2], 0, len(answer) + 1, request[0]) + answer


# -- Modbus RTU --------------------------------------------------------------------------------

def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_CRC_TABLE: Final = _crc_table()


def crc16(data: bytes | bytearray | memoryview) -> int:
    """Modbus's CRC-16 (Modbus over Serial Line V1.02, 6.2.2: polynomial 0xA001 reflected,
    initial 0xFFFF).  On the wire its low byte goes first."""
    crc = 0xFFFF
    table = _CRC_TABLE
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc


RTU_FRAME_MAX: Final = 256  # unit id, PDU of 253, CRC (Modbus over Serial Line 2.5.1)


class RtuFramer:
    """Modbus RTU framing, the frame format alone: no serial I/O, no timing.  The transport
    calls :meth:`gap` when the line has been silent for 3.5 characters (the end of a frame,
    2.5.1.1): a frame of a function code whose length is not known ends there, and whatever
    was begun and is not a whole frame is dropped (counted in ``partial``).  A frame with a
    bad CRC is dropped (counted in ``crc_errors``) with everything buffered after it, up to
    the next gap: once a frame is wrong, so may be the lengths that follow; bytes past the
    longest frame with no length known are noise, dropped the same way (``partial``).  A
    broadcast (unit 0) is a request like any other here; that it gets no answer is the
    server's rule (2.1, broadcast)."""

    __slots__ = ("_skip", "buffer", "crc_errors", "partial")

    def __init__(self) -> None:
        self.buffer = bytearray()
        self.crc_errors = 0  # frames dropped for their CRC
        self.partial = 0  # frames begun and cut off by a gap, and runs of noise
        self._skip = False  # dropping what comes until the next gap

    @property
    def idle(self) -> bool:
        """Nothing that the line's next silence would decide: no frame begun, no burst
        being dropped."""
        return not self.buffer and not self._skip

    @property
    def discarded(self) -> int:
        """Frames dropped, for either reason."""
        return self.crc_errors + self.partial

    def feed(self, data: bytes) -> None:
        if not self._skip:
            self.buffer += data
            if len(self.buffer) > RTU_FRAME_MAX and request_pdu_length(self.buffer, 1) == -1:
                self.partial += 1  # no frame is this long: noise until the next gap
                self._drop()

    @property
    def buffered(self) -> int:
        return len(self.buffer)

    def _drop(self) -> None:
        self.buffer.clear()
        self._skip = True

    def _take(self, end: int) -> Request | None:
        buffer = self.buffer
        crc = buffer[end - 2] | buffer[end - 1] << 8
        if crc16(memoryview(buffer)[:end - 2]) != crc:
            self.crc_errors += 1
            self._drop()
            return None
        request = buffer[0], bytes(buffer[1:end - 2]), 0
        del buffer[:end]
        return request

    def next_request(self) -> Request | None:
        if len(self.buffer) < 4:  # unit id, function code, CRC: the shortest frame
            return None
        length = request_pdu_length(self.buffer, 1)
        if length is None or length == -1:  # -1: it ends at the gap
            return None
        end = 1 + length + 2
        return self._take(end) if len(self.buffer) >= end else None

    def gap(self) -> Request | None:
        """The line was silent for 3.5 characters: what is buffered ends here.  A whole
        frame whose length only its end gives is returned; any other leftover is dropped."""
        buffer = self.buffer
        self._skip = False
        if not buffer:
            return None
        if len(buffer) >= 4 and request_pdu_length(buffer, 1) == -1:
            request = self._take(len(buffer))
            self._skip = False  # a bad CRC's burst ended here: the next frame is heard
            return request
        self.partial += 1
        buffer.clear()
        return None

    def whole(self, data: bytes) -> Request | None:
        if self.buffer or self._skip or len(data) < 4:
            return None
        length = request_pdu_length(data, 1)
        if length is None or length == -1 or len(data) != length + 3:
            return None
        if crc16(memoryview(data)[:-2]) != data[-2] | data[-1] << 8:
            return None  # fed, it is dropped and counted
        return data[0], data[1:-2], 0

    def encode(self, request: Request, answer: bytes) -> bytes:
        frame = bytes((request[0],)) + answer
        crc = crc16(frame)
        return frame + bytes((crc & 0xFF, crc >> 8))


def drain(framer: Framer) -> list[Request]:
    """Every whole request buffered in ``framer`` (a caller that needs no fairness)."""
    out = []
    while (request := framer.next_request()) is not None:
        out.append(request)
    return out
