"""The fault table (gateway/modbus/faults.py) as clients see it over loopback: the pymodbus
client, mbpoll and a raw socket.  Each fault is seen exactly while it is set."""

from __future__ import annotations

import asyncio
import shutil
import time
from collections.abc import AsyncIterator

import pytest
import pytest_asyncio
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException

from ncgate.gateway import Gateway
from ncgate.gateway.modbus.faults import FaultError, ModbusFault
from ncgate.gateway.modbus.server import ModbusServer

from .rawclient import Raw, mbap, pdu
from .test_mbpoll import mbpoll

BUSY = 6


def server_of(gw: Gateway) -> ModbusServer:
    server = gw.modbus_server
    assert server is not None
    return server


@pytest_asyncio.fixture
async def client(ncgate_gateway: Gateway) -> AsyncIterator[AsyncModbusTcpClient]:
    host, port = ncgate_gateway.modbus_address
    c = AsyncModbusTcpClient(host, port=port, retries=0, timeout=5)
    assert await c.connect()
    yield c
    c.close()


async def test_an_exception_fault_is_seen_exactly_while_it_is_set(
        ncgate_gateway: Gateway, client: AsyncModbusTcpClient) -> None:
    server = server_of(ncgate_gateway)
    assert not (await client.read_input_registers(0, count=2, device_id=1)).isError()
    server.set_faults([ModbusFault("exception")])
    assert server.faults == (ModbusFault("exception", code=BUSY),)
    for _ in range(3):
        answer = await client.read_input_registers(0, count=2, device_id=1)
        assert answer.isError() and answer.exception_code == BUSY
    answer = await client.read_coils(10, count=1, device_id=7)  # every unit, every table
    assert answer.isError() and answer.exception_code == BUSY
    server.set_faults([])
    answer = await client.read_input_registers(0, count=2, device_id=1)
    assert not answer.isError() and answer.registers == [1, 4]
    assert server.fault_counts["exception"] == 4


async def test_a_fault_applies_to_its_unit_and_address_range_only(
        ncgate_gateway: Gateway, client: AsyncModbusTcpClient) -> None:
    server = server_of(ncgate_gateway)
    server.set_faults([ModbusFault("exception", code=4, unit=1, addresses=(5, 6))])
    for address, count, faulted in [(0, 5, False), (0, 6, True), (6, 3, True), (7, 3, False)]:
        answer = await client.read_holding_registers(address, count=count, device_id=1)
        assert answer.isError() is faulted, (address, count)
        if faulted:
            assert answer.exception_code == 4
    answer = await client.read_holding_registers(5, count=1, device_id=7)  # another unit
    assert not answer.isError()
    assert server.fault_counts["exception"] == 2


async def test_a_write_under_an_exception_fault_stores_nothing(
        ncgate_gateway: Gateway, client: AsyncModbusTcpClient) -> None:
    gw = ncgate_gateway
    server_of(gw).set_faults([ModbusFault("exception", addresses=(5, 5))])
    before = gw.image.snapshot()
    answer = await client.write_register(5, 200, device_id=1)  # SK5
    assert answer.isError() and answer.exception_code == BUSY
    answer = await client.write_registers(4, [9, 200], device_id=1)  # SK4, SK5
    assert answer.isError() and answer.exception_code == BUSY
    answer = await client.write_coil(5, True, device_id=1)  # the range is of any table
    assert answer.isError() and answer.exception_code == BUSY
    assert gw.image.snapshot() == before
    server_of(gw).set_faults(())
    assert not (await client.write_register(5, 200, device_id=1)).isError()
    assert gw.image.read("SK", 5, "BY") == 200


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll not installed "
                    "(apt-get install mbpoll); CI runs it")
async def test_mbpoll_sees_server_busy_while_the_fault_is_set(ncgate_gateway: Gateway) -> None:
    gw = ncgate_gateway
    server_of(gw).set_faults([ModbusFault("exception")])
    rc, _, text = await mbpoll(gw, "input", 0, 2)
    assert rc != 0 and "busy" in text.lower(), text
    rc, _, text = await mbpoll(gw, "holding", 5, write=[200])
    assert rc != 0 and "busy" in text.lower(), text
    assert gw.image.read("SK", 5, "BY") == 0
    server_of(gw).set_faults([])
    rc, values, _ = await mbpoll(gw, "input", 0, 2)
    assert rc == 0 and values == {0: 1, 1: 4}


