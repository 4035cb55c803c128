"""A raw Modbus TCP client on asyncio streams, for frames no well-behaved client would send."""

from __future__ import annotations

import asyncio
import ssl
import struct


def mbap(tid: int, unit: int, pdu: bytes, protocol: int = 0, length: int | None = None) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1 if length is None else length,
                       unit) + pdu


def pdu(fc: int, fmt: str = "", *values: int) -> bytes:
    return bytes((fc,)) + struct.pack(">" + fmt, *values)


class Raw:
    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self.tid = 0

    @classmethod
    async def open(cls, host: str, port: int, tls: ssl.SSLContext | None = None) -> Raw:
        reader, writer = await asyncio.open_connection(
            host, port, ssl=tls, server_hostname="localhost" if tls is not None else None)
        return cls(reader, writer)

    async def send(self, data: bytes) -> None:
        self.writer.write(data)
        await self.writer.drain()

    async def recv(self, timeout_s: float = 5.0) -> tuple[int, int, bytes]:
        """(transaction id, unit, response PDU)."""
        async with asyncio.timeout(timeout_s):
            header = await self.reader.readexactly(7)
            tid, protocol, length, unit = struct.unpack(">HHHB", header)
            assert protocol == 0
            return tid, unit, await self.reader.readexactly(length - 1)

    async def ask(self, request_pdu: bytes, unit: int = 1) -> bytes:
        self.tid = (self.tid + 1) & 0xFFFF
        await self.send(mbap(self.tid, unit, request_pdu))
        tid, got_unit, answer = await self.recv()
        assert (tid, got_unit) == (self.tid, unit)
        return answer

    async def closed_by_peer(self, timeout_s: float = 5.0) -> bool:
        """True when the server closes the connection (EOF or reset) within the timeout."""
        try:
            async with asyncio.timeout(timeout_s):
                data = await self.reader.read(1)
        except (ConnectionResetError, BrokenPipeError):
            return True
        return data == b""

    def close(self) -> None:
        self.writer.close()
