"""Connection hygiene (spec 3.2): client limit, idle and half-open connections, concurrency."""

from __future__ import annotations

import asyncio

import pytest
from pymodbus.client import AsyncModbusTcpClient

import ncgate.gateway.modbus.server as modbus_server
from ncgate.gateway import Gateway

from .rawclient import Raw, mbap, pdu

GOOD = pdu(4, "HH", 0, 1)


@pytest.mark.parametrize("ncgate_config", [{"modbus.max_clients": 3}], indirect=True)
async def test_connections_beyond_max_clients_are_refused_at_once(
        ncgate_gateway: Gateway) -> None:
    address = ncgate_gateway.modbus_address
    clients = [await Raw.open(*address) for _ in range(3)]
    for c in clients:
        assert (await c.ask(GOOD))[0] == 4
    extra = await Raw.open(*address)
    assert await extra.closed_by_peer(timeout_s=2.0)
    clients[0].close()
    server = ncgate_gateway.modbus_server
    assert server is not None
    # once one leaves, a newcomer is served
    async with asyncio.timeout(5):
        await server.wait_connections(2)
    newcomer = await Raw.open(*address)
    assert (await newcomer.ask(GOOD))[0] == 4
    for c in (*clients[1:], newcomer):
        c.close()


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