async def test_a_delayed_answer_comes_no_earlier_than_its_delay(
        ncgate_gateway: Gateway, client: AsyncModbusTcpClient) -> None:
    server = server_of(ncgate_gateway)
    server.set_faults([ModbusFault("delay", ms=300)])
    for _ in range(2):
        began = time.monotonic()
        answer = await client.read_input_registers(0, count=2, device_id=1)
        assert time.monotonic() - began >= 0.3
        assert answer.registers == [1, 4]
    server.set_faults([ModbusFault("delay", ms=250, unit=1)])
    began = time.monotonic()
    assert not (await client.write_register(1000, 42, device_id=1)).isError()  # SYVAR0
    assert time.monotonic() - began >= 0.25
    assert ncgate_gateway.image.read("SYVAR", 0, "IN") == 42  # executed, late
    assert server.fault_counts["delay"] == 3


async def test_a_delay_holds_its_connection_in_order_and_no_other(
        ncgate_gateway: Gateway) -> None:
    """Two requests pipelined behind a delayed one are answered after it, in order; another
    connection is answered while it is held."""
    server = server_of(ncgate_gateway)
    server.set_faults([ModbusFault("delay", ms=1000, unit=1, addresses=(0, 0))])
    held, other = await Raw.open(*ncgate_gateway.modbus_address), await Raw.open(
        *ncgate_gateway.modbus_address)
    began = time.monotonic()
    await held.send(mbap(1, 1, pdu(4, "HH", 0, 1)) + mbap(2, 1, pdu(4, "HH", 1, 1))
                    + mbap(3, 1, pdu(4, "HH", 1, 1)))
    first = asyncio.create_task(held.recv())
    assert await other.ask(pdu(4, "HH", 0, 2), unit=7) == bytes.fromhex("04 04 0001 0004")
    assert not first.done()  # the other connection was served while this one is held
    assert (await first)[0] == 1
    assert time.monotonic() - began >= 1.0
    assert [(await held.recv())[0] for _ in range(2)] == [2, 3]
    held.close()
    other.close()


async def test_no_reply_times_the_client_out_and_silences_its_connection_only(
        ncgate_gateway: Gateway) -> None:
    gw = ncgate_gateway
    server = server_of(gw)
    host, port = gw.modbus_address
    server.set_faults([ModbusFault("no_reply", addresses=(0, 0))])
    quiet = AsyncModbusTcpClient(host, port=port, retries=0, timeout=0.5)
    assert await quiet.connect()
    other = await Raw.open(host, port)
    with pytest.raises(ModbusException):
        await quiet.read_input_registers(0, count=1, device_id=1)
    quiet.close()
    assert (await other.ask(pdu(4, "HH", 1, 1)))[0] == 4  # another connection: served
    # A raw client on the same fault: its later requests, matching or not, go unanswered,
    # also once the fault is cleared; the connection stays open and others are served.
    silent = await Raw.open(host, port)
    await silent.send(mbap(1, 1, pdu(4, "HH", 0, 1)) + mbap(2, 1, pdu(4, "HH", 1, 1)))
    assert (await other.ask(pdu(4, "HH", 1, 1)))[0] == 4  # after the two, on the loop's turn
    server.set_faults([])
    await silent.send(mbap(3, 1, pdu(4, "HH", 1, 1)))
    assert (await other.ask(pdu(4, "HH", 0, 1)))[0] == 4
    with pytest.raises(TimeoutError):
        await silent.recv(timeout_s=0.3)
    assert not silent.reader.at_eof()
    counts = server.fault_counts
    assert counts["no_reply"] == 2 and counts["silenced"] == 2, counts
    silent.close()
    other.close()


async def test_set_faults_is_all_or_nothing(ncgate_gateway: Gateway) -> None:
    server = server_of(ncgate_gateway)
    row = ModbusFault("delay", ms=5)
    server.set_faults([row])
    with pytest.raises(FaultError):
        server.set_faults([ModbusFault("exception"), "busy"])  # type: ignore[list-item]
    assert server.faults == (row,)


async def test_a_delayed_write_acts_at_its_time_when_its_client_has_left(
        ncgate_gateway: Gateway) -> None:
    """docs/plant.md: a write under a delay acts then, "also when the client gave up
    waiting" -- and masters give up by closing the connection, which dropped it."""
    gw = ncgate_gateway
    server = server_of(gw)
    server.set_faults([ModbusFault("delay", ms=300, addresses=(1000, 1000))])
    stored = asyncio.Event()
    gw.image.subscribe(lambda changes, writer: stored.set() if gw.image.read(
        "SYVAR", 0, "IN") == 42 else None)
    leaver = await Raw.open(*gw.modbus_address)
    began = time.monotonic()
    await leaver.send(mbap(1, 1, pdu(6, "HH", 1000, 42)) + mbap(2, 1, pdu(6, "HH", 1001, 7)))
    leaver.close()
    async with asyncio.timeout(10):
        await stored.wait()
    assert time.monotonic() - began >= 0.3
    assert gw.image.read("SYVAR", 1, "IN") == 0  # not taken yet when it left: gone with it
    assert not server.orphans


