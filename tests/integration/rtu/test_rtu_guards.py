"""What a hostile review found in Modbus RTU, each held to its rule: RTU over TCP keeps the
Modbus TCP server's guards (the allow-list, max_clients, the idle timeout, a frame cut by a
disconnect counted); a serial line whose master stops reading does not make the gateway
buffer without bound; a refused broadcast is not counted as applied; a config without a
serial address for RTU is refused."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

import pytest

from ncgate.config import ConfigError
from ncgate.gateway import Gateway
from ncgate.gateway.rtu import server as rtu
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.gateway.web.status import fieldbus

from .conftest import RawLine, frame


async def rtu_tcp_gateway(cell: Path, **more: object) -> Gateway:
    return Gateway(ncgate_test_config(cell / "ncgate.toml", **{"modbus.rtu_tcp.port": 0,
                                                                 **more}))


async def connect(gw: Gateway) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    host, port = gw.adapters["modbus_rtu"].tcp.address
    return await asyncio.open_connection(host, port)


async def test_rtu_over_tcp_keeps_the_allow_list(cell: Path) -> None:
    async with await rtu_tcp_gateway(cell, **{"modbus.allow": ["10.0.0.0/8"]}) as gw:
        reader, writer = await connect(gw)
        writer.write(frame("01 06 03E9 04D2"))  # SYVAR1 = 1234, from 127.0.0.1
        assert await reader.read(100) == b""  # closed, unanswered
        writer.close()
        assert gw.image.syvar[1] == 0


async def test_rtu_over_tcp_keeps_max_clients_and_the_idle_timeout(cell: Path) -> None:
    async with await rtu_tcp_gateway(cell, **{"modbus.max_clients": 2,
                                              "modbus.idle_timeout_s": 0.3}) as gw:
        first, second, third = [await connect(gw) for _ in range(3)]
        assert await third[0].read(100) == b""  # refused: two are connected
        first[1].write(frame("01 04 0001 0001"))
        assert await first[0].readexactly(7) == frame("01 04 02 0004")
        # Silent from here: each is closed after the idle timeout (an EOF, not a hang).
        for reader, _ in (first, second):
            async with asyncio.timeout(10):
                assert await reader.read(100) == b""
        for _, writer in (first, second, third):
            writer.close()


async def test_a_frame_cut_by_a_disconnect_is_counted_partial(cell: Path) -> None:
    async with await rtu_tcp_gateway(cell) as gw:
        _, writer = await connect(gw)
        writer.write(frame("01 04 0000 0002")[:5])
        await writer.drain()
        writer.close()
        await writer.wait_closed()
        listener = gw.adapters["modbus_rtu"].tcp
        await listener.all_closed.wait()
        assert fieldbus(gw)["modbus_rtu"]["partial"] == 1


async def test_a_serial_master_that_stops_reading_is_not_buffered_for(
        raw_gateway: Gateway, raw_line: RawLine) -> None:
    gw = raw_gateway
    line = gw.adapters["modbus_rtu"].serial
    asyncio.get_running_loop().remove_reader(raw_line.master)  # the master stops reading
    request = frame("01 03 0000 007D")  # 125 K-byte registers: a 255-byte answer each
    frames = 0  # frames begun
    rest = b""  # the bytes of the last one the driver has not taken yet
    loop = asyncio.get_running_loop()
    writable = asyncio.Event()
    async with asyncio.timeout(20):
        while line.is_open and not line.paused:
            if not rest:
                rest, frames = request, frames + 1
            try:
                rest = rest[os.write(raw_line.master, rest):]
            except BlockingIOError:  # the driver's buffer towards the gateway is full: until
                writable.clear()     # the gateway reads more, or stops reading
                line.changed.clear()
                loop.add_writer(raw_line.master, writable.set)
                waits = [asyncio.ensure_future(writable.wait()),
                         asyncio.ensure_future(line.changed.wait())]
                await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
                for w in waits:
                    w.cancel()
                loop.remove_writer(raw_line.master)
    # What waits is bounded: the high-water mark, and the answers to the frames read before.
    assert len(line.pending) <= rtu.PENDING_MOST, (len(line.pending), rtu.PENDING_MOST)
    status = fieldbus(gw)["modbus_rtu"]["ports"][0]
    assert status["reading"] is False and status["unsent"] == len(line.pending)
    # The master reads again: every answer comes, reading resumes, a new request is answered.
    loop.add_reader(raw_line.master, raw_line._readable)
    os.set_blocking(raw_line.master, True)
    os.write(raw_line.master, rest)  # the last frame whole (blocking: the gateway reads now)
    os.set_blocking(raw_line.master, False)
    answers = await raw_line.answer(frames * 255, timeout_s=60)
    assert answers[:255] == answers[-255:] == frame("01 03 FA" + "0000" * 125)
    raw_line.send(frame("01 04 0001 0001"))
    assert await raw_line.answer(7) == frame("01 04 02 0004")


async def test_a_refused_broadcast_is_not_counted_applied(raw_gateway: Gateway,
                                                          raw_line: RawLine) -> None:
    raw_line.send(frame("00 06 0007 012C"))  # SK7 = 300 to every slave: not a byte, refused
    await raw_line.silence()
    raw_line.send(frame("00 06 0007 0012"))  # SK7 = 18: applied
    await raw_line.silence()
    raw_line.send(frame("01 04 0001 0001"))
    assert await raw_line.answer(7) == frame("01 04 02 0004")
    assert raw_gateway.image.k[7] == 18
    assert fieldbus(raw_gateway)["modbus_rtu"]["broadcasts"] == 1


def test_rtu_without_a_serial_address_is_a_config_error(cell: Path) -> None:
    with pytest.raises(ConfigError) as caught:
        ncgate_test_config(cell / "ncgate.toml", **{"modbus.unit_ids": [255],
                                                   "modbus.rtu_tcp.port": 0})
    assert "modbus.rtu.unit_ids: missing: modbus.unit_ids ([255]) has no serial address" \
        in str(caught.value)


async def test_rtu_over_tcp_a_delayed_write_acts_after_its_client_left_and_at_a_clear(
        cell: Path) -> None:
    """As on Modbus TCP: a write a delay holds acts at its time when its client has gone
    (it was dropped), and a clear brings that time to now (it waited the hour)."""
    async with await rtu_tcp_gateway(cell) as gw:
        listener = gw.adapters["modbus_rtu"].tcp
        gw.fault("modbus", "delay", ms=3_600_000, addresses=[1001, 1001])
        _, writer = await connect(gw)
        writer.write(frame("01 06 03E9 04D2"))  # SYVAR1 = 1234
        await writer.drain()
        # Another client's request, answered after its own 20 ms gap: the first frame's
        # gap, armed before, has passed by then, and the write is held.
        other_reader, other = await connect(gw)
        other.write(frame("01 04 0001 0001"))
        assert await other_reader.readexactly(7) == frame("01 04 02 0004")
        assert sum(1 for c in listener.connections if c.link is not None and c.link.held) == 1
        other.close()
        writer.close()
        await writer.wait_closed()
        await listener.all_closed.wait()
        assert len(listener.orphans) == 1 and gw.image.syvar[1] == 0
        stored = asyncio.Event()
        gw.image.subscribe(lambda changes, who: stored.set() if gw.image.syvar[1] else None)
        gw.clear_fault("modbus")
        async with asyncio.timeout(10):
            await stored.wait()
        assert gw.image.syvar[1] == 1234
