"""What a master configures (issue 11, items 8 and 9): SYNC and the transmission types, the
event timer, dynamic PDO mapping -- with a canopen master on the virtual bus, the timers on
a clock the test moves (never slept for)."""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path

import canopen
import pytest

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.canopen.clock import ManualClock, Timer
from ncgate.gateway.canopen.dictionary import write_eds

from .conftest import Master, sdo_error, u8, u32

TPDO1, TPDO3, TPDO4 = 0x190, 0x390, 0x490


async def set_type(master: Master, comm: int, ttype: int) -> None:
    cob = await master.upload(comm, 1)
    await master.download(comm, 1, u32(int.from_bytes(cob, "little") | 0x80000000))
    await master.download(comm, 2, u8(ttype))
    await master.download(comm, 1, cob)


async def operational(master: Master) -> None:
    master.nmt(0x01)
    await master.barrier()


async def p1_waits_for_sa10(gw: Gateway) -> None:
    gw.command(1)  # MAIN: EXE 2 SIDE, then waits for SA10
    await gw.wait_state(1, "WAIT_COND", timeout_s=5)
    await gw.wait_state(2, "WAIT_COND", timeout_s=5)


# -- 8. SYNC and the transmission types --------------------------------------------------------

async def test_type_1_sends_on_every_sync_and_not_on_change(gw: Gateway, master: Master) -> None:
    await set_type(master, 0x1800, 1)
    await operational(master)
    await p1_waits_for_sa10(gw)
    await master.barrier()
    assert master.frames[TPDO1].empty()  # changes alone send nothing
    for _ in range(3):
        master.sync()
        assert await master.next(TPDO1) == bytes((3, 3, 0, 0))  # P1, P2 wait for conditions
    await master.barrier()
    assert master.frames[TPDO1].empty()  # one frame per SYNC


async def test_type_3_sends_on_every_third_sync(gw: Gateway, master: Master) -> None:
    await set_type(master, 0x1800, 3)
    await operational(master)
    for _ in range(2):
        for _ in range(2):
            master.sync()
        await master.barrier()
        assert master.frames[TPDO1].empty()
        master.sync()
        assert await master.next(TPDO1) == bytes(4)


async def test_type_0_sends_at_the_sync_after_a_change(gw: Gateway, master: Master) -> None:
    await set_type(master, 0x1800, 0)
    await operational(master)
    master.sync()
    await master.barrier()
    assert master.frames[TPDO1].empty()  # no change yet
    await p1_waits_for_sa10(gw)
    await master.barrier()
    assert master.frames[TPDO1].empty()  # a change: sent at the next SYNC, not now
    master.sync()
    assert await master.next(TPDO1) == bytes((3, 3, 0, 0))
    master.sync()
    await master.barrier()
    assert master.frames[TPDO1].empty()  # nothing changed since


async def test_sync_start_value_waits_for_the_sync_counter(gw: Gateway, master: Master) -> None:
    await set_type(master, 0x1800, 2)
    await master.while_disabled(0x1800, 6, u8(5))
    await operational(master)
    sent_at = []
    for counter in range(1, 11):
        master.sync(counter)
        await master.barrier()
        if not master.frames[TPDO1].empty():
            master.frames[TPDO1].get_nowait()
            sent_at.append(counter)
    assert sent_at == [5, 7, 9]


async def test_synchronous_rpdo_is_applied_at_the_next_sync(gw: Gateway, master: Master) -> None:
    await set_type(master, 0x1400, 1)
    await operational(master)
    master.network.send_message(0x210, bytes((0x2A,)) + bytes(7))
    await master.barrier()
    assert gw.read("SA0.BY") == 0  # received, not applied
    master.network.send_message(0x210, bytes((0x07,)) + bytes(7))  # the last one counts
    await master.barrier()
    master.sync()
    await master.barrier()
    assert gw.read("SA0.BY") == 0x07
    writes = [e for e in gw.trace if e["event"] == "write" and e["var"].startswith("SA")]
    assert {e["who"] for e in writes} == {"canopen RPDO1 0x210"}