async def test_a_clear_answers_a_held_request_at_once(ncgate_gateway: Gateway) -> None:
    server = server_of(ncgate_gateway)
    server.set_faults([ModbusFault("delay", ms=3_600_000, unit=1)])
    raw, other = (await Raw.open(*ncgate_gateway.modbus_address),
                  await Raw.open(*ncgate_gateway.modbus_address))
    await raw.send(mbap(1, 1, pdu(4, "HH", 0, 2)) + mbap(2, 1, pdu(4, "HH", 0, 2)))
    answer = asyncio.create_task(raw.recv(timeout_s=10))
    await other.ask(pdu(4, "HH", 0, 2), unit=7)  # served after the loop read the first
    assert [c.held is not None for c in server.connections].count(True) == 1
    server.set_faults([ModbusFault("exception", unit=9)])  # no delay matches it any more
    assert await answer == (1, 1, bytes.fromhex("04 04 0001 0004"))
    assert (await raw.recv())[0] == 2  # and the one behind it
    raw.close()
    other.close()


@pytest.mark.parametrize("order", ["delay first", "exception first"])
async def test_an_exception_wins_over_a_delay_whatever_came_first(
        ncgate_gateway: Gateway, order: str) -> None:
    """The first row decided: a delay injected before an exception let a write the
    exception covers through, and stored it."""
    gw = ncgate_gateway
    server = server_of(gw)
    rows = [ModbusFault("delay", ms=50), ModbusFault("exception", code=4, unit=1,
                                                     addresses=(1000, 1000))]
    server.set_faults(rows if order == "delay first" else rows[::-1])
    raw = await Raw.open(*gw.modbus_address)
    assert await raw.ask(pdu(6, "HH", 1000, 42)) == bytes.fromhex("86 04")
    assert gw.image.read("SYVAR", 0, "IN") == 0
    assert (await raw.ask(pdu(4, "HH", 0, 2)))[0] == 4  # the delay still acts elsewhere
    raw.close()


@pytest.mark.parametrize("ncgate_config", [{"modbus.idle_timeout_s": 0.5}], indirect=True)
async def test_a_client_that_left_behind_a_backlog_and_a_held_request_frees_its_slot(
        ncgate_gateway: Gateway) -> None:
    """Past the backlog's high-water mark reading pauses, so the end of stream was never
    read: the connection sat in CLOSE-WAIT, a slot of max_clients, for the delay's hour."""
    server = server_of(ncgate_gateway)
    server.set_faults([ModbusFault("delay", ms=3_600_000)])
    leaver = await Raw.open(*ncgate_gateway.modbus_address)
    await leaver.send(mbap(1, 1, pdu(3, "HH", 1000, 1)) * 3000)  # 36 KB, then gone
    async with asyncio.timeout(10):
        while not server.connections:
            server.connections_changed.clear()
            await server.connections_changed.wait()
    leaver.close()
    async with asyncio.timeout(10):  # the idle check sees it gone (0.5 s), not the hour
        while server.connections:
            server.connections_changed.clear()
            await server.connections_changed.wait()
    assert len(server.orphans) == 1  # its held read acts at its time, unanswered


async def test_a_held_request_is_due_at_its_arrival_plus_the_longest_delay_now_in_force(
        ncgate_gateway: Gateway) -> None:
    """The 1 h row ends (its for_s) and a 10 ms one stays: the request waited the hour,
    since a delay still matched it."""
    server = server_of(ncgate_gateway)
    server.set_faults([ModbusFault("delay", ms=3_600_000, unit=1), ModbusFault("delay", ms=10)])
    raw, other = (await Raw.open(*ncgate_gateway.modbus_address),
                  await Raw.open(*ncgate_gateway.modbus_address))
    await raw.send(mbap(1, 1, pdu(4, "HH", 0, 2)))
    answer = asyncio.create_task(raw.recv(timeout_s=10))
    await other.ask(pdu(4, "HH", 0, 2), unit=7)  # (10 ms late: the loop read the first)
    assert [c.held is not None for c in server.connections].count(True) == 1
    server.set_faults([ModbusFault("delay", ms=10)])
    assert await answer == (1, 1, bytes.fromhex("04 04 0001 0004"))
    raw.close()
    other.close()
