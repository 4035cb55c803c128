"""PDOs, NMT, heartbeat and EMCY of the node (spec 3.3), seen by a master on the bus."""

from __future__ import annotations

import asyncio
import itertools
import queue
import statistics
import struct
from pathlib import Path

import canopen
import pytest

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.canopen.clock import ManualClock
from ncgate.gateway.canopen.dictionary import build_dictionary
from ncgate.gateway.cli.main import main

from .conftest import Master, u8


async def test_boot_up_then_pre_operational(gw: Gateway, master: Master) -> None:
    assert await master.next(0x710) == b"\x00"  # boot-up
    node = gw.canopen_node
    assert node is not None and node.node.nmt.state == "PRE-OPERATIONAL"


@pytest.mark.parametrize("ncgate_config", [{"canopen.nmt_autostart": True}], indirect=True)
async def test_nmt_autostart_goes_operational(gw: Gateway, master: Master) -> None:
    assert await master.next(0x710) == b"\x00"
    node = gw.canopen_node
    assert node is not None and node.node.nmt.state == "OPERATIONAL"
    assert await master.next(0x190) == bytes(4)  # TPDO1: the states as they are


async def test_pdos_flow_only_in_operational(gw: Gateway, master: Master) -> None:
    await gw.start("BAD", process=3)  # a state change while PRE-OPERATIONAL: no TPDO
    master.network.send_message(0x210, bytes(range(1, 9)))  # RPDO1: ignored
    assert await master.upload(0x2000, 1) == u8(0)
    with pytest.raises(queue.Empty):
        master.frames[0x190].get(timeout=0.3)
    master.nmt(0x01)  # start
    assert await master.next(0x190) == bytes((0, 0, 8, 0))  # current states on entry
    master.network.send_message(0x210, bytes(range(1, 9)))  # RPDO1 -> SA bytes 0..7
    master.network.send_message(0x310, bytes(range(11, 19)))  # RPDO2 -> K bytes 0..7
    assert await master.upload(0x2100, 8) == u8(18)  # both landed (SDO after the PDOs)
    assert bytes(gw.image.sa[:8]) == bytes(range(1, 9))
    assert bytes(gw.image.k[:8]) == bytes(range(11, 19))
    who = {e["who"] for e in gw.trace if e["event"] == "write"}
    assert who == {"canopen RPDO1 0x210", "canopen RPDO2 0x310"}
    master.nmt(0x80)  # back to pre-operational: no more PDOs
    await master.upload(0x1000, 0)  # the NMT command has been handled by now
    master.network.send_message(0x210, bytes(8))
    assert await master.upload(0x2000, 1) == u8(1)


async def test_tpdo1_on_every_state_change_and_tpdo2_on_every_snd(gw: Gateway,
                                                                  master: Master) -> None:
    master.nmt(0x01)
    assert await master.next(0x190) == bytes(4)
    gw.command(1)  # cycle start: MAIN
    await gw.wait_state(1, "WAIT_COND", timeout_s=5)
    gw.write("SK5", 200)
    gw.write("SA10", 1)
    await gw.wait_state(1, "WAIT_PROC", timeout_s=5)
    gw.send(4, 1)
    await gw.wait_idle(timeout_s=5)
    # Every state change of P1..P4, in order, until all are IDLE again.
    seen = await master.until(0x190, bytes(4))
    states = [s[0] for s in seen]
    assert states[0] == 1 and states[-1] == 0  # RUNNING first, IDLE at the end
    assert 3 in states and 2 in states  # WAIT_COND, WAIT_PROC on the way
    assert all(a != b for a, b in itertools.pairwise(seen))  # only changes
    # TPDO2: one per SND, in order: P1 -> P4 (N3), then the mailbox P4 -> P1.
    first, second = await master.next(0x290), await master.next(0x290)
    n1, s1, t1, b1 = struct.unpack("<LBBH", first)
    n2, s2, t2, b2 = struct.unpack("<LBBH", second)
    assert (s1, t1, b1) == (1, 4, 3) and (s2, t2, b2) == (4, 1, 0) and n2 > n1
    assert sum(1 for e in gw.trace if e["event"] == "snd") == 2  # one TPDO2 per SND


async def test_tpdo2_inhibit_time_spaces_the_snds(clocked: Gateway, master: Master,
                                                  clock: ManualClock) -> None:
    gw = clocked
    await master.while_disabled(0x1801, 3, struct.pack("<H", 500))  # 50 ms
    master.nmt(0x01)
    await master.next(0x190)  # the node is OPERATIONAL: it sent its states
    gw.command(1)
    await gw.wait_state(1, "WAIT_COND", timeout_s=5)
    gw.write("SK5", 200)
    gw.write("SA10", 1)
    await gw.wait_state(1, "WAIT_PROC", timeout_s=5)
    gw.send(4, 1)
    await master.next(0x290)
    await master.barrier()
    # the second SND came right after the first: its frame waits for the inhibit time
    assert master.frames[0x290].empty()
    clock.advance(0.049)
    await master.barrier()
    assert master.frames[0x290].empty()
    clock.advance(0.001)
    await master.next(0x290)


async def test_emcy_on_alarm_and_on_reset(gw: Gateway, master: Master) -> None:
    await gw.start("BAD", process=3)  # AL101 in P3
    emcy = await master.next(0x90)
    code, register, data = struct.unpack("<HB5s", emcy)
    assert (code, register, data[0], int.from_bytes(data[1:3], "little")) == (0x6200, 1, 3, 101)
    gw.command(3)  # reset
    code, register, _ = struct.unpack("<HB5s", await master.next(0x90))
    assert (code, register) == (0, 0)
    assert await master.upload(0x1001, 0) == u8(0)