async def test_sync_cob_id_moves(gw: Gateway, master: Master) -> None:
    await set_type(master, 0x1800, 1)
    await master.download(0x1005, 0, u32(0x85))
    await operational(master)
    master.sync()  # on 0x80: no longer the SYNC
    await master.barrier()
    assert master.frames[TPDO1].empty()
    master.sync(cob=0x85)
    assert await master.next(TPDO1) == bytes(4)
    # the node produces no SYNC (bit 30), 11-bit identifiers only (bit 29)
    for bad in (0x40000080, 0x20000080):
        assert await sdo_error(master.download(0x1005, 0, u32(bad))) == 0x06090030
    assert await master.upload(0x1005, 0) == u32(0x85)


@pytest.mark.parametrize("ttype", [241, 251, 252, 253])
async def test_types_the_node_cannot_honour_are_refused(gw: Gateway, master: Master,
                                                        ttype: int) -> None:
    for comm in (0x1400, 0x1800):
        cob = await master.upload(comm, 1)
        await master.download(comm, 1, u32(int.from_bytes(cob, "little") | 0x80000000))
        assert await sdo_error(master.download(comm, 2, u8(ttype))) == 0x06090030
        assert await master.upload(comm, 2) == u8(255)  # nothing stored


async def test_event_timer_sends_without_change(clocked: Gateway, master: Master,
                                                clock: ManualClock) -> None:
    await master.while_disabled(0x1800, 5, struct.pack("<H", 100))  # 100 ms
    await operational(master)
    assert await master.next(TPDO1) == bytes(4)  # entering OPERATIONAL: where things stand
    clock.advance(0.099)
    await master.barrier()
    assert master.frames[TPDO1].empty()
    clock.advance(0.001)
    assert await master.next(TPDO1) == bytes(4)  # 100 ms, nothing changed: sent anyway
    clock.advance(0.05)
    await p1_waits_for_sa10(clocked)
    await master.until(TPDO1, bytes((3, 3, 0, 0)))  # on change ...
    clock.advance(0.099)
    await master.barrier()
    assert master.frames[TPDO1].empty()  # ... which restarted the timer
    clock.advance(0.001)
    assert await master.next(TPDO1) == bytes((3, 3, 0, 0))


async def test_inhibit_time_on_the_injected_clock(clocked: Gateway, master: Master,
                                                  clock: ManualClock) -> None:
    await master.while_disabled(0x1800, 3, struct.pack("<H", 100))  # 10 ms
    await operational(master)
    assert await master.next(TPDO1) == bytes(4)
    await p1_waits_for_sa10(clocked)  # two changes at once: P1 runs, then both wait
    await master.barrier()
    assert master.frames[TPDO1].empty()  # within 10 ms of the last frame
    clock.advance(0.01)
    assert await master.next(TPDO1) == bytes((3, 3, 0, 0))  # the latest states, once
    await master.barrier()
    assert master.frames[TPDO1].empty()


# -- 9. dynamic mapping --------------------------------------------------------------------------

async def test_master_maps_tpdo3_with_read_edit_save(gw: Gateway, master: Master) -> None:
    tpdo = master.node.tpdo
    await _to_thread(tpdo.read)
    assert not tpdo[3].enabled and len(tpdo[3].map) == 0
    tpdo[3].clear()
    tpdo[3].add_variable(0x2000, 2)  # SA byte 1 (SA8..15)
    tpdo[3].add_variable(0x2200, 3)  # SYVAR 2 (INTEGER16)
    tpdo[3].add_variable(0x2500, 1)  # process 1 state
    tpdo[3].add_variable(0x2600, 2)  # last SND sender
    tpdo[3].trans_type = 254
    tpdo[3].enabled = True
    await _to_thread(tpdo[3].save)
    master.listen(TPDO3)
    await operational(master)
    assert await master.next(TPDO3) == bytes(5)
    gw.write("SA10", 1)
    assert await master.next(TPDO3) == bytes((0x04, 0, 0, 0, 0))
    gw.write("SYVAR2", -2)
    assert await master.next(TPDO3) == bytes((0x04,)) + struct.pack("<h", -2) + bytes(2)
    # the mapping as the master reads it back
    fresh = canopen.RemoteNode(master.node_id, master.node.object_dictionary)
    master.network.add_node(fresh)
    await _to_thread(fresh.tpdo.read)
    assert [(v.index, v.subindex, v.length) for v in fresh.tpdo[3].map] == [
        (0x2000, 2, 8), (0x2200, 3, 16), (0x2500, 1, 8), (0x2600, 2, 8)]
    assert fresh.tpdo[3].trans_type == 254 and fresh.tpdo[3].enabled


