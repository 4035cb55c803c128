"""Bytes that are not OPC UA on the server's port (OPC 10000-6 7.1.2.5, 7.1.5): an Error
message (ERRF) with the reason, the connection closed by the server, one line in its log and
no traceback, and the server serving the next client.  A client's own Error message closes
its connection, unanswered."""

from __future__ import annotations

import asyncio
import random
import re
import struct
from urllib.parse import urlsplit

import pytest
from asyncua import Client, ua

from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from .conftest import IMAGE

Bad = ua.StatusCodes
# A whole Hello (OPC 10000-6 7.1.2.3): version, buffer sizes, message size, chunk count, and
# an EndpointUrl of its own length (here none).
HELLO = b"HELF" + struct.pack("<I", 32) + struct.pack("<5Ii", 0, 65536, 65536, 0, 0, -1)


async def answer_to(host: str, port: int, garbage: bytes) -> tuple[bytes, int]:
    """What the server sends back to ``garbage`` until it closes the connection, and the
    status code of its Error message."""
    reader, writer = await asyncio.open_connection(host, port)
    try:
        writer.write(garbage)
        await writer.drain()
        async with asyncio.timeout(10):
            answer = await reader.read()  # b"" ... to the end: the server closed it
    finally:
        writer.close()
    kind, size = answer[:4], struct.unpack_from("<I", answer, 4)[0]
    assert kind == b"ERRF", answer
    assert size == len(answer)  # the whole message, and nothing after it
    return answer, struct.unpack_from("<I", answer, 8)[0]


async def test_bytes_that_are_not_opc_ua_get_an_error_message_and_a_close(
        capfd: pytest.CaptureFixture[str]) -> None:
    garbage = random.Random(4840).randbytes(64)
    assert garbage[:3] not in (b"HEL", b"ERR", b"OPN", b"CLO", b"MSG")
    config = ncgate_test_config(**{"opcua.enabled": True, "opcua.port": 0,
                                   "canopen.enabled": False})
    async with Gateway(config) as gw:
        address = urlsplit(gw.opcua_endpoint)
        host, port = address.hostname, address.port
        assert host is not None and port is not None
        for sent, status in ((b"GET / HTTP/1.0\r\n\r\n", Bad.BadTcpMessageTypeInvalid),
                             (garbage, Bad.BadTcpMessageTypeInvalid),
                             # Whole, of a type asyncua raised on (a traceback, left open).
                             (b"ACKF" + struct.pack("<I", 16) + bytes(8),
                              Bad.BadTcpMessageTypeInvalid),
                             # A Hello of 1 GB: refused from its header, not buffered.
                             (b"HELF" + struct.pack("<I", 1 << 30) + bytes(24),
                              Bad.BadTcpMessageTooLarge),
                             (b"MSGF" + struct.pack("<I", 4), Bad.BadDecodingError),
                             # Out of order (OPC 10000-6 7.1.3): asyncua raised on these in
                             # its message loop, a traceback, the connection left unanswered.
                             (b"MSGF" + struct.pack("<I", 24) + bytes(16),
                              Bad.BadTcpMessageTypeInvalid),
                             (b"OPNF" + struct.pack("<I", 24) + bytes(16),
                              Bad.BadTcpMessageTypeInvalid),
                             (b"HELF" + struct.pack("<I", 12) + bytes(4),
                              Bad.BadDecodingError),
                             (HELLO + HELLO, Bad.BadTcpMessageTypeInvalid)):
            _, code = await answer_to(host, port, sent)
            assert code == status, (sent, hex(code))
        async with Client(gw.opcua_endpoint) as client:  # and the server still serves
            state = client.get_node(ua.NodeId(ua.ObjectIds.Server_ServerStatus_State))
            assert await state.read_value() == ua.ServerState.Running
    err = capfd.readouterr().err
    assert "Traceback" not in err
    # Nine refusals: five lines, then the log's budget (five of a kind every 10 s) counts
    # the rest in one line.
    assert err.count("not OPC UA") == 6 and "4 more like: " in err, err


def error_message(code: int, reason: bytes | None) -> bytes:
    """A client's Error message (OPC 10000-6 7.1.2.5): the status code and the reason."""
    body = struct.pack("<I", code) + (struct.pack("<i", -1) if reason is None
                                      else struct.pack("<i", len(reason)) + reason)
    return b"ERRF" + struct.pack("<I", 8 + len(body)) + body


async def closed_after(host: str, port: int, hello: bool, *error: bytes) -> bytes:
    """What the server sends after the parts of ``error`` (each written on its own) until it
    closes the connection, after a Hello and its Acknowledge when ``hello``."""
    reader, writer = await asyncio.open_connection(host, port)
    try:
        async with asyncio.timeout(10):
            if hello:
                writer.write(HELLO)
                header = await reader.readexactly(8)
                assert header[:4] == b"ACKF", header
                await reader.readexactly(struct.unpack_from("<I", header, 4)[0] - 8)
            for part in error:
                writer.write(part)
                await writer.drain()
            return await reader.read()  # to the end: the server closed it
    finally:
        writer.close()


