"""The OPC UA server's connections (in the server's process): asyncua's binary protocol, with
each message header checked before asyncua buffers or parses what follows it.

asyncua 2.1's ``OPCUAProtocol`` reads any 3 bytes as a message type and the next 4 as a
size.  Bytes that are not OPC UA (an HTTP request, a port scanner's probe) got no answer and
no close: ``GET / HTTP/1.0`` reads as a chunk of 1.4 GB, which it waited for, buffering
whatever came; a short one of an unknown type raised in its message loop, a traceback in the
log, the connection left open.  OPC 10000-6 7.1.2.5 and 7.1.5 have the server answer an
Error message (``ERRF``) with the reason and close the connection.  An Error message from the
client is the client closing the connection (7.1.5): the server closes its side, answering
nothing (asyncua logged it and kept the connection, its secure channel and session, open).
This module imports asyncua and is imported only by :mod:`ncgate.gateway.opcua.space`.
"""

from __future__ import annotations

import logging
import struct
from typing import Any

from asyncua import ua
from asyncua.server.binary_server_asyncio import BinaryServer, OPCUAProtocol
from asyncua.server.server import Server
from asyncua.ua.status_codes import StatusCodes, code_to_name_doc
from asyncua.ua.ua_binary import uatcp_to_binary

log = logging.getLogger("ncgate.opcua")

# OPC 10000-6 7.1.2.2: the message types a server receives, and the chunk types each may
# have (Acknowledge and ReverseHello go from a server to a client; asyncua raised on them).
_FINAL_ONLY = frozenset({b"F"})
_CHUNKS = {b"HEL": _FINAL_ONLY, b"ERR": _FINAL_ONLY, b"OPN": _FINAL_ONLY,
           b"CLO": _FINAL_ONLY, b"MSG": frozenset({b"F", b"C", b"A"})}
_SECURE = frozenset({b"OPN", b"CLO", b"MSG"})  # their header has a SecureChannelId: 12 bytes
HEADER = struct.Struct("<3scI")


def header_refusal(header: bytes, max_chunk: int) -> tuple[int, str] | None:
    """What a message header (its first 8 bytes) is refused with, or None: an unknown
    message or chunk type is Bad_TcpMessageTypeInvalid, a chunk larger than the server's
    receive buffer Bad_TcpMessageTooLarge (7.1.2.4), one smaller than its own header
    Bad_DecodingError."""
    kind, chunk, size = HEADER.unpack(header)
    if chunk not in _CHUNKS.get(kind, ()):
        return StatusCodes.BadTcpMessageTypeInvalid, f"message type {(kind + chunk)!r}"
    if 0 < max_chunk < size:  # (0: no limit)
        return StatusCodes.BadTcpMessageTooLarge, f"a chunk of {size} bytes (at most {max_chunk})"
    if size <= (12 if kind in _SECURE else 8):
        return StatusCodes.BadDecodingError, f"a {kind.decode()} chunk of {size} bytes"
    return None


# OPC 10000-6 7.1.2.3: a Hello's body is 5 UInt32 and the EndpointUrl's length at least.
HELLO_MIN = HEADER.size + 24
# OPC 10000-6 7.1.2.5: an Error message's body is its Error (a StatusCode, UInt32) and its
# Reason (a String: an Int32 length, -1 for none, then UTF-8) of at most 4096 bytes.  The log
# line shows the reason's first characters, the reason being the client's to make long.
REASON_SHOWN = 200


def error_size(header: bytes, max_chunk: int) -> int:
    """How much of a client's Error message (its header: the first 8 bytes) to wait for
    before closing: the whole message, to log its status code and reason, unless the header
    already shows it is not one the server reads (a chunk type other than ``F``, a size
    shorter than the header or past the receive buffer): then the header alone."""
    chunk, size = header[3:4], int(HEADER.unpack(header)[2])
    if chunk != b"F" or size <= HEADER.size or 0 < max_chunk < size:
        return HEADER.size
    return size


def peer_error(message: bytes, max_chunk: int) -> str:
    """What a client's Error message says, for the log: its status code's name and its
    reason, or what in it is malformed.  ``message``: its first :func:`error_size` bytes."""
    kind, chunk, size = HEADER.unpack_from(message)
    if chunk != b"F":
        return f"message type {(kind + chunk)!r}"
    if 0 < max_chunk < size:
        return f"a chunk of {size} bytes (at most {max_chunk})"
    body = message[HEADER.size:size]
    if len(body) < 4:
        return f"a chunk of {size} bytes, too short for its status code"
    code = struct.unpack_from("<I", body)[0]
    name = code_to_name_doc.get(code, (f"0x{code:08X}",))[0]
    if len(body) < 8:
        return f"{name}, a chunk of {size} bytes, too short for its reason"
    length = struct.unpack_from("<i", body, 4)[0]
    if length == -1:
        return f"{name}, no reason"
    reason = body[8:8 + length]
    if length < -1 or len(reason) < length:
        return f"{name}, a reason of {length} bytes in a chunk of {size}"
    text = reason.decode("utf-8", "replace")
    more = f" (the first {REASON_SHOWN} of {len(text)} characters)" if len(
        text) > REASON_SHOWN else ""
    return f"{name} {text[:REASON_SHOWN]!r}{more}"