async def test_rpdo3_with_a_syvar_and_a_dummy(gw: Gateway, master: Master) -> None:
    await master.download(0x1402, 2, u8(255))
    await master.download(0x1602, 0, u8(0))
    await master.download(0x1602, 1, u32(0x22000110))  # SYVAR 0
    await master.download(0x1602, 2, u32(0x00050008))  # dummy UNSIGNED8: a byte skipped
    await master.download(0x1602, 3, u32(0x20000308))  # SA byte 2
    await master.download(0x1602, 0, u8(3))
    await master.download(0x1402, 1, u32(0x410))  # RPDO3 on, default COB-ID 0x400+16
    await operational(master)
    master.network.send_message(0x410, struct.pack("<hBB", -300, 0xEE, 0x81))
    await master.barrier()
    assert (gw.read("SYVAR0"), gw.read("SA2.BY")) == (-300, 0x81)
    assert gw.read("SA1.BY") == 0  # the dummy's byte went nowhere
    master.network.send_message(0x410, bytes(3))  # shorter than its 4 mapped bytes
    await master.barrier()
    assert gw.read("SYVAR0") == -300  # ignored


async def test_mapping_only_while_disabled_and_count_0(gw: Gateway, master: Master) -> None:
    # TPDO1 is valid: no change to its mapping
    assert await sdo_error(master.download(0x1A00, 0, u8(0))) == 0x06010000
    assert await sdo_error(master.download(0x1A00, 1, u32(0x20000108))) == 0x06010000
    await master.download(0x1800, 1, u32(0xC0000190))  # disabled; count still 4
    assert await sdo_error(master.download(0x1A00, 1, u32(0x20000108))) == 0x06010000
    assert await master.upload(0x1A00, 1) == u32(0x25000108)  # nothing stored
    await master.download(0x1A00, 0, u8(0))
    bad = {
        0x10180108: "identity: not mappable",
        0x24000110: "the command word: not mappable",
        0x20000110: "an SA byte is 8 bits, not 16",
        0x20FF0108: "no such sub-index",
        0x30000008: "no such object",
        0x00050008: "a dummy in a TPDO",
    }
    for entry in bad:
        assert await sdo_error(master.download(0x1A00, 1, u32(entry))) == 0x06040041, bad[entry]
    assert await sdo_error(master.download(0x1A00, 0, u8(9))) == 0x06040042  # > 8 objects
    for sub in (1, 2, 3):  # three U32: 96 bits
        await master.download(0x1A00, sub, u32(0x25000720))
    assert await sdo_error(master.download(0x1A00, 0, u8(3))) == 0x06040042
    assert await master.upload(0x1A00, 0) == u8(0)
    await master.download(0x1A00, 0, u8(2))  # 64 bits: fine
    # a status object into an RPDO: read-only, not mappable there
    await master.download(0x1400, 1, u32(0x80000210))
    await master.download(0x1600, 0, u8(0))
    assert await sdo_error(master.download(0x1600, 1, u32(0x25000108))) == 0x06040041


async def test_inhibit_time_and_sync_start_only_while_disabled(gw: Gateway,
                                                               master: Master) -> None:
    for sub, data in ((3, struct.pack("<H", 10)), (6, u8(3))):
        assert await sdo_error(master.download(0x1800, sub, data)) == 0x06090030
    await master.download(0x1800, 5, struct.pack("<H", 10))  # the event timer: any time


