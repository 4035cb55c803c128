"""Every row of the Modbus map (spec 3.2) over real loopback TCP with the pymodbus client."""

from __future__ import annotations

import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.gateway import Gateway
from ncgate.gateway.testing.modbus_kit import VirtualPLC, VirtualPLCError
from ncgate.interpreter.engine import ProcessState


async def test_cell_runs_with_the_test_playing_plc_and_external_process(
        ncgate_gateway: Gateway, virtual_plc: VirtualPLC) -> None:
    gw, plc = ncgate_gateway, virtual_plc
    await plc.command(1)  # cycle start: MAIN into P1
    await plc.wait_state(1, "WAIT_COND")
    status = await plc.status(1)
    assert status[:6] == [int(ProcessState.WAIT_COND), 3, 3, 2, 0, 0]  # N3, line 3, cond
    await plc.wait_state(2, "WAIT_COND")
    await plc.set("SK5", 200)  # releases P2's N1
    await plc.set("SA10", 1)  # releases P1's N3
    snd = await plc.next_snd()  # #(SND,4): to the external process, after N2's motion
    assert (snd.sender, snd.target, snd.n) == (1, 4, 4)
    await plc.wait_state(1, "WAIT_PROC")
    assert (await plc.status(1))[3:5] == [1, 4]  # waits for process 4
    await plc.send(4, 1)  # the mailbox: P4 sends to P1
    await gw.wait_idle(timeout_s=20)
    assert await plc.get("SYVAR3") == -7
    trace = gw.trace
    resume = next(e for e in trace if e["event"] == "resume" and e["n"] == 5)
    assert resume["by"] == 4
    written = [(e["var"], e["value"], e["who"].split()[0]) for e in trace if e["event"] == "write"]
    assert ("SK5", 200, "modbus") in written and ("SA10", 1, "modbus") in written
    # The per-process counters: P1 sent 1, received 1; the event counter follows the trace.
    p1 = await plc.status(1)
    assert (p1[6] << 16 | p1[7], p1[8] << 16 | p1[9]) == (1, 1)
    assert await plc.event_counter() == gw.runtime.trace.counter


async def test_coils_and_sa_bytes_are_the_same_bits(ncgate_gateway: Gateway,
                                                   virtual_plc: VirtualPLC) -> None:
    client = virtual_plc.client
    r = await client.write_coils(8, [True, False, True], device_id=1)
    assert not r.isError()
    assert await virtual_plc.get("SA1.BY") == 0b101
    await virtual_plc.set("SA1.BY", 0b1000_0000)
    bits = (await client.read_coils(8, count=8, device_id=1)).bits[:8]
    assert bits == [False] * 7 + [True]
    assert ncgate_gateway.image.read("SA", 15, "bit") == 1


async def test_k_bytes_syvars_and_word_views(ncgate_gateway: Gateway,
                                            virtual_plc: VirtualPLC) -> None:
    plc = virtual_plc
    await plc.set("SK2.IN", -2)
    assert (await plc.get("SK2"), await plc.get("SK3"), await plc.get("SK2.IN")) == (254, 255, -2)
    await plc.set("SYVAR255", -32768)
    assert await plc.get("SYVAR255") == -32768
    assert ncgate_gateway.image.read("SYVAR", 255, "IN") == -32768
    with pytest.raises(VirtualPLCError, match="exception_code=3"):
        await plc.set("SK9", 256)
    assert ncgate_gateway.image.read("SK", 9, "BY") == 0  # nothing stored


async def test_gateway_info_registers(ncgate_gateway: Gateway, virtual_plc: VirtualPLC) -> None:
    info = await virtual_plc._input(0, 8)
    assert info[:2] == [1, 4]  # map version, process count
    assert info[2] << 16 | info[3] == ncgate_gateway.runtime.trace.counter


async def test_discrete_inputs_follow_the_process(ncgate_gateway: Gateway,
                                                  virtual_plc: VirtualPLC) -> None:
    client = virtual_plc.client
    await ncgate_gateway.start("LONG", process=3)
    flags = (await client.read_discrete_inputs(32, count=16, device_id=1)).bits[:16]
    # loaded, running, waiting, alarm, motion active, hold; 6..15 read 0
    assert flags[:6] == [True, True, False, False, True, False] and not any(flags[6:])
    await virtual_plc.command(2)  # feed hold
    await virtual_plc.wait_state(3, "HOLD")
    flags = (await client.read_discrete_inputs(32, count=6, device_id=1)).bits[:6]
    assert flags == [True, False, False, False, True, True]
    await virtual_plc.command(3)  # reset
    await virtual_plc.wait_state(3, "IDLE")
    assert not any((await client.read_discrete_inputs(0, count=64, device_id=1)).bits[:64])


async def test_command_and_mailbox_read_zero_and_refuse_bad_values(
        ncgate_gateway: Gateway, virtual_plc: VirtualPLC) -> None:
    assert await virtual_plc._holding(2000, 3) == [0, 0, 0]
    with pytest.raises(VirtualPLCError, match="exception_code=3"):
        await virtual_plc.command(17)  # no command 17 (16 reloads the PLC logic)
    with pytest.raises(VirtualPLCError, match="exception_code=3"):
        await virtual_plc.send(2, 1)  # P2 is not external
    with pytest.raises(VirtualPLCError, match="exception_code=4"):
        await virtual_plc.send(4, 1)  # P1 runs no program
    r = await virtual_plc.client.write_register(2001, 4, device_id=1)  # half a mailbox
    assert r.isError() and r.exception_code == 2


async def test_second_unit_id_is_served_and_others_are_not(ncgate_gateway: Gateway) -> None:
    host, port = ncgate_gateway.modbus_address
    client = AsyncModbusTcpClient(host, port=port, retries=0)
    await client.connect()
    try:
        assert not (await client.read_input_registers(0, count=2, device_id=7)).isError()
        r = await client.read_input_registers(0, count=2, device_id=3)
        assert r.isError() and r.exception_code == 0x0B
    finally:
        client.close()


MOVED = {"modbus.map": {"syvars": 3000, "status": 500, "command": 4000,
                        "read_only": ["k_bytes"]}}


@pytest.mark.parametrize("ncgate_config", [MOVED], indirect=True)
async def test_regions_move_and_become_read_only(ncgate_gateway: Gateway,
                                                 virtual_plc: VirtualPLC) -> None:
    client = virtual_plc.client
    await virtual_plc.set("SYVAR2", 1234)  # the kit follows the map in force
    assert ncgate_gateway.image.read("SYVAR", 2, "IN") == 1234
    assert (await client.read_holding_registers(3002, count=1, device_id=1)).registers == [1234]
    r = await client.read_holding_registers(1000, count=1, device_id=1)
    assert r.isError() and r.exception_code == 2  # nothing at the old place
    r = await client.write_register(5, 1, device_id=1)  # K bytes: read-only here
    assert r.isError() and r.exception_code == 2
    assert ncgate_gateway.image.read("SK", 5, "BY") == 0
    await virtual_plc.command(1)  # the command word at 4000
    await virtual_plc.wait_state(1, "WAIT_COND")  # the status blocks at 500
    assert (await client.read_input_registers(500, count=1, device_id=1)).registers == [3]