class _Protocol(OPCUAProtocol):
    """asyncua's protocol, which sees only headers it can take, in the order OPC 10000-6
    7.1.3 gives: a Hello first, and one; and no Error message, which closes the connection."""

    closed = False  # by a refusal or by the client's Error message: what comes after is dropped
    hello = False  # the Hello came
    _received = 0  # bytes received on the connection
    _judged = -1  # where the last header judged starts, counted as _received is

    def data_received(self, data: bytes) -> None:
        if self.closed or self.transport is None:
            return
        # asyncua's data_received adds the bytes to _buffer and takes every whole message
        # from its front, so _buffer holds at most the start of one: the headers from there.
        self._buffer += data
        self._received += len(data)
        buffer, at = self._buffer, 0
        base = self._received - len(buffer)  # where the buffer starts on the connection
        while len(buffer) - at >= HEADER.size:
            header = buffer[at:at + HEADER.size]
            size = HEADER.unpack(header)[2]
            if header[:3] == b"ERR":
                # Judged before the refusals, whatever the order or the size: an Error message
                # is never answered with one (two peers would volley them), and one that is
                # malformed still says the client is closing.
                wanted = error_size(header, self.limits.max_recv_buffer)
                if len(buffer) - at < wanted:
                    break  # its status code and reason are still to come
                self._close_for_client(buffer[at:at + wanted])
                return
            if base + at > self._judged:  # (a header seen before, still whole, is not again)
                self._judged = base + at
                refusal = header_refusal(header, self.limits.max_recv_buffer) or self._order(
                    header[:3], size)
                if refusal is not None:
                    self._refuse(*refusal)
                    return
            at += size
        super().data_received(b"")  # (b"" adds nothing to _buffer, and copies nothing)

    def _order(self, kind: bytes, size: int) -> tuple[int, str] | None:
        """A message out of order: anything before the Hello, a Hello too short to hold its
        fields, a second Hello (asyncua raised on the first two in its message loop -- a
        traceback, the connection left open unanswered -- and answered the third)."""
        if not self.hello:
            if kind != b"HEL":
                return StatusCodes.BadTcpMessageTypeInvalid, f"{kind.decode()} before Hello"
            if size < HELLO_MIN:
                return StatusCodes.BadDecodingError, f"a Hello of {size} bytes"
            self.hello = True
            return None
        if kind == b"HEL":
            return StatusCodes.BadTcpMessageTypeInvalid, "a second Hello"
        return None

    def _close_for_client(self, error: bytes) -> None:
        """OPC 10000-6 7.1.5: the client's Error message closes the connection, with no
        answer.  ``connection_lost`` then releases what the connection held, as for any close:
        its secure channel, and its session (asyncua keeps an activated session that has
        subscriptions for its timeout, OPC 10000-4 6.7, for the client to take back)."""
        self.closed = True
        self._buffer = b""
        log.warning("opcua %s: closed by the client's Error message: %s",
                    _peer(self.peer_name), peer_error(error, self.limits.max_recv_buffer))
        assert self.transport is not None
        self.transport.close()

    def _refuse(self, code: int, what: str) -> None:
        """OPC 10000-6 7.1.5: an Error message, then the connection is closed."""
        self.closed = True
        self._buffer = b""
        status = ua.StatusCode(ua.UInt32(code))
        log.warning("opcua %s: not OPC UA (%s): answered %s and closed",
                    _peer(self.peer_name), what, status.name)
        assert self.transport is not None
        error = ua.ErrorMessage(status, ua.String(f"{status.name}: {what}"))
        # (asyncua annotates the message type as its class MessageType; its values are bytes)
        self.transport.write(uatcp_to_binary(ua.MessageType.Error, error))  # type: ignore[arg-type]
        self.transport.close()


def _peer(name: Any) -> str:
    return f"{name[0]}:{name[1]}" if isinstance(name, tuple) and len(name) >= 2 else str(name)


class CheckedServer(Server):
    """asyncua's server, its connections :class:`_Protocol`'s.

    ``Server.start`` makes its ``BinaryServer`` and starts it in one go, with no protocol
    factory to pass in: this attribute's setter gives the new ``BinaryServer`` the factory
    before it listens (no library code is changed)."""

    _bserver: BinaryServer | None = None

    @property
    def bserver(self) -> BinaryServer | None:
        return self._bserver

    @bserver.setter
    def bserver(self, binary: BinaryServer | None) -> None:
        if binary is not None:
            def make() -> OPCUAProtocol:
                return _Protocol(iserver=binary.iserver,
                                 policies=binary._policies,  # (set_policies', after this)
                                 clients=binary.clients, closing_tasks=binary.closing_tasks,
                                 limits=binary.limits)
            binary._make_protocol = make  # type: ignore[method-assign]
        self._bserver = binary
