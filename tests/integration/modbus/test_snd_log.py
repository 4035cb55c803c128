"""The SND log window (issue 10, finding 7): a poller reads what it missed, at any rate.

The layout checked here is the one `ncgate map` and the README's map table document: at
`modbus.map.snd_log` (input 200) the newest sequence number (u32), then the last 16 SNDs
newest first, six registers each: sequence (u32), sender, target, block N, id.
"""

from __future__ import annotations

import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.gateway import Gateway
from ncgate.gateway.testing.modbus_kit import VirtualPLC, VirtualPLCError


async def _read_log(client: AsyncModbusTcpClient, base: int = 200) -> list[int]:
    r = await client.read_input_registers(base, count=98, device_id=1)
    assert not r.isError(), r
    return list(r.registers)


async def test_the_window_holds_the_last_16_snds_newest_first(
        ncgate_gateway: Gateway) -> None:
    gw = ncgate_gateway
    host, port = gw.modbus_address
    client = AsyncModbusTcpClient(host, port=port, retries=0)
    assert await client.connect()
    try:
        assert await _read_log(client) == [0] * 98  # nothing sent yet
        await gw.start("BURST")  # N1..N20 each (SND,4), at one moment
        await gw.wait_idle()
        regs = await _read_log(client)
    finally:
        client.close()
    assert regs[:2] == [0, 20]
    entries = [regs[2 + 6 * j:8 + 6 * j] for j in range(16)]
    # newest first: SND #20 from N20 back to SND #5 from N5; P1 -> P4, id 0
    assert entries == [[0, seq, 1, 4, seq, 0] for seq in range(20, 4, -1)]
    sent = [(e["proc"], e["to"], e["n"]) for e in gw.trace if e["event"] == "snd"]
    assert sent == [(1, 4, n) for n in range(1, 21)]  # the trace agrees, in order


async def test_next_snd_loses_none_of_16_between_two_calls(
        ncgate_gateway: Gateway, virtual_plc: VirtualPLC) -> None:
    gw, plc = ncgate_gateway, virtual_plc
    await gw.start("BURST16")
    await gw.wait_idle()  # all 16 happened before the client reads once
    seen = [await plc.next_snd() for _ in range(16)]
    assert [(s.sender, s.target, s.n, s.seq) for s in seen] == [
        (1, 4, n, n) for n in range(1, 17)]
    assert max(s.seq for s in await plc.snd_log()) == 16  # and nothing more is there


async def test_next_snd_says_how_many_left_the_window(
        ncgate_gateway: Gateway, virtual_plc: VirtualPLC) -> None:
    gw, plc = ncgate_gateway, virtual_plc
    await gw.start("BURST")
    await gw.wait_idle()  # 20 SNDs: #1..#4 are gone before the first read
    with pytest.raises(VirtualPLCError, match=r"4 SND\(s\) after #0 .* next is #5"):
        await plc.next_snd()
    rest = [await plc.next_snd() for _ in range(16)]  # said once; the rest are all there
    assert [s.n for s in rest] == list(range(5, 21))


async def test_a_reset_does_not_restart_the_sequence(
        ncgate_gateway: Gateway, virtual_plc: VirtualPLC) -> None:
    gw, plc = ncgate_gateway, virtual_plc
    await gw.start("BURST16")
    await gw.wait_idle()
    await plc.command(3)  # reset
    await gw.start("BURST16")
    await gw.wait_idle()
    log = await plc.snd_log()
    assert [s.seq for s in log] == list(range(17, 33))  # a poller can still tell them apart
    assert [s.n for s in log] == list(range(1, 17))
