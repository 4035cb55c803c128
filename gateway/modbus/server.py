"""The Modbus TCP server (spec 3.2): our transport and framing, pymodbus's PDU codec.

pymodbus 3.16.1 on its own answers only the first of several requests in one TCP segment,
wedges a connection after an MBAP with a bad protocol id or length, answers 01 where 03 is due
(its request decoders raise on a bad quantity and the server cannot tell that from garbage),
accepts FC5 values other than 0x0000/0xFF00, and has no client limit or idle timeout.  So this
module owns the layer where those are decided:

- the transport: one ``asyncio.Protocol`` per connection; at most ``max_clients``, the rest
  closed at once; an allow-list; an idle connection closed after ``idle_timeout_s``; a partial
  frame must complete within 5 s.  No sleeps anywhere, least of all on an error path;
- the framing, sans-IO in ``ncgate.gateway.modbus.framer`` (its ``MbapFramer`` for plain TCP
  and TLS alike): any number of requests per segment, a request split over any number of
  segments, each answered in order with its own transaction id; a protocol id other than 0 or
  a length outside 2..254 closes that connection (and only that one).  A connection keeps the
  transport, the fairness and the backpressure, and feeds its framer;
- the fault table (``ncgate.gateway.modbus.faults``): exception, delay and no-reply faults the
  gateway puts on requests, done by the connection;
- the validation of each PDU, in libmodbus's order: function code (01), then length, quantity
  and byte count (03), then the address range (02), then values (03);

and uses pymodbus where it serves: its request classes decode a PDU that passed validation,
its response classes encode the answers -- except for register reads (FC3/FC4, what pollers
send), whose answers are packed straight from the map, and those of the image alone kept
until the image changes (RequestHandler.kept; bench/modbus.py).  The map itself lives in
``ncgate.gateway.modbus.map``.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import socket
import ssl
import struct
import time
from collections.abc import Callable, Sequence
from typing import Any, Final, cast

from pymodbus.pdu import ModbusPDU
from pymodbus.pdu.bit_message import (
    ReadCoilsResponse,
    ReadDiscreteInputsResponse,
    WriteMultipleCoilsResponse,
    WriteSingleCoilResponse,
)
from pymodbus.pdu.decoders import DecodePDU
from pymodbus.pdu.register_message import (
    MaskWriteRegisterResponse,
    ReadWriteMultipleRegistersResponse,
    WriteMultipleRegistersResponse,
    WriteSingleRegisterResponse,
)

from ncgate.config import Evict, ModbusConfig
from ncgate.errors import InputRefused
from ncgate.gateway import identity
from ncgate.gateway.errors import ModbusError, listen_error
from ncgate.gateway.modbus import security
from ncgate.gateway.modbus.codes import (
    DEVICE_FAILURE,
    ILLEGAL_ADDRESS,
    ILLEGAL_FUNCTION,
    ILLEGAL_VALUE,
    REFUSAL,
    TARGET_NO_RESPONSE,
)
from ncgate.gateway.modbus.codes import FunctionCode as FC
from ncgate.gateway.modbus.faults import FaultTable, ModbusFault, held_delay
from ncgate.gateway.modbus.framer import (
    FramingError,
    MbapFramer,
    Request,
    exception_pdu,
    mbap_tail,
)
from ncgate.gateway.modbus.map import ModbusMap, Table
from ncgate.gateway.modbus.security import TlsSession
from ncgate.gateway.ratelimit import RateLimitedLog
from ncgate.gateway.wiring import Backend
from ncgate.inputs import Source, SourceKind

try:  # a socket's unsent bytes in the kernel (Linux: SIOCOUTQ): a slow reader is seen reading
    import fcntl
    import termios
except ImportError:  # pragma: no cover - not on this platform: the transport's buffer only
    fcntl = termios = None  # type: ignore[assignment]

log = logging.getLogger("ncgate.modbus")

PARTIAL_FRAME_TIMEOUT_S: Final = 5.0
# Unsent answers of one connection above which its requests are no longer read, and below
# which reading resumes (a client that sends and never reads cannot make us buffer for it).
WRITE_HIGH_WATER: Final = 256 * 1024
WRITE_LOW_WATER: Final = 64 * 1024
# Requests of one connection answered in one loop turn before the others get theirs (at most
# this many, and no more once its share of ROUND_S of the loop's time went to them: ROUND_S
# split among the connections whose turns are due, never under MIN_TURN_S), and the backlog
# of unanswered requests above which (and below which again) its reading pauses.  A round of
# every greedy connection's turn so takes about ROUND_S, however many there are: a poller's
# request waits at most that behind them (4 pipelining writers at 0.5 ms each held it 2 ms
# and more; bench/storm.py, storm phase).
FRAMES_PER_TURN: Final = 16
ROUND_S: Final = 0.0005
MIN_TURN_S: Final = 0.00005
BACKLOG_HIGH: Final = 16 * 1024
# Delayed requests whose clients left, still to act at their time (a delay fault): a bound on
# what clients that connect, send a write and leave can leave behind.
ORPHANS_MAX: Final = 1024
TCP_CLOSE_WAIT: Final = 8  # Linux's tcpi_state (include/net/tcp_states.h)
BACKLOG_LOW: Final = 4 * 1024
NO_SUB_UNIT: Final = 0xFF  # Modbus TCP implementation guide: "the server itself"


_ADDRESS_COUNT = struct.Struct(">HH")
# A read-registers answer PDU of n registers: function code, byte count, the registers.
_REGISTERS: Final = [struct.Struct(f">BB{n}H") for n in range(126)]
# Function code -> (fixed PDU length or None, max quantity); spec 3.2.
_READ_LIMITS: Final[dict[int, int]] = {FC.READ_COILS: 2000, FC.READ_DISCRETE_INPUTS: 2000,
                        FC.READ_HOLDING_REGISTERS: 125, FC.READ_INPUT_REGISTERS: 125}
# The register reads (the pollers' hot path in RequestHandler.handle) and their tables.
_READ_TABLES: Final = {int(FC.READ_HOLDING_REGISTERS): Table.HOLDING,
                       int(FC.READ_INPUT_REGISTERS): Table.INPUT}
SERVED: Final = frozenset(FC)
WRITES: Final = frozenset({FC.WRITE_SINGLE_COIL, FC.WRITE_SINGLE_REGISTER,
                           FC.WRITE_MULTIPLE_COILS, FC.WRITE_MULTIPLE_REGISTERS,
                           FC.MASK_WRITE_REGISTER, FC.READ_WRITE_MULTIPLE_REGISTERS})
MEI_DEVICE_ID: Final = 0x0E  # FC43's "read device identification"
CONFORMITY: Final = 0x82  # regular identification, stream and individual access


def validate(pdu: bytes) -> None:
    """Length, quantity and byte count of a request PDU (exception 01 or 03)."""
    fc = pdu[0]
    n = len(pdu)
    if fc not in SERVED:
        raise ModbusError(ILLEGAL_FUNCTION, f"function code {fc} is not served")
    if fc in _READ_LIMITS:
        if n != 5:
            raise ModbusError(ILLEGAL_VALUE, "length")
        quantity = pdu[3] << 8 | pdu[4]
        if not 1 <= quantity <= _READ_LIMITS[fc]:
            raise ModbusError(ILLEGAL_VALUE, f"quantity {quantity}")
    elif fc in (FC.WRITE_SINGLE_COIL, FC.WRITE_SINGLE_REGISTER):
        if n != 5:
            raise ModbusError(ILLEGAL_VALUE, "length")
    elif fc in (FC.WRITE_MULTIPLE_COILS, FC.WRITE_MULTIPLE_REGISTERS):
        if n < 6:
            raise ModbusError(ILLEGAL_VALUE, "length")
        quantity = pdu[3] << 8 | pdu[4]
        limit, per = (1968, None) if fc == FC.WRITE_MULTIPLE_COILS else (123, 2)
        if not 1 <= quantity <= limit:
            raise ModbusError(ILLEGAL_VALUE, f"quantity {quantity}")
        expected = (quantity + 7) // 8 if per is None else quantity * 2
        if pdu[5] != expected or n != 6 + expected:
            raise ModbusError(ILLEGAL_VALUE, "byte count")
    elif fc == FC.MASK_WRITE_REGISTER:
        if n != 7:
            raise ModbusError(ILLEGAL_VALUE, "length")
    elif fc == FC.ENCAPSULATED_INTERFACE:
        if n < 2 or pdu[1] != MEI_DEVICE_ID:  # 0x0D (CANopen reference) is not served
            raise ModbusError(ILLEGAL_FUNCTION, "MEI type other than 0x0E")
        if n != 4 or not 1 <= pdu[2] <= 4:
            raise ModbusError(ILLEGAL_VALUE, "read device id code")
    else:  # 23
        if n < 10:
            raise ModbusError(ILLEGAL_VALUE, "length")
        read_quantity = pdu[3] << 8 | pdu[4]
        write_quantity = pdu[7] << 8 | pdu[8]
        if not 1 <= read_quantity <= 125 or not 1 <= write_quantity <= 121:
            raise ModbusError(ILLEGAL_VALUE, "quantity")
        if pdu[9] != write_quantity * 2 or n != 10 + write_quantity * 2:
            raise ModbusError(ILLEGAL_VALUE, "byte count")


def _pdu(response: ModbusPDU) -> bytes:
    return bytes((response.function_code,)) + response.encode()


class RequestHandler:
    """Answers one request PDU against the map."""

    def __init__(self, mmap: ModbusMap, backend: Backend, unit_ids: frozenset[int],
                 strict_unit_id: bool = False) -> None:
        self.map = mmap
        self.backend = backend
        # 0xFF ("no sub-unit") is the server itself; 0 is answered too unless strict (what
        # libmodbus clients send when they never set a slave id); other ids get 0x0B.
        self.unit_ids = unit_ids | {NO_SUB_UNIT} | (set() if strict_unit_id else {0})
        self.decoder = DecodePDU(is_server=True)
        self.served = 0
        # The answers of the register reads that read the image alone (ModbusMap.read), in
        # two forms: ``kept`` by the request's MBAP header after its transaction id and its
        # PDU (framer.mbap_tail), the answer's, to follow the request's transaction id (the
        # pollers' direct path, _Connection.data_received, takes one with the request's
        # bytes); ``kept_pdus`` the answer PDU by the request PDU (handle(), for the others:
        # pipelined requests, TLS, RTU).  All of them were read at the image's generation
        # ``kept_at``: once it moves (any write that changed a value, whoever wrote it), they
        # are forgotten, and the next read reads the image.
        self.image = backend.image
        self.kept: dict[bytes, bytes] = {}
        self.kept_pdus: dict[bytes, bytes] = {}
        self.kept_at = self.image.generation
        # Device identification (FC43/14): the identity CANopen's 0x1018 gives too.
        texts = {0x00: identity.VENDOR_NAME, 0x01: identity.product_code_text(),
                 0x02: identity.revision_text(), 0x04: identity.PRODUCT_NAME,
                 0x05: identity.model_name(), 0x06: mmap.config.nc.cell}
        # At most 240 bytes an object (one PDU holds 253), cut at a whole character.
        self.identity = {k: v.encode("utf-8")[:240].decode("utf-8", "ignore").encode("utf-8")
                         for k, v in texts.items()}

    def handle(self, unit: int, pdu: bytes, source: Source,
               writable: frozenset[str] | None = None) -> bytes:
        """The answer PDU.  ``writable``: the map regions this client's role may write (None:
        no roles, as on plain Modbus/TCP); a write elsewhere is exception 01."""
        fc = pdu[0]
        self.served += 1
        if unit not in self.unit_ids:
            return exception_pdu(fc, TARGET_NO_RESPONSE)
        table = _READ_TABLES.get(fc)
        if table is not None and len(pdu) == 5:
            # The pollers' hot path: validate's rules for a read (the quantity from the same
            # _READ_LIMITS, then the address), no pymodbus objects, the answer packed at once.
            # Ahead of validate, it is worth 4 % of poller throughput (bench/modbus.py).
            if self.kept_at == self.image.generation:
                kept = self.kept_pdus.get(pdu)
                if kept is not None:
                    return kept
            address, count = _ADDRESS_COUNT.unpack_from(pdu, 1)
            if not 1 <= count <= _READ_LIMITS[fc]:
                return exception_pdu(fc, ILLEGAL_VALUE)
            try:
                regs, steady = self.map.read(self.backend, table, address, count)
                answer: bytes = _REGISTERS[count].pack(fc, 2 * count, *regs)
            except ModbusError as exc:
                return exception_pdu(fc, exc.code)
            except Exception:  # a bug of ours (a value that does not pack): 04, not a close
                log.exception("modbus: read %s from %s failed", pdu.hex(), source)
                return exception_pdu(fc, DEVICE_FAILURE)
            if steady:
                self._keep(unit, pdu, answer)
            return answer
        try:
            if len(pdu) == 5 and writable is None and (fc == FC.WRITE_SINGLE_COIL
                                                       or fc == FC.WRITE_SINGLE_REGISTER):
                return self._write_single(fc, pdu, source)
            validate(pdu)  # (an FC3/FC4 of another length: 03)
            if fc == FC.ENCAPSULATED_INTERFACE:
                return self._device_identification(pdu[2], pdu[3])
            if writable is not None and fc in WRITES and not writable:
                raise ModbusError(ILLEGAL_FUNCTION, "this client's role may not write")
            request = self.decoder.decode(pdu)
            if request is None:  # not reached: validation accepts only what decodes
                raise ModbusError(ILLEGAL_VALUE, "undecodable")
            if writable is not None and fc in WRITES:
                self._authorise(fc, request, writable)
            return self._execute(fc, request, pdu, source)
        except ModbusError as exc:
            return exception_pdu(fc, exc.code)
        except InputRefused as exc:  # the door refused it: nothing was applied
            return exception_pdu(fc, REFUSAL[exc.reason])
        except Exception:  # a bug of ours must not take the connection down
            log.exception("modbus: request %s from %s failed", pdu.hex(), source)
            return exception_pdu(fc, DEVICE_FAILURE)

    def _keep(self, unit: int, pdu: bytes, answer: bytes) -> None:
        """Keep the answer of a read of the image alone, read just now (``kept``)."""
        kept = self.kept
        generation = self.image.generation
        if generation != self.kept_at or len(kept) >= 4096:  # (a bound, as the map's)
            kept.clear()
            self.kept_pdus.clear()
            self.kept_at = generation
        kept[mbap_tail(unit, pdu)] = mbap_tail(unit, answer)
        self.kept_pdus[pdu] = answer

    def _write_single(self, fc: int, pdu: bytes, source: Source) -> bytes:
        """FC5 and FC6 of plain Modbus/TCP, the writers' hot path: validate's rules for them
        (the length, checked by the caller) without pymodbus's decoding, which formats every
        request for a debug log it does not write.  The answer is the request echoed
        (Modbus application protocol 6.5, 6.6).  It took bench/modbus.py's write -> resume
        p50 inside the gateway from 24 to 19 us."""
        address, value = _ADDRESS_COUNT.unpack_from(pdu, 1)
        m = self.map
        if fc == FC.WRITE_SINGLE_COIL:
            m.region(Table.COILS, address, 1)  # the address first (libmodbus)
            if value != 0xFF00 and value != 0:
                raise ModbusError(ILLEGAL_VALUE, "FC5 value must be 0x0000 or 0xFF00")
            m.write_bits(self.backend, address, (value == 0xFF00,), source)
        else:
            m.write_registers(self.backend, address, (value,), source)
        return bytes(pdu)

    def _device_identification(self, code: int, object_id: int) -> bytes:
        """FC43/14 (Modbus application protocol 6.21): the basic objects (0..2) and the
        regular ones we have (4..6), in stream access (codes 1-3) or one at a time (4)."""
        objects = self.identity
        if code == 4:
            if object_id not in objects:
                raise ModbusError(ILLEGAL_ADDRESS, f"no device identification object {object_id}")
            chosen = [object_id]
        else:
            last = 0x02 if code == 1 else 0xFF
            ids = [i for i in sorted(objects) if i <= last]
            # An object id the category does not hold restarts at the beginning.
            start = object_id if object_id in ids else 0
            chosen = [i for i in ids if i >= start]
        body = bytearray()
        count, next_id = 0, 0
        for i in chosen:
            value = objects[i]
            if 6 + len(body) + 2 + len(value) > 253 - 1 and count:  # does not fit: next time
                next_id = i
                break
            body += bytes((i, len(value))) + value
            count += 1
        more = 0xFF if next_id else 0x00
        return bytes((43, MEI_DEVICE_ID, code, CONFORMITY, more, next_id, count)) + bytes(body)

    def _authorise(self, fc: int, request: Any, writable: frozenset[str]) -> None:
        """Exception 01 unless the role may write every region the request writes (after
        the address check: an unmapped address is still 02)."""
        if fc in (FC.WRITE_SINGLE_COIL, FC.WRITE_MULTIPLE_COILS):
            count = 1 if fc == FC.WRITE_SINGLE_COIL else request.count
            table, address = Table.COILS, request.address
        elif fc == FC.READ_WRITE_MULTIPLE_REGISTERS:
            table, address, count = (Table.HOLDING, request.write_address,
                                     len(request.write_registers))
        else:
            count = (1 if fc in (FC.WRITE_SINGLE_REGISTER, FC.MASK_WRITE_REGISTER)
                     else request.count)
            table, address = Table.HOLDING, request.address
        for region, _, _ in self.map.segments(table, address, count):
            if region.name not in writable:
                raise ModbusError(ILLEGAL_FUNCTION, f"this client's role may not write "
                                  f"{region.name}")

    def _execute(self, fc: int, request: Any, pdu: bytes, who: Source) -> bytes:
        m, backend = self.map, self.backend
        if fc == FC.READ_COILS:
            bits = m.read_bits(backend, Table.COILS, request.address, request.count)
            return _pdu(ReadCoilsResponse(bits=bits))
        if fc == FC.READ_DISCRETE_INPUTS:
            bits = m.read_bits(backend, Table.DISCRETE_INPUTS, request.address, request.count)
            return _pdu(ReadDiscreteInputsResponse(bits=bits))
        if fc == FC.WRITE_SINGLE_COIL:
            m.region(Table.COILS, request.address, 1)  # the address first (libmodbus)
            raw = pdu[3:5]  # pymodbus keeps only bool(value): check the bytes themselves
            if raw not in (b"\x00\x00", b"\xff\x00"):
                raise ModbusError(ILLEGAL_VALUE, "FC5 value must be 0x0000 or 0xFF00")
            m.write_bits(backend, request.address, [raw == b"\xff\x00"], who)
            return _pdu(WriteSingleCoilResponse(address=request.address, bits=[raw != b"\0\0"]))
        if fc == FC.WRITE_SINGLE_REGISTER:
            m.write_registers(backend, request.address, list(request.registers), who)
            return _pdu(WriteSingleRegisterResponse(address=request.address,
                                                    registers=list(request.registers)))
        if fc == FC.WRITE_MULTIPLE_COILS:
            m.write_bits(backend, request.address, list(request.bits), who)
            return _pdu(WriteMultipleCoilsResponse(address=request.address,
                                                   count=request.count))
        if fc == FC.WRITE_MULTIPLE_REGISTERS:
            m.write_registers(backend, request.address, list(request.registers), who)
            return _pdu(WriteMultipleRegistersResponse(address=request.address,
                                                       count=request.count))
        if fc == FC.MASK_WRITE_REGISTER:
            (current,) = m.read_registers(backend, Table.HOLDING, request.address, 1)
            value = (current & request.and_mask) | (request.or_mask & ~request.and_mask & 0xFFFF)
            m.check_register_values(request.address, [value])
            m.write_registers(backend, request.address, [value], who)
            return _pdu(MaskWriteRegisterResponse(address=request.address,
                                                  and_mask=request.and_mask,
                                                  or_mask=request.or_mask))
        # 23: both ranges are checked before anything is written; the write comes first
        values = list(request.write_registers)
        m.segments(Table.HOLDING, request.read_address, request.read_count)  # as FC3 reads
        m.check_register_values(request.write_address, values)
        m.write_registers(backend, request.write_address, values, who)
        regs = m.read_registers(backend, Table.HOLDING, request.read_address,
                                request.read_count)
        return _pdu(ReadWriteMultipleRegistersResponse(registers=regs))


class _Connection(asyncio.Protocol):
    """One client: the transport (plain, or TLS through a ``TlsSession``), its share of the
    loop and its backpressure.  The bytes become requests in its framer; faults are done
    here, since a delay and a silence are about when (and whether) answers are sent."""

    def __init__(self, server: ModbusServer, tls: ssl.SSLContext | None = None) -> None:
        self.server = server
        # Modbus/TCP Security: the TLS session (None: plain Modbus/TCP) and what the client's
        # role may write (None: no roles apply, as on plain Modbus/TCP).
        self.tls = TlsSession(tls) if tls is not None else None
        self.writable: frozenset[str] | None = None
        self.handler = server.handler
        self.handle = server.handler.handle
        self.framer = MbapFramer()
        self.transport: asyncio.Transport | None = None
        self.source = Source(SourceKind.MODBUS_TLS if tls is not None else SourceKind.MODBUS)
        self.who = str(self.source)  # for the log: the source, and the address if it has none
        self.loop = asyncio.get_running_loop()
        self.last_activity = self.loop.time()
        self.partial_since: float | None = None
        self.timer: asyncio.TimerHandle | None = None
        self.paused = False  # the client does not read its answers (backpressure)
        self.connected_at = self.last_activity
        # When it last completed a request (None: never -- a socket that only connected).
        self.completed_at: float | None = None
        self.backlogged = False  # reading paused: a backlog of requests waits its turns
        self.turn: asyncio.Handle | None = None  # the next turn of _process, when one is due
        self.drain_mark = 0  # answers unsent at the last idle check (paused: is it reading?)
        # A delay fault: the request held, when (time.monotonic) it may be answered, and the
        # timer; the requests after it wait in the framer.
        self.held: tuple[Request, float] | None = None
        self.hold_timer: asyncio.Handle | None = None
        self.held_since = 0.0  # when the held request came
        self.silent = False  # a no_reply fault: this connection answers nothing any more
        self.direct = False  # a whole request in a segment may be answered at once (below)
        self.update_direct()

    def update_direct(self) -> None:
        """Whether data_received may answer a request that came whole in one segment on the
        spot: plain TCP, the client reading its answers, no delayed request before it, not
        silent, no fault table.  One flag, so that the pollers' path tests one attribute,
        kept by whatever changes these (bench/modbus.py)."""
        self.direct = (self.tls is None and not self.paused and self.held is None
                       and not self.silent and self.server.fault_table is None)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)
        peer = transport.get_extra_info("peername") or ("?", 0)
        address = f"{peer[0]}:{peer[1]}"
        self.source = Source(self.source.kind, address, address)
        self.who = str(self.source)
        server = self.server
        if not server.allowed(peer[0]):
            server.refusals.note(f"{self.who} refused: not in the allow-list")
            self.transport.abort()
            return
        self.transport.set_write_buffer_limits(high=WRITE_HIGH_WATER, low=WRITE_LOW_WATER)
        if len(server.connections) >= server.config.max_clients:
            room = server.make_room(self)
            if room is None:
                server.refusals.note(f"{self.who} refused: {len(server.connections)} clients "
                                     "already (max_clients), none of them idle")
                self.transport.abort()
                return
            server.refusals.note(f"{room.who} closed for {self.who}: "
                                 f"{len(server.connections)} clients already (max_clients)")
            room.evict()
        server.connections.add(self)
        # Whether a request may be answered at once is decided again now that the server
        # knows the connection: uvloop makes the protocol at the accept and calls
        # connection_made a turn later, and a fault table set in between (which updates the
        # connections it knows) found it in none -- its requests then skipped the faults.
        self.update_direct()
        server.connections_changed.set()
        server.chatter.note(f"{self.who} connected ({len(server.connections)} clients)")
        if self.tls is not None:
            self.writable = frozenset()  # nothing until the handshake names a role
            # The handshake has the 5 s of a partial frame.
            self.partial_since = self.last_activity
            self._arm(min(PARTIAL_FRAME_TIMEOUT_S, server.config.idle_timeout_s))
        else:
            self._arm(server.config.idle_timeout_s)

    @property
    def proven(self) -> bool:
        """Completed a request, or a TLS handshake: a client, not just a socket."""
        return self.completed_at is not None or (self.tls is not None and self.tls.established)

    def pause_writing(self) -> None:
        """Answers not yet sent passed the high-water mark: answer and read no more requests
        from this client until it reads its answers (the others are served meanwhile)."""
        self.paused = True
        self.direct = False
        self.drain_mark = self._unsent()
        self._reading()

    def resume_writing(self) -> None:
        self.paused = False
        self.update_direct()
        self._reading()
        self._process()  # what arrived before the pause

    def _unsent(self) -> int:
        """Answers not yet read by the client: the transport's buffer and the kernel's send
        queue (Linux: SIOCOUTQ), so that a slow reader is seen reading."""
        transport = self.transport
        if transport is None:
            return 0
        unsent = transport.get_write_buffer_size()
        sock = transport.get_extra_info("socket")
        if sock is not None and termios is not None and hasattr(termios, "TIOCOUTQ"):
            with contextlib.suppress(OSError, ValueError):
                queued = fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0")
                unsent += struct.unpack("i", queued)[0]
        return unsent

    def _peer_closed(self) -> bool:
        """The client closed its side (Linux: the socket is in CLOSE-WAIT), though the end
        of stream waits unread behind what reading paused for."""
        transport = self.transport
        sock = transport.get_extra_info("socket") if transport is not None else None
        if sock is None or not hasattr(socket, "TCP_INFO"):
            return False
        try:
            state: int = sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 1)[0]
        except OSError:
            return False
        return state == TCP_CLOSE_WAIT

    def _reading(self) -> None:
        """Read while the client reads its answers and its backlog is small."""
        transport = self.transport
        if transport is None or transport.is_closing():
            return
        if self.paused or self.backlogged:
            transport.pause_reading()
        else:
            transport.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        if self in self.server.connections:
            self.server.connections.discard(self)
            self.server.chatter.note(f"{self.who} disconnected")
            self.server.connections_changed.set()
            if not self.server.connections:
                self.server.all_closed.set()
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        if self.turn is not None:
            self.turn.cancel()
            self.turn = None
            self.server.due_turns.discard(self)
        if self.hold_timer is not None:
            orphans = self.server.orphans
            if self.held is not None and len(orphans) < ORPHANS_MAX \
                    and not self.server.closing:
                # The client gave up waiting and left: the device had the request, and a
                # write under a delay acts at its time all the same (docs/plant.md); what it
                # had not taken yet goes with the connection.
                orphans.add(self)
                self.framer.buffer.clear()
            else:
                self.hold_timer.cancel()
                self.hold_timer = None
                self.held = None

    def evict(self) -> None:
        """Out of the count at once (its connection_lost comes later), and closed."""
        self.server.connections.discard(self)
        self.server.connections_changed.set()
        if self.transport is not None and not self.transport.is_closing():
            self.transport.abort()

    def close(self, why: str) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.server.chatter.note(f"{self.who} closed: {why}")
            self.transport.abort()

    def data_received(self, data: bytes) -> None:
        self.last_activity = now = self.loop.time()
        tls = self.tls
        if self.direct:
            # The common case, one whole request in one segment, answered without the
            # buffer's bookkeeping of _process: worth 10 % of poller throughput (measured with
            # bench/modbus.py, 16 connections).  Any other case goes through _process.
            framer = self.framer
            handler = self.handler
            if handler.kept_at == handler.image.generation and not framer.buffer:
                # A read of the image alone that was answered since the image last changed:
                # the same answer, with this request's transaction id (RequestHandler.kept).
                tail = handler.kept.get(data[2:])
                if tail is not None:
                    handler.served += 1
                    assert self.transport is not None
                    self.transport.write(data[:2] + tail)
                    self.partial_since = None
                    self.completed_at = now
                    return
            request = framer.whole(data)
            if request is not None:
                unit, pdu, _ = request
                answer = self.handle(unit, pdu, self.source, self.writable)
                assert self.transport is not None
                self.transport.write(framer.encode(request, answer))
                self.partial_since = None
                self.completed_at = now
                return
        if tls is not None:
            was_established = tls.established
            try:
                data = tls.feed(data)
            except ssl.SSLError as exc:
                self._flush_tls()  # the alert tells the client why
                self.server.refusals.note(f"{self.who} refused: TLS handshake failed "
                                          f"({exc.reason or exc})")
                self.close("TLS handshake failed")
                return
            self._flush_tls()
            if not tls.established:
                return
            if not was_established:
                self._established()
            if tls.closed:
                self.close("the client closed the TLS session")
                return
        self.framer.feed(data)
        if self.turn is None:  # else its next turn, already due, takes it
            self._process()

    def _flush_tls(self) -> None:
        assert self.tls is not None and self.transport is not None
        pending = self.tls.outgoing()
        if pending and not self.transport.is_closing():
            self.transport.write(pending)

    def _established(self) -> None:
        """The handshake is done and the client's certificate verified: read its role."""
        assert self.tls is not None
        der = self.tls.peer_certificate()
        try:
            role = security.role_of(der) if der is not None else None
        except ValueError as exc:  # an extension cryptography cannot parse: no role
            log.warning("%s: the certificate's extensions do not parse (%s): no role",
                        self.who, exc)
            role = None
        self.writable = self.server.config.roles.get(role, frozenset()) if role else frozenset()
        self.source = Source(SourceKind.MODBUS_TLS, role or "(no role)", self.source.peer)
        self.who = f"{self.source} {self.source.peer}"
        self.partial_since = None
        self.server.chatter.note(f"{self.who}: {self.tls.version()} established")

    def _process(self) -> None:
        """Answer the whole requests in the framer, in order, at most FRAMES_PER_TURN (or
        its share of ROUND_S of the loop's time) in one loop turn (then the next turn is due
        after everyone else's: a pipelining client gets its share and stalls nobody), unless
        the client stopped reading its answers (then the rest waits in the buffer until it
        does) or a delay fault holds a request (the rest waits until it is answered).  A
        backlog above BACKLOG_HIGH stops reading from the client until its turns have
        brought it under BACKLOG_LOW."""
        self.turn = None
        due = self.server.due_turns
        due.discard(self)
        framer = self.framer
        next_request, encode, handle = framer.next_request, framer.encode, self.handle
        faulty = self.silent or self.server.fault_table is not None  # (set between turns)
        out: list[bytes] = []
        size = 0
        taken = 0
        turn_ends = time.perf_counter() + max(MIN_TURN_S, ROUND_S / (len(due) + 1))
        while not self.paused and self.held is None:
            if taken >= FRAMES_PER_TURN or (taken and time.perf_counter() > turn_ends):
                if framer.buffered:
                    self.turn = self.loop.call_soon(self._process)
                    due.add(self)
                break
            try:
                request = next_request()
            except FramingError as exc:
                if out:
                    self._send(out)
                self.close(str(exc))
                return
            if request is None:
                break
            taken += 1
            if faulty:
                answer = self._faulted(request)
                if answer is None:  # held or dropped
                    continue
            else:
                unit, pdu, _ = request
                answer = handle(unit, pdu, self.source, self.writable)
            frame = encode(request, answer)
            out.append(frame)
            size += len(frame)
            if size >= WRITE_LOW_WATER:  # in batches: the transport may pause us on a write
                self._send(out)
                out, size = [], 0
        if out:
            self._send(out)
        buffered = framer.buffered
        backlogged = buffered > (BACKLOG_LOW if self.backlogged else BACKLOG_HIGH)
        if backlogged != self.backlogged:
            self.backlogged = backlogged
            self._reading()
        if taken:
            self.completed_at = self.loop.time()
            self.partial_since = None  # each frame has its own 5 s, from its first byte
        if not buffered or self.paused or self.turn is not None or self.held is not None:
            # nothing begun, a paused client, whole frames waiting for their turn or behind
            # a delayed request: not timed
            self.partial_since = None
        elif self.partial_since is None:  # a frame has begun: it has 5 s to complete
            self.partial_since = self.last_activity
            if self.timer is not None:
                self.timer.cancel()
            self._arm(min(PARTIAL_FRAME_TIMEOUT_S, self.server.config.idle_timeout_s))

    def _faulted(self, request: Request) -> bytes | None:
        """The answer to ``request`` under the fault table, or None: none now (a delay holds
        it, or the connection went silent)."""
        server = self.server
        table = server.fault_table
        if self.silent:
            server.fault_tally["silenced"] += 1
            return None
        unit, pdu, _ = request
        fault = table.match(unit, pdu) if table is not None else None
        if fault is None:
            return self.handle(unit, pdu, self.source, self.writable)
        if fault.kind == "exception":  # not executed: nothing of a write is stored
            return exception_pdu(pdu[0], fault.code)
        if fault.kind == "no_reply":
            self.silent = True
            self.direct = False
            server.chatter.note(f"{self.who}: no answers any more (a no_reply fault)")
            return None
        seconds = fault.ms / 1000
        self.held_since = time.monotonic()
        self.held = (request, self.held_since + seconds)
        self.direct = False
        self.hold_timer = self.loop.call_later(seconds, self._release)
        return None

    def _release(self) -> None:
        """A delayed request's time has come: execute it, answer it, go on with the rest."""
        self.hold_timer = None
        if self.held is None:
            return
        request, due = self.held
        early = due - time.monotonic()
        if early > 0:  # a timer may run early by its loop's clock granularity (libuv: 1 ms)
            self.hold_timer = self.loop.call_later(early, self._release)
            return
        self.held = None
        self.update_direct()
        unit, pdu, _ = request
        if self in self.server.orphans:  # its client left: a write acts, unanswered
            self.server.orphans.discard(self)
            if pdu[:1] and pdu[0] in WRITES:
                self.handle(unit, pdu, self.source, self.writable)
            return
        if self.transport is None or self.transport.is_closing():
            return
        answer = self.handle(unit, pdu, self.source, self.writable)
        self._send([self.framer.encode(request, answer)])
        self.completed_at = self.loop.time()
        if self.turn is None:
            self._process()

    def faults_changed(self, table: FaultTable | None) -> None:
        """A new fault table: a request a delay holds is answered at its arrival plus the
        longest delay of the new table that matches it -- at once when none does any more,
        or that time is past (a clear ends the slowness; it used to wait out its delay)."""
        self.update_direct()
        if self.held is None or self.hold_timer is None:
            return
        request, due = self.held
        new_due = self.held_since + held_delay(table, request[0], request[1])
        if new_due == due:
            return
        self.hold_timer.cancel()
        self.held = (request, new_due)
        wait = new_due - time.monotonic()
        self.hold_timer = (self.loop.call_later(wait, self._release) if wait > 0
                           else self.loop.call_soon(self._release))  # (after the caller)

    def _send(self, answers: list[bytes]) -> None:
        assert self.transport is not None
        data = answers[0] if len(answers) == 1 else b"".join(answers)
        self.transport.write(data if self.tls is None else self.tls.encrypt(data))

    def _arm(self, delay: float) -> None:
        self.timer = self.loop.call_later(delay, self._check_timeouts)

    def _check_timeouts(self) -> None:
        self.timer = None
        if self.transport is None or self.transport.is_closing():
            return
        now = self.loop.time()
        idle = self.server.config.idle_timeout_s
        if self.partial_since is not None and now - self.partial_since >= PARTIAL_FRAME_TIMEOUT_S:
            what = ("TLS handshake" if self.tls is not None and not self.tls.established
                    else "partial frame")
            self.close(f"{what} not completed in {PARTIAL_FRAME_TIMEOUT_S:g} s")
            return
        if (self.paused or self.backlogged or self.held is not None) and self._peer_closed():
            # Reading is paused (or it waits for a delayed answer): its end of stream is not
            # read, and the connection held a slot of max_clients in CLOSE-WAIT until the
            # idle timeout -- for a delay's whole length while it held a request.
            self.close("the client closed its side")
            return
        unsent = self._unsent()
        if (self.paused and unsent < self.drain_mark) or self.held is not None:
            # answers still unsent, but the client is reading them; or it waits for a
            # delayed answer: not silence
            self.last_activity = now
        self.drain_mark = unsent
        # Answering its requests is activity too: a backlog being served is not silence.
        self.last_activity = max(self.last_activity, self.completed_at or 0.0)
        if now - self.last_activity >= idle:
            self.close(f"idle for {idle:g} s")
            return
        next_check = self.last_activity + idle - now
        if self.paused:  # look again soon whether the client reads what it is sent
            next_check = min(next_check, idle / 4)
        if self.partial_since is not None:
            next_check = min(next_check, self.partial_since + PARTIAL_FRAME_TIMEOUT_S - now)
        self._arm(max(next_check, 0.001))