def test_eds_tells_what_can_be_mapped(tmp_path: Path, ncgate_config: Config) -> None:
    path = tmp_path / "node.eds"
    write_eds(ncgate_config, str(path))
    od = canopen.import_od(str(path), ncgate_config.canopen.node_id)
    text = path.read_text()
    assert "Granularity=8" in text and "NrOfRXPDO=4" in text and "NrOfTXPDO=4" in text
    for index in od:
        obj = od[index]
        members = [obj] if isinstance(obj, canopen.objectdictionary.ODVariable) else [
            obj[s] for s in obj.subindices if s]
        for m in members:
            image_or_status = 0x2000 <= index < 0x2400 or 0x2500 <= index <= 0x2700
            assert m.pdo_mappable == image_or_status, (hex(index), m.subindex)
    for key in ("FileName", "FileVersion", "FileRevision", "EDSVersion", "Description",
                "CreationTime", "CreationDate", "CreatedBy", "ModificationTime",
                "ModificationDate", "ModifiedBy", "VendorName", "VendorNumber", "ProductName",
                "ProductNumber", "RevisionNumber", "OrderCode", "SimpleBootUpMaster",
                "SimpleBootUpSlave", "DynamicChannelsSupported", "GroupMessaging",
                "LSS_Supported", "BaudRate_500"):
        assert f"\n{key}=" in text, key
    assert "DefaultValue=$NODEID+0x40000180" in text  # TPDO1, relative to the node id
    assert "DefaultValue=$NODEID+0x80000400" in text  # RPDO3, disabled


async def _to_thread(fn: object) -> None:
    import asyncio

    await asyncio.to_thread(fn)  # type: ignore[arg-type]


class CoarseClock(ManualClock):
    """A loop clock like uvloop's: a timer of a millisecond or more may fire up to half a
    millisecond early (its timers have a millisecond's resolution); time itself is exact."""

    def call_later(self, delay_s: float, fn: Callable[[], None]) -> Timer:
        return super().call_later(delay_s - 0.0005 if delay_s >= 0.001 else delay_s, fn)


@pytest.mark.parametrize("clock", [CoarseClock()], indirect=False)
async def test_inhibit_time_is_kept_on_a_coarse_loop_clock(clocked: Gateway, master: Master,
                                                           clock: ManualClock) -> None:
    await master.while_disabled(0x1800, 3, struct.pack("<H", 20))  # 2 ms
    await operational(master)
    assert await master.next(TPDO1) == bytes(4)
    await p1_waits_for_sa10(clocked)
    await master.barrier()
    clock.advance(0.0015)  # the 2 ms timer fires here, early
    await master.barrier()
    assert master.frames[TPDO1].empty()  # not before the inhibit time is over
    clock.advance(0.0005)
    assert await master.next(TPDO1) == bytes((3, 3, 0, 0))


async def test_the_status_says_how_late_the_node_answered_its_syncs(
        gw: Gateway, master: Master) -> None:
    """The console's fieldbus status keeps the node's own SYNC record: SYNCs answered, the
    longest time from a SYNC's arrival to its TPDO sent, and how many took longer than each
    bound.  A SYNC that waits behind a frame whose handling holds the receive thread 30 ms is
    answered at least that late (a lower bound the hold guarantees: no time limit asserted)."""
    import time

    from ncgate.gateway.web.status import fieldbus

    await set_type(master, 0x1800, 1)
    await operational(master)
    held = 0x7E0  # no object's COB-ID: a frame only this test listens to, on the node's side
    gw.canopen_node.network.subscribe(held, lambda *_: time.sleep(0.03))
    for _ in range(2):
        master.sync()
        await master.next(TPDO1)
    master.network.send_message(held, b"")
    master.sync()  # queued behind the held frame
    await master.next(TPDO1)
    await master.barrier()
    sync = fieldbus(gw)["canopen"]["sync"]
    assert sync["answered"] == 3
    assert sync["latency_max_ms"] >= 30
    later = sync["later_than_ms"]
    assert list(later) == ["1", "2", "5", "10", "20", "50"]
    assert later["20"] >= 1 and later["10"] >= 1
    counts = list(later.values())
    assert counts == sorted(counts, reverse=True) and counts[0] <= 3
    assert sync["tpdos_dropped"] == 0 and sync["rpdos_late"] == 0
    # A SYNC frame without a time stamp (an interface that gives none) is counted all the
    # same, its latency unknown (it was not counted before).
    gw.canopen_node.network.notify(0x80, bytearray(), 0.0)
    await master.next(TPDO1)
    assert fieldbus(gw)["canopen"]["sync"]["answered"] == 4