async def test_an_error_message_from_the_client_closes_its_connection_unanswered(
        capfd: pytest.CaptureFixture[str]) -> None:
    """OPC 10000-6 7.1.5: a client's Error message closes the connection.  The server closes
    its side with no answer (an Error is never answered with one), before or after the
    Hello, and when the message is malformed; one line names the client and what it said,
    and the server serves the next client."""
    config = ncgate_test_config(**{"opcua.enabled": True, "opcua.port": 0,
                                   "canopen.enabled": False})
    leaving = error_message(Bad.BadSecureChannelClosed, b"going away")
    async with Gateway(config) as gw:
        address = urlsplit(gw.opcua_endpoint)
        host, port = address.hostname, address.port
        assert host is not None and port is not None
        for hello, parts in ((True, (leaving,)),
                             # Its reason in a later segment: waited for, then logged.
                             (True, (leaving[:13], leaving[13:])),
                             (True, (error_message(Bad.BadTcpInternalError, None),)),
                             (False, (error_message(Bad.BadTcpEndpointUrlInvalid, b"before"),)),
                             # Malformed: no reason, no status code, a reason longer than the
                             # message, a chunk type of its own, past the receive buffer.
                             (True, (b"ERRF" + struct.pack("<II", 12, Bad.BadTimeout),)),
                             (True, (b"ERRF" + struct.pack("<I", 9) + b"\0",)),
                             (True, (b"ERRF" + struct.pack("<IIi", 16, Bad.BadTimeout, 99),)),
                             (True, (b"ERRC" + struct.pack("<I", 16) + bytes(8),)),
                             (False, (b"ERRF" + struct.pack("<I", 1 << 30),))):
            assert await closed_after(host, port, hello, *parts) == b"", parts
        async with Client(gw.opcua_endpoint) as client:  # and the server still serves
            state = client.get_node(ua.NodeId(ua.ObjectIds.Server_ServerStatus_State))
            assert await state.read_value() == ua.ServerState.Running
    err = capfd.readouterr().err
    assert "Traceback" not in err and "not OPC UA" not in err, err
    closes = [line for line in err.splitlines() if "closed by the client's Error message" in line]
    # Nine closes: five lines, then the log's budget (five of a kind every 10 s) counts the
    # rest in one line, with the last.
    assert len(closes) == 6, err
    assert re.search(r"opcua 127\.0\.0\.1:\d+: closed by the client's Error message: "
                     r"BadSecureChannelClosed 'going away'", closes[0]), closes[0]
    assert closes[1].endswith("BadSecureChannelClosed 'going away'"), closes[1]
    assert closes[2].endswith("BadTcpInternalError, no reason"), closes[2]
    assert closes[3].endswith("BadTcpEndpointUrlInvalid 'before'"), closes[3]
    assert closes[4].endswith("BadTimeout, a chunk of 12 bytes, too short for its reason"), \
        closes[4]
    assert "4 more like: " in closes[5] and closes[5].endswith(
        "a chunk of 1073741824 bytes (at most 65535)"), closes[5]


async def test_an_error_message_from_the_client_ends_its_session() -> None:
    """The connection a client's Error message closes gives up its secure channel and its
    session: with room for one session, the next client gets it."""
    config = ncgate_test_config(**{"opcua.enabled": True, "opcua.port": 0,
                                   "canopen.enabled": False, "opcua.max_sessions": 1,
                                   "opcua.writable": ["syvars"]})
    async with Gateway(config) as gw:
        adapter = gw.adapters["opcua"]
        leaver = Client(gw.opcua_endpoint)
        await leaver.connect()
        protocol = leaver.uaclient.protocol
        assert protocol is not None and protocol.transport is not None
        closed = asyncio.Event()
        told = protocol.on_connection_lost

        def lost(exc: Exception | None) -> None:
            closed.set()
            if told is not None:
                told(exc)

        protocol.on_connection_lost = lost
        try:
            protocol.transport.write(error_message(Bad.BadSecureChannelClosed, b"going away"))
            async with asyncio.timeout(10):
                await closed.wait()
        finally:
            leaver.disconnect_socket()
        async with Client(gw.opcua_endpoint) as probe:  # the one session there is room for
            ns = await probe.get_namespace_index(IMAGE)
            # Its write goes through the gateway after the counts told before it.
            await probe.get_node(ua.NodeId("SYVAR7", ns)).write_value(
                ua.Variant(1, ua.VariantType.Int16))
            assert (adapter.sessions, adapter.subscriptions) == (1, 0)