AllowList = list[ipaddress.IPv4Network | ipaddress.IPv6Network]


def allow_list(config: ModbusConfig) -> AllowList:
    """``modbus.allow`` as networks (checked by the config already)."""
    return [ipaddress.ip_network(a, strict=False) for a in config.allow]


def allowed(networks: AllowList, host: str) -> bool:
    """Whether a client at ``host`` may connect: every host without an allow-list, else one
    inside it (Modbus TCP and TLS, and RTU over TCP)."""
    if not networks:
        return True
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        return False
    return any(address in net for net in networks)


class ModbusServer:
    """The listening socket and its connections."""

    def __init__(self, config: ModbusConfig, mmap: ModbusMap, backend: Backend) -> None:
        self.config = config
        self.handler = RequestHandler(mmap, backend, frozenset(config.unit_ids),
                                      config.strict_unit_id)
        self.refusals = RateLimitedLog(log)
        # Per-connection INFO lines (connected, disconnected, closed): a connect flood gives
        # a few lines a second and a count, not a line per socket.
        self.chatter = RateLimitedLog(log, level=logging.INFO, burst=10)
        self.connections: set[_Connection] = set()
        self.due_turns: set[_Connection] = set()  # connections whose next turn is due
        # Connections whose client left while a delay fault held a request: it acts at its
        # time (at most ORPHANS_MAX of them; more are dropped with their connection).
        self.orphans: set[_Connection] = set()
        self.closing = False
        self.all_closed = asyncio.Event()
        self.connections_changed = asyncio.Event()  # set when a connection comes or goes
        self._servers: list[asyncio.Server] = []
        self._allow = allow_list(config)
        # (host, port) of the plain Modbus/TCP listener and of the TLS one (None: off).
        self.address: tuple[str, int] | None = None
        self.tls_address: tuple[str, int] | None = None
        # The fault table (ncgate.gateway.modbus.faults); fault_table is None while it has no
        # row, the one test a request pays then.
        self._faults = FaultTable()
        self.fault_table: FaultTable | None = None
        self.fault_tally = self._faults.counts

    def set_faults(self, faults: Sequence[ModbusFault]) -> None:
        """Put the fault table ``faults`` in force for every connection, from its next
        request on (``()`` clears it).  A request a delay holds is answered when its time
        comes; a connection a no_reply silenced stays silent (the module faults says why).
        FaultError (a ValueError) for a row that is not a ModbusFault; nothing changes."""
        self._faults.set(faults)
        self.fault_table = self._faults if self._faults.rows else None
        for connection in [*self.connections, *self.orphans]:
            connection.faults_changed(self.fault_table)

    @property
    def faults(self) -> tuple[ModbusFault, ...]:
        """The fault table in force."""
        return self._faults.rows

    @property
    def fault_counts(self) -> dict[str, int]:
        """Requests the faults caught since the server started, by kind (``exception``,
        ``delay``, ``no_reply``), and ``silenced``: those a silent connection dropped."""
        return dict(self.fault_tally)

    def make_room(self, newcomer: _Connection) -> _Connection | None:
        """Whom to close at ``max_clients`` so that ``newcomer`` may stay, or None: refuse it.

        Never a client that completed a request within the idle window (or a TLS client
        whose handshake is done) for a socket that has done nothing yet: first the socket
        connected longest ago that never completed a request nor a handshake; then, for a
        plain newcomer, the client idle longest beyond the idle window."""
        if self.config.evict is Evict.REFUSE:
            return None
        unproven = [c for c in self.connections if not c.proven]
        if unproven:
            return min(unproven, key=lambda c: c.connected_at)
        now = newcomer.loop.time()
        window = self.config.idle_timeout_s
        idle = [c for c in self.connections if (c.completed_at or c.connected_at) < now - window
                and not (c.tls is not None and c.tls.established)]
        return min(idle, key=lambda c: c.completed_at or c.connected_at) if idle else None

    def allowed(self, host: str) -> bool:
        return allowed(self._allow, host)

    async def wait_connections(self, at_most: int | None = None,
                               at_least: int | None = None) -> None:
        """Until at most ``at_most`` (and at least ``at_least``) connections are open."""
        while ((at_most is not None and len(self.connections) > at_most)
               or (at_least is not None and len(self.connections) < at_least)):
            self.connections_changed.clear()
            await self.connections_changed.wait()

    async def start(self) -> None:
        """Listen: plain Modbus/TCP on ``port`` and, with ``[modbus.tls]``, Modbus/TCP
        Security on ``tls.port``; both share ``max_clients``."""
        tls = self.config.tls
        if not tls.enabled or tls.plain:
            self.address = await self._listen(self.config.port, None)
        if tls.enabled:
            self.tls_address = await self._listen(tls.port, security.server_context(tls))

    async def _listen(self, port: int, context: ssl.SSLContext | None) -> tuple[str, int]:
        loop = asyncio.get_running_loop()
        factory: Callable[[], asyncio.Protocol] = lambda: _Connection(self, context)  # noqa: E731
        try:
            server = await loop.create_server(factory, self.config.host, port,
                                              reuse_address=True)
        except OSError as exc:  # name the key to change
            key = "modbus.tls.port" if context is not None else "modbus.port"
            raise listen_error(exc, key, self.config.host, port) from None
        self._servers.append(server)
        host, bound = server.sockets[0].getsockname()[:2]
        return host, bound

    async def close(self) -> None:
        self.closing = True
        for orphan in list(self.orphans):  # the gateway stops: nothing acts after it
            if orphan.hold_timer is not None:
                orphan.hold_timer.cancel()
        self.orphans.clear()
        self.refusals.flush()  # the counts of lines held back, said before the end
        self.chatter.flush()
        if not self._servers:
            return
        for server in self._servers:
            server.close()
        if self.connections:
            self.all_closed.clear()
            for connection in list(self.connections):
                connection.close("server shutting down")
            await self.all_closed.wait()  # every connection_lost has run
        for server in self._servers:
            await server.wait_closed()
        self._servers = []
