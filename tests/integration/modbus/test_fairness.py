"""The cell stays on time under any load, on the Modbus side: a pipelining client is served at
its share and stalls nobody; a connect flood knocks no client off and floods no log.  Counts,
not wall-clock times: what the server did before it answered the other client."""

from __future__ import annotations

import logging

import pytest

from ncgate.gateway import Gateway

from .rawclient import Raw, mbap, pdu

READ = pdu(3, "HH", 0, 1)  # FC3, one holding register
FLOOD = 20_000


async def test_a_pipelined_flood_does_not_hold_up_a_poller(ncgate_gateway: Gateway) -> None:
    address = ncgate_gateway.modbus_address
    server = ncgate_gateway.modbus_server
    assert server is not None
    greedy, poller = await Raw.open(*address), await Raw.open(*address)
    assert (await poller.ask(READ))[0] == 3
    # 20,000 requests in one write (240 KB), never drained here: the server reads them in
    # the chunks its transport hands over.
    greedy.writer.write(b"".join(mbap(i & 0xFFFF, 1, READ) for i in range(FLOOD)))
    await greedy.recv()  # the server has begun on the flood
    before = server.handler.served
    # It yielded the loop after a few turns of it (today's old code answered all 20,000
    # before anything else could run).
    assert before < FLOOD // 10, before
    assert (await poller.ask(READ))[0] == 3
    served_meanwhile = server.handler.served - before
    # Answering the poller waited for a few turns of the greedy client, not for a chunk of
    # thousands of its requests.
    assert served_meanwhile < FLOOD // 10, served_meanwhile
    # And the greedy client still gets every answer, in order.
    for i in range(1, 200):
        tid, _, answer = await greedy.recv()
        assert tid == i and answer[0] == 3
    greedy.close()
    poller.close()


async def test_many_greedy_clients_share_one_round_of_the_loop(
        ncgate_gateway: Gateway, monkeypatch: pytest.MonkeyPatch) -> None:
    """Four clients with thousands of requests queued each: a poller waits for one round of
    their turns, and a round is ROUND_S whatever their number (each gets its share of it), not
    ROUND_S each.  Every request here costs 100 µs of the loop, so a 0.5 ms turn each (the old
    rule) made a round of about 24 of their requests, the shared round about 8."""
    import time

    from ncgate.gateway.modbus import server as server_module

    server = ncgate_gateway.modbus_server
    assert server is not None
    real_handle = server.handler.handle

    def slow_handle(*args: object) -> bytes:
        until = time.perf_counter() + 0.0001  # a request that costs the loop 100 µs
        while time.perf_counter() < until:
            pass
        return real_handle(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(server.handler, "handle", slow_handle)  # the connections made next
    address = ncgate_gateway.modbus_address
    greedy = [await Raw.open(*address) for _ in range(4)]
    poller = await Raw.open(*address)
    assert (await poller.ask(READ))[0] == 3
    for client in greedy:  # never read here: each keeps turns due
        client.writer.write(b"".join(mbap(i, 1, READ) for i in range(1, 3001)))
        await client.writer.drain()
    for client in greedy:
        await client.recv()  # every one has had a turn: the four are in the round
    rounds = []
    for _ in range(10):
        before = server.handler.served
        assert (await poller.ask(READ))[0] == 3
        rounds.append(server.handler.served - before - 1)
    # This poller shares the gateway's loop: its request goes out in one loop turn, is read
    # and answered in the next, and its answer read in a third or fourth -- a round of the
    # four greedy turns in each (ROUND_S over 100 µs requests, and the one request each turn
    # answers whatever its share).  Four rounds: 36 at most; a turn of ROUND_S each: ~72.
    bound = 4 * (round(server_module.ROUND_S / 0.0001) + 4)
    assert max(rounds) <= bound, rounds
    for client in greedy:
        client.close()
    poller.close()


@pytest.mark.parametrize("ncgate_config", [{"modbus.max_clients": 4}], indirect=True)
async def test_a_connect_flood_knocks_no_client_off(
        ncgate_gateway: Gateway, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="ncgate.modbus")
    address = ncgate_gateway.modbus_address
    poller = await Raw.open(*address)
    assert (await poller.ask(READ))[0] == 3
    sockets = []
    for _ in range(60):  # sockets that connect and never send a byte
        sockets.append(await Raw.open(*address))
        assert (await poller.ask(READ))[0] == 3  # the poller is served throughout
    assert (await poller.ask(READ))[0] == 3
    server = ncgate_gateway.modbus_server
    assert server is not None and len(server.connections) <= 4
    lines = [r for r in caplog.records if r.name == "ncgate.modbus"]
    assert len(lines) < 40, len(lines)  # not a line per socket (60 connects, 57 closes)
    for s in sockets:
        s.close()
    poller.close()


@pytest.mark.parametrize("ncgate_config", [{"modbus.idle_timeout_s": 1.0}], indirect=True)
async def test_a_slow_reader_is_not_closed_as_idle(ncgate_gateway: Gateway,
                                                   caplog: pytest.LogCaptureFixture) -> None:
    """A client whose answers back up (the server pauses it) but who keeps reading them is
    active: the idle timeout is for silent clients."""
    import asyncio
    import socket

    server = ncgate_gateway.modbus_server
    assert server is not None
    host, port = ncgate_gateway.modbus_address
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # answers back up at once
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, (host, port))
    reader, writer = await asyncio.open_connection(sock=sock)
    request = pdu(3, "HH", 0, 125)  # 257-byte answers
    writer.write(b"".join(mbap(i & 0xFFFF, 1, request) for i in range(20_000)))
    (connection,) = server.connections
    read = 0
    began = asyncio.get_running_loop().time()
    while asyncio.get_running_loop().time() - began < 3.0:  # three idle timeouts
        read += len(await reader.read(8192))
        await asyncio.sleep(0.05)  # the stimulus: a slow reader's pace
    assert connection in server.connections and connection.paused, read
    assert not any("idle for" in r.getMessage() for r in caplog.records)
    writer.close()


async def test_clients_that_never_read_do_not_hold_up_a_poller(
        ncgate_gateway: Gateway) -> None:
    address = ncgate_gateway.modbus_address
    server = ncgate_gateway.modbus_server
    assert server is not None
    poller = await Raw.open(*address)
    assert (await poller.ask(READ))[0] == 3
    request = pdu(3, "HH", 0, 125)  # 257-byte answers that nobody reads
    greedy = [await Raw.open(*address) for _ in range(8)]
    await server.wait_connections(at_least=9)
    before = server.handler.served
    for client in greedy:  # 40,000 requests in all, then the poller's
        client.writer.write(b"".join(mbap(i & 0xFFFF, 1, request) for i in range(5_000)))
    assert (await poller.ask(READ))[0] == 3
    # The poller's answer waited for a turn or two of each of the others, never for their
    # whole backlogs.
    served_first = server.handler.served - before - 1
    assert served_first < 2_000, served_first
    for _ in range(20):  # and so it stays while they go on not reading
        before = server.handler.served
        assert (await poller.ask(READ))[0] == 3
        assert server.handler.served - before < 2_000
    for client in (*greedy, poller):
        client.close()