async def test_no_sdo_in_stopped_and_reset_communication(gw: Gateway, master: Master) -> None:
    assert await master.next(0x710) == b"\x00"
    await master.download(0x1017, 0, struct.pack("<H", 250))
    master.nmt(0x02)  # stop
    with pytest.raises(canopen.SdoCommunicationError):
        await asyncio.to_thread(master.node.sdo.upload, 0x1000, 0)
    master.nmt(0x82)  # reset communication: boot-up, pre-operational, defaults back
    await master.until(0x710, b"\x00")  # heartbeats (0x1017 = 250 ms) until the boot-up
    assert await master.upload(0x1017, 0) == struct.pack("<H", 0)  # the cell's default
    node = gw.canopen_node
    assert node is not None and node.node.nmt.state == "PRE-OPERATIONAL"


@pytest.mark.parametrize("ncgate_config", [{"canopen.heartbeat_ms": 50}], indirect=True)
async def test_heartbeat_producer(gw: Gateway, master: Master) -> None:
    assert await master.next(0x710) == b"\x00"  # boot-up first
    beats = []
    for _ in range(8):
        beats.append((await master.next(0x710), asyncio.get_running_loop().time()))
    assert {b for b, _ in beats} == {bytes((127,))}  # PRE-OPERATIONAL
    gaps = [b[1] - a[1] for a, b in itertools.pairwise(beats)]
    # The period of 0x1017 (50 ms); generous bounds: this is a shared 2-core machine.
    assert 0.025 <= statistics.median(gaps) <= 0.1
    await master.download(0x1017, 0, struct.pack("<H", 0))  # 0 stops the producer
    node = gw.canopen_node
    assert node is not None and node.node.nmt._send_task is None


def test_eds_round_trip(tmp_path: Path, ncgate_config: Config) -> None:
    out = tmp_path / "node.eds"
    cfg_file = tmp_path / "cfg.toml"
    cfg_file.write_text("[nc]\nprocesses = 3\n[plc]\nk_bytes = 300\nsyvars = 130\n")
    assert main(["eds", "--config", str(cfg_file), "-o", str(out)]) == 0
    from ncgate.config import load_config

    ours = build_dictionary(load_config(cfg_file))
    theirs = canopen.import_od(str(out), 16)
    # canopen adds the dummy types the EDS's [DummyUsage] declares (those RPDOs map)
    assert sorted(theirs) == [2, 3, 4, 5, 6, 7, *sorted(ours)]

    def described(obj: object) -> list[tuple[object, ...]]:
        members = [obj] if isinstance(obj, canopen.objectdictionary.ODVariable) else [
            obj[s] for s in sorted(obj.subindices)]  # type: ignore[attr-defined]
        return [(m.index, m.subindex, m.name, m.data_type, m.access_type, m.default)
                for m in members]

    for index in ours:
        assert described(theirs[index]) == described(ours[index]), hex(index)
    assert 0x2102 in theirs and len(theirs[0x2102].subindices) == 1 + 300 - 256


def test_eds_to_standard_output_is_the_same_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """`ncgate eds -o -` wrote a file named "-" (a hostile try): "-" is standard output, as
    for the tools it is piped into; the EDS is the file's, its FileName ncgate.eds."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")  # (the same dates in both)
    assert main(["eds", "-o", "-"]) == 0
    piped = capsys.readouterr().out
    assert not (tmp_path / "-").exists()
    assert main(["eds", "-o", "ncgate.eds"]) == 0
    assert piped == (tmp_path / "ncgate.eds").read_text(encoding="utf-8")
    assert "FileName=ncgate.eds" in piped


async def test_reset_node_boots_again_in_pre_operational(gw: Gateway, master: Master) -> None:
    assert await master.next(0x710) == b"\x00"
    master.nmt(0x01)
    assert await master.next(0x190) == bytes(4)
    await master.while_disabled(0x1800, 3, struct.pack("<H", 30))
    assert await master.next(0x190) == bytes(4)  # enabled again: where things stand
    master.nmt(0x81)  # reset node
    assert await master.next(0x710) == b"\x00"  # boot-up again
    node = gw.canopen_node
    assert node is not None and node.node.nmt.state == "PRE-OPERATIONAL"
    assert await master.upload(0x1800, 3) == struct.pack("<H", 0)  # default inhibit time
    await gw.start("BAD", process=3)  # a state change: no TPDO1 in PRE-OPERATIONAL ...
    assert (await master.upload(0x2502, 1)) == u8(8)
    assert master.frames[0x190].empty()  # ... and the SDO answer came after the change


@pytest.mark.parametrize("ncgate_config", [{"nc.dialect": "isg"}], indirect=True)
async def test_tpdo2_on_every_isg_signal(gw: Gateway, master: Master, cell: Path) -> None:
    """Spec 5.6: a signal counts like an SND -- TPDO2 carries the sender, the first channel
    it is addressed to (0 for a broadcast) and N."""
    (cell / "SIGS.nc").write_text("%channel1\nN7 #SIGNAL [ID9 CH2 CH3]\nN8 #SIGNAL [ID10]\n"
                                  "N9 M30\n", encoding="utf-8")
    master.nmt(0x01)
    assert await master.next(0x190) == bytes(4)
    await gw.start("SIGS", process=1)
    await gw.wait_idle(timeout_s=5)
    first, second = await master.next(0x290), await master.next(0x290)
    n1, s1, t1, b1 = struct.unpack("<LBBH", first)
    n2, s2, t2, b2 = struct.unpack("<LBBH", second)
    assert (s1, t1, b1) == (1, 2, 7) and (s2, t2, b2) == (1, 0, 8) and n2 > n1
    with pytest.raises(queue.Empty):  # one TPDO2 per #SIGNAL, not one per channel
        master.frames[0x290].get(timeout=0.3)
