"""The plant's CANopen faults (docs/plant.md), as a canopen master on the virtual bus sees
them: the heartbeat stops and comes back, an EMCY with the fault's code and its end, the
TPDOs silenced and back."""

from __future__ import annotations

import struct

import pytest

from ncgate.gateway import Gateway

from .conftest import Master


@pytest.mark.parametrize("ncgate_config", [{"canopen.heartbeat_ms": 20}], indirect=True)
async def test_heartbeat_stop_silences_the_producer_until_cleared(gw: Gateway,
                                                                  master: Master) -> None:
    assert await master.next(0x710) == b"\x00"  # boot-up
    assert await master.next(0x710) == bytes((127,))  # a heartbeat
    gw.fault("canopen", "heartbeat_stop")
    node = gw.canopen_node
    assert node is not None and node.node.nmt._send_task is None
    from ncgate.gateway.web.status import fieldbus

    assert fieldbus(gw)["canopen"]["faults"] == ["heartbeat_stop"]  # heartbeat_ms: as set
    while not master.frames[0x710].empty():  # what was on its way before the fault
        master.frames[0x710].get_nowait()
    await master.barrier()  # the node answered a request: time passed, no heartbeat came
    assert master.frames[0x710].empty()
    gw.clear_fault("canopen")
    assert await master.next(0x710) == bytes((127,))


@pytest.mark.parametrize("ncgate_config", [{"canopen.heartbeat_ms": 20}], indirect=True)
@pytest.mark.parametrize("how", ["write 0x1017", "reset communication", "reset node"])
async def test_a_master_does_not_start_a_stopped_heartbeat_while_the_fault_is_in_force(
        gw: Gateway, master: Master, how: str) -> None:
    """A master's configuration writes 0x1017 or resets the node: canopen's NMT slave
    started its producer again with either, the fault still in force."""
    assert await master.next(0x710) == b"\x00"  # boot-up
    gw.fault("canopen", "heartbeat_stop")
    if how == "write 0x1017":
        await master.download(0x1017, 0, struct.pack("<H", 10))
    else:
        master.nmt(0x82 if how == "reset communication" else 0x81)
        await master.until(0x710, b"\x00")  # its boot-up message still goes
    node = gw.canopen_node
    assert node is not None
    await master.barrier()
    assert node.node.nmt._send_task is None  # no producer running
    while not master.frames[0x710].empty():  # what was on its way before the fault
        master.frames[0x710].get_nowait()
    for _ in range(3):
        await master.barrier()
    assert master.frames[0x710].empty()
    gw.clear_fault("canopen")
    assert (await master.next(0x710))[0] in (0x7F, 0x05)  # beating again


async def test_an_emcy_fault_raises_its_code_and_its_clear_ends_it(gw: Gateway,
                                                                   master: Master) -> None:
    gw.fault("canopen", "emcy", code=0x3120)
    code, register, _ = struct.unpack("<HB5s", await master.next(0x90))
    assert code == 0x3120 and register & 1
    history = await master.upload(0x1003, 1)
    assert int.from_bytes(history, "little") & 0xFFFF == 0x3120
    gw.clear_fault("canopen")
    code, register, _ = struct.unpack("<HB5s", await master.next(0x90))
    # The end of the error, with the register as it is now: nothing left (it said 0x01).
    assert (code, register) == (0, 0)
    assert await master.upload(0x1001, 0) == b"\x00"


async def test_pdo_stop_silences_the_tpdos_until_cleared(gw: Gateway, master: Master) -> None:
    assert await master.next(0x710) == b"\x00"
    master.nmt(0x01)  # operational: TPDO1 (the process states) says where things stand
    assert await master.next(0x190) == bytes(4)
    gw.fault("canopen", "pdo_stop")
    await gw.start("MAIN")  # P1 runs, starts P2, waits: state changes TPDO1 would carry
    await gw.wait_state(1, "WAIT_COND")
    await master.barrier()
    assert master.frames[0x190].empty()
    gw.clear_fault("canopen")
    gw.write("SA10", 1)  # P1 goes on: TPDO1 again, with the states as they are
    frame = await master.next(0x190)
    assert frame != bytes(4)


@pytest.mark.parametrize("ncgate_config", [{"nc.cycle_start_inhibit_input": "SA100"}],
                         indirect=True)
async def test_an_interlocked_cycle_start_on_0x2400_is_refused_in_the_sdo_answer(
        gw: Gateway, master: Master) -> None:
    """The CANopen door decides what does not depend on the program before it answers, as
    Modbus and the console do: the cycle start against a set interlock is abort 0x08000022
    and nothing starts."""
    import canopen

    from ncgate.errors import Reason
    from ncgate.gateway.canopen.codes import REFUSAL

    gw.write("SA100", 1)
    with pytest.raises(canopen.SdoAbortedError) as caught:
        await master.download(0x2400, 1, struct.pack("<H", 0x0101))
    assert caught.value.code == REFUSAL[Reason.INTERLOCK] == 0x08000022
    gw.write("SA100", 0)
    await master.download(0x2400, 1, struct.pack("<H", 0x0101))  # now taken
    await gw.wait_state(1, "WAIT_COND")


async def test_a_second_emcy_fault_replaces_the_first(gw: Gateway, master: Master) -> None:
    """Two EMCY faults of other codes were both listed while the node raised the newer one;
    when it ended, the older came back (EMCY 0x0000, then its code again)."""
    gw.fault("canopen", "emcy", code=0x3120)
    assert struct.unpack("<H", (await master.next(0x90))[:2]) == (0x3120,)
    gw.fault("canopen", "emcy", code=0x4210)
    assert [f["kind"] for f in gw.plant.status()["faults"]] == ["emcy"]  # type: ignore[union-attr]
    codes = [struct.unpack("<H", (await master.next(0x90))[:2])[0] for _ in range(2)]
    assert codes == [0, 0x4210]
    clear = [e for e in gw.trace if e["event"] == "fault_clear"]
    assert [(e["target"], e["kind"]) for e in clear] == [("canopen", "emcy")]
    gw.clear_fault("canopen")
    assert struct.unpack("<H", (await master.next(0x90))[:2]) == (0,)
    await master.barrier()
    assert master.frames[0x90].empty()  # nothing raised again
