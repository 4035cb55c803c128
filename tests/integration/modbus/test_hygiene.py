"""Connection hygiene (spec 3.2): client limit, idle and half-open connections, concurrency."""

from __future__ import annotations

import asyncio
import socket
import struct

import pytest
from pymodbus.client import AsyncModbusTcpClient

import ncgate.gateway.modbus.server as modbus_server
from ncgate.gateway import Gateway

from ...helpers import cyclic_garbage
from .rawclient import Raw, mbap, pdu

GOOD = pdu(4, "HH", 0, 1)


@pytest.mark.parametrize("ncgate_config", [{"modbus.max_clients": 3}], indirect=True)
async def test_at_max_clients_a_silent_socket_makes_room_never_a_client(
        ncgate_gateway: Gateway) -> None:
    """Idle sockets cannot lock everyone out, and cannot knock a client off either: a socket
    that never completed a request makes room; with none such, the newcomer is refused."""
    address = ncgate_gateway.modbus_address
    server = ncgate_gateway.modbus_server
    assert server is not None
    clients = [await Raw.open(*address) for _ in range(2)]
    for c in clients:
        assert (await c.ask(GOOD))[0] == 4
    silent = await Raw.open(*address)  # connects, never asks
    await server.wait_connections(at_least=3)
    newcomer = await Raw.open(*address)
    assert (await newcomer.ask(GOOD))[0] == 4
    assert await silent.closed_by_peer(timeout_s=5.0)
    # Every connection has completed a request now: the next socket is refused.
    late = await Raw.open(*address)
    assert await late.closed_by_peer(timeout_s=5.0)
    for c in (*clients, newcomer):  # the clients are untouched
        assert (await c.ask(GOOD))[0] == 4
    assert len(server.connections) == 3
    for c in (*clients, newcomer):
        c.close()


@pytest.mark.parametrize("ncgate_config", [{"modbus.max_clients": 2,
                                            "modbus.evict": "refuse"}], indirect=True)
async def test_evict_refuse_keeps_even_a_silent_socket(ncgate_gateway: Gateway) -> None:
    address = ncgate_gateway.modbus_address
    server = ncgate_gateway.modbus_server
    assert server is not None
    client = await Raw.open(*address)
    assert (await client.ask(GOOD))[0] == 4
    silent = await Raw.open(*address)
    await server.wait_connections(at_least=2)
    late = await Raw.open(*address)
    assert await late.closed_by_peer(timeout_s=5.0)
    assert (await client.ask(GOOD))[0] == 4 and len(server.connections) == 2
    client.close()
    silent.close()


@pytest.mark.parametrize("ncgate_config", [{"modbus.max_clients": 2}], indirect=True)
async def test_a_burst_of_reset_sockets_never_refuses_the_next_client(
        ncgate_gateway: Gateway, caplog: pytest.LogCaptureFixture) -> None:
    address = ncgate_gateway.modbus_address
    for _ in range(50):  # connect and reset at once, as a scanner does
        _reader, writer = await asyncio.open_connection(*address)
        sock = writer.get_extra_info("socket")
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        writer.close()
    client = await Raw.open(*address)
    assert (await client.ask(GOOD))[0] == 4
    client.close()
    # The lines about making room are rate-limited: far fewer than the 48 evictions.
    lines = [r for r in caplog.records if "max_clients" in r.getMessage()]
    assert len(lines) < 10


@pytest.mark.parametrize("ncgate_config", [{"modbus.idle_timeout_s": 0.3}], indirect=True)
async def test_idle_connection_is_closed(ncgate_gateway: Gateway) -> None:
    client = await Raw.open(*ncgate_gateway.modbus_address)
    assert (await client.ask(GOOD))[0] == 4
    assert await client.closed_by_peer(timeout_s=5.0)


