"""Bytes that are not OPC UA on the server's port (OPC 10000-6 7.1.2.5, 7.1.5): an Error
message (ERRF) with the reason, the connection closed by the server, one line in its log and
no traceback, and the server serving the next client."""

from __future__ import annotations

import asyncio
import random
import struct
from urllib.parse import urlsplit

import pytest
from asyncua import Client, ua

from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

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