async def test_half_open_frame_is_closed(ncgate_gateway: Gateway,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(modbus_server, "PARTIAL_FRAME_TIMEOUT_S", 0.3)
    client = await Raw.open(*ncgate_gateway.modbus_address)
    await client.send(mbap(1, 1, GOOD)[:5])  # a frame that never completes
    assert await client.closed_by_peer(timeout_s=5.0)
    other = await Raw.open(*ncgate_gateway.modbus_address)
    assert (await other.ask(GOOD))[0] == 4
    other.close()


@pytest.mark.parametrize("ncgate_config", [{"modbus.allow": ["10.9.9.9"]}], indirect=True)
async def test_allow_list(ncgate_gateway: Gateway) -> None:
    client = await Raw.open(*ncgate_gateway.modbus_address)
    assert await client.closed_by_peer(timeout_s=2.0)


@pytest.mark.parametrize("ncgate_config", [{"modbus.max_clients": 20}], indirect=True)
async def test_twenty_concurrent_clients_lose_no_write(ncgate_gateway: Gateway) -> None:
    host, port = ncgate_gateway.modbus_address
    writes_each = 40

    async def client(k: int) -> None:
        c = AsyncModbusTcpClient(host, port=port, retries=0)
        assert await c.connect()
        try:
            for v in range(1, writes_each + 1):
                r = await c.write_register(1000 + k, v * 100 + k, device_id=1)  # SYVAR k
                assert not r.isError()
        finally:
            c.close()

    await asyncio.gather(*(client(k) for k in range(20)))
    image = ncgate_gateway.image
    assert [image.read("SYVAR", k, "IN") for k in range(20)] == [
        writes_each * 100 + k for k in range(20)]
    writes = [e for e in ncgate_gateway.trace if e["event"] == "write"]
    per_var = {f"SYVAR{k}": 0 for k in range(20)}
    for e in writes:
        per_var[e["var"]] += 1
    assert set(per_var.values()) == {writes_each}


async def test_each_frame_has_its_own_partial_frame_clock(
        ncgate_gateway: Gateway, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 10.2: segments that always end mid-frame, each frame completing at once, are
    served for as long as the client goes on (here three times the partial-frame timeout)."""
    timeout = 0.05
    monkeypatch.setattr(modbus_server, "PARTIAL_FRAME_TIMEOUT_S", timeout)
    client = await Raw.open(*ncgate_gateway.modbus_address)
    loop = asyncio.get_running_loop()
    frames = [mbap(tid, 1, GOOD) for tid in range(1, 10_000)]
    await client.send(frames[0][:5])
    start, i = loop.time(), 0
    while loop.time() - start < 3 * timeout:
        await client.send(frames[i][5:] + frames[i + 1][:5])  # ends in the middle of the next
        tid, _, answer = await client.recv()
        assert (tid, answer[0]) == (i + 1, 4)
        i += 1
    client.close()


async def test_a_client_that_never_reads_is_not_buffered_for_and_hurts_no_one(
        ncgate_gateway: Gateway) -> None:
    """Issue 10.3: backpressure. 10 MB of requests whose answers are never read: the server
    stops taking this client's requests once its unsent answers pass the high-water mark,
    and another client is served all the while.

    The kernel's buffers on the flood's two ends are made small (its own receive buffer, the
    server's send buffer for it), which changes nothing of what is tested: the transport's
    buffer, whose high-water mark stops the reading. With Linux's autotuned ones (4 MB a
    side) the server first answered some 16,000 requests, 16 a turn, to fill them, which
    took over 30 s at a load of 4 on 2 cores: the test ran out of its time. Small, they are
    full before the mark is passed, so the pause lasts: nothing drains the transport's
    buffer while the flood reads nothing."""
    address = ncgate_gateway.modbus_address
    server = ncgate_gateway.modbus_server
    assert server is not None
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, address)
    flood = Raw(*await asyncio.open_connection(sock=sock))
    await server.wait_connections(at_least=1)
    (flooding,) = server.connections
    transport = flooding.transport
    assert transport is not None
    transport.get_extra_info("socket").setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    request = mbap(1, 1, pdu(4, "HH", 100, 125))  # 12 bytes asking for a 257-byte answer
    flood.writer.write(request * (10 * 1024 * 1024 // len(request)))  # never drained, never read
    other = await Raw.open(*address)

    def bounded() -> bool:
        """What is kept for the flood, at any moment: the unsent answers up to the mark and
        one turn's more, and what arrived before its reading paused."""
        return (transport.get_write_buffer_size()
                < modbus_server.WRITE_HIGH_WATER + 2 * 64 * 1024
                and flooding.framer.buffered <= 1024 * 1024)

    # The other client is answered until the flood pauses (its pace is the poll: the server
    # state is another party's).
    while not flooding.paused:
        assert (await other.ask(GOOD))[0] == 4
        assert bounded()
    for _ in range(20):  # and after
        assert (await other.ask(GOOD))[0] == 4
        assert bounded()
    assert flooding.paused and not transport.is_reading()  # paused: it reads no requests
    assert transport.get_write_buffer_size() >= modbus_server.WRITE_HIGH_WATER
    flood.writer.transport.abort()
    other.close()


async def test_a_poller_and_a_running_cell_leave_nothing_for_the_cyclic_collector(
        ncgate_gateway: Gateway) -> None:
    """A poller's reads and writes and the engine's turns are freed by their reference
    counts: garbage that only the cyclic collector frees makes it run, with the interpreter's
    lock held, inside the turns that must stay on time."""
    client = await Raw.open(*ncgate_gateway.modbus_address)
    with cyclic_garbage() as found:
        ncgate_gateway.command(1)  # MAIN: EXE 2 SIDE, moves, then waits for SA10
        await ncgate_gateway.wait_state(1, "WAIT_COND", timeout_s=5)
        for value in range(100):
            assert (await client.ask(pdu(4, "HH", 100, 40)))[0] == 4  # P1, P2 records
            assert (await client.ask(pdu(6, "HH", 5, value)))[0] == 6  # SK5
            assert (await client.ask(pdu(1, "HH", 0, 16)))[0] == 1
        assert (await client.ask(pdu(5, "HH", 10, 0xFF00)))[0] == 5  # SA10: P1 goes on
        await ncgate_gateway.wait_state(1, "WAIT_PROC", timeout_s=5)
    client.close()
    assert found == []
