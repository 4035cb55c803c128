"""What a real master hit (issue 11, defects 1-7 and the COB-ID rules of 10), each against
CiA 301, with a canopen master and raw frames on the virtual bus."""

from __future__ import annotations

import asyncio
import struct
import threading
from pathlib import Path

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.canopen.clock import ManualClock

from .conftest import Master, abort_code, i16, sdo_error, u8

SDO_ANSWER = 0x590


async def rpdo1_lands(master: Master, cob: int, value: int) -> bool:
    """Send RPDO1 on ``cob``; True when SA byte 0 took the value (the SDO read after it
    waits until the node has handled the frame)."""
    master.network.send_message(cob, bytes((value,)) + bytes(7))
    return await master.upload(0x2000, 1) == u8(value)


# -- 1. disabling and re-enabling an RPDO, as every DCF download does ---------------------------

async def test_rpdo_disable_enable_and_move_take_effect_every_time(gw: Gateway,
                                                                   master: Master) -> None:
    master.nmt(0x01)
    for i in range(1, 11):
        await master.download(0x1400, 1, struct.pack("<L", 0x80000210))  # disable
        assert not await rpdo1_lands(master, 0x210, 100 + i)
        await master.download(0x1400, 1, struct.pack("<L", 0x210))  # enable again
        assert await rpdo1_lands(master, 0x210, i)
    # a new COB-ID: off, move, on -- in effect when the answer comes
    for i, cob in enumerate((0x220, 0x230, 0x210), start=1):
        await master.download(0x1400, 1, struct.pack("<L", 0x80000000 | cob))
        await master.download(0x1400, 1, struct.pack("<L", cob))
        assert await rpdo1_lands(master, cob, 50 + i)
        assert not await rpdo1_lands(master, 0x240, 99)  # elsewhere: nothing


# -- 2. a toggle-bit error ends the transfer ----------------------------------------------------

async def test_toggle_error_aborts_once_and_closes_the_transfer(gw: Gateway,
                                                                master: Master) -> None:
    assert (await master.raw_sdo(struct.pack("<BHBL", 0x21, 0x2200, 1, 2)))[0] == 0x60
    answer = await master.raw_sdo(bytes((0x10 | 0x0B, 0x34, 0x12)) + bytes(5))  # toggle 1
    assert abort_code(answer) == 0x05030000
    assert answer[1:4] == bytes((0x00, 0x22, 0x01))  # names the transfer's object
    sdo = gw.canopen_node.node.sdo  # type: ignore[union-attr]
    assert sdo._mode is None and sdo._timer is None  # closed: no abort will follow
    # the next segment is no continuation, and the aborted data was never written
    assert abort_code(await master.raw_sdo(bytes((0x0B, 0x34, 0x12)) + bytes(5))) == 0x05040001
    assert gw.image.read("SYVAR", 0, "IN") == 0


# -- 3. an upload segment with no upload open ---------------------------------------------------

async def test_upload_segment_without_an_upload_is_0x05040001(gw: Gateway,
                                                              master: Master) -> None:
    assert abort_code(await master.raw_sdo(bytes((0x60,)) + bytes(7))) == 0x05040001
    await master.download(0x2200, 1, i16(-3), force_segment=True)
    answer = await master.raw_sdo(bytes((0x60,)) + bytes(7))  # not that download's bytes
    assert abort_code(answer) == 0x05040001


# -- 4. a VAR has sub-index 0 only -----------------------------------------------------------

async def test_var_objects_have_only_sub_index_0(gw: Gateway, master: Master) -> None:
    before = await master.upload(0x1017, 0)
    assert await sdo_error(master.download(0x1017, 3, struct.pack("<H", 77))) == 0x06090011
    assert await sdo_error(master.upload(0x1017, 1)) == 0x06090011
    assert await master.upload(0x1017, 0) == before


# -- 5. a long command is answered at once ----------------------------------------------------

@pytest.mark.parametrize("ncgate_config", [{"nc.main": "LONG"}], indirect=True)
async def test_cycle_start_of_a_long_main_is_answered_before_it_starts(
        gw: Gateway, master: Master, cell: Path) -> None:
    # 30,000 blocks: parsing them takes the loop a while, as a 300,000-line main did 3.5 s.
    (cell / "LONG.nc").write_text("".join(f"N{n}G1X{n % 100}F6000\n"
                                          for n in range(1, 30_001)) + "M30\n")
    answered = threading.Event()  # set on the master's thread when the answer arrives
    master.network.subscribe(SDO_ANSWER, lambda *_: answered.set())
    order: list[str] = []
    gw.runtime.trace.subscribe(
        lambda e: order.append("answered first" if answered.is_set() else "started first")
        if e.kind == "start" else None)
    await master.download(0x2400, 1, struct.pack("<H", 1))  # cycle start: no abort
    await gw.wait_state(1, "RUNNING", timeout_s=20)
    assert order == ["answered first"]


# -- 6. STOPPED: no EMCY, no SDO timeout abort ---------------------------------------------------

async def test_no_emcy_and_no_sdo_abort_in_stopped(clocked: Gateway, master: Master,
                                                   clock: ManualClock) -> None:
    gw = clocked
    node = gw.canopen_node
    assert node is not None
    sdo = node.node.sdo
    assert (await master.raw_sdo(struct.pack("<BHBL", 0x21, 0x2200, 1, 2)))[0] == 0x60
    master.nmt(0x02)  # stop, with a download open (its 1 s timer armed)
    async with asyncio.timeout(5):
        while node.node.nmt.state != "STOPPED":  # noqa: ASYNC110 -- the node's thread
            await asyncio.sleep(0.01)
    assert sdo._mode == "download"  # type: ignore[attr-defined]
    await gw.start("BAD", process=3)  # an alarm while STOPPED
    clock.advance(1.0)  # the node's own timer ends the transfer, silently
    assert sdo._mode is None  # type: ignore[attr-defined]
    master.nmt(0x80)  # pre-operational: SDO again
    answers = master.frames[SDO_ANSWER] if SDO_ANSWER in master.frames else master.listen(
        SDO_ANSWER)
    assert answers.empty()  # no abort was sent while stopped
    assert await master.upload(0x1001, 0) == u8(1)  # the error register has the alarm
    assert master.frames[0x90].empty()  # and no EMCY went out for it


# -- 7. sizes and block transfers --------------------------------------------------------------

@pytest.mark.parametrize(("data", "code"), [(bytes(4), 0x06070012), (bytes(1), 0x06070013)])
async def test_segmented_download_of_the_wrong_size(gw: Gateway, master: Master, data: bytes,
                                                    code: int,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    # The raw transfer below is opened, then its segment sent from a worker thread: on a
    # loaded machine (CI, -n 4 on two cores) more than the node's 1 s segmented timeout
    # passed between them once, and the segment met no transfer (0x05040001).  The timeout
    # has tests of its own; here it must not decide.
    from ncgate.gateway.canopen import sdo as sdo_module

    monkeypatch.setattr(sdo_module, "SEGMENTED_TIMEOUT_S", 60.0)
    error = await sdo_error(master.download(0x2200, 1, data, force_segment=True))
    assert error == code
    # announced without a size, the length is checked at the end
    assert (await master.raw_sdo(struct.pack("<BHB4x", 0x20, 0x2200, 1)))[0] == 0x60
    last = 0x01 | (7 - len(data)) << 1
    assert abort_code(await master.raw_sdo(bytes((last,)) + data.ljust(7, b"\0"))) == code
    assert gw.image.read("SYVAR", 0, "IN") == 0


async def test_a_segmented_download_past_its_objects_size_is_aborted_at_that_segment(
        gw: Gateway, master: Master, monkeypatch: pytest.MonkeyPatch) -> None:
    """Unsized, a download to a 2-byte number went on taking segments (20,000 of them, 140 kB
    in memory: a hostile try) until its last one's abort: CiA 301 lets a server abort as soon
    as the data passes the object's size, so it does, at that segment.  Sized, past the size
    it announced: 0x06070010."""
    from ncgate.gateway.canopen import sdo as sdo_module

    monkeypatch.setattr(sdo_module, "SEGMENTED_TIMEOUT_S", 60.0)  # (as the test above)
    for initiate, code in ((struct.pack("<BHB4x", 0x20, 0x2200, 1), 0x06070012),
                           (struct.pack("<BHBL", 0x21, 0x2200, 1, 2), 0x06070010)):
        assert (await master.raw_sdo(initiate))[0] == 0x60
        answer = await master.raw_sdo(bytes((0x00,)) + bytes(7))  # 7 bytes, more to come
        assert abort_code(answer) == code
        # The transfer is gone: a further segment meets none.
        assert abort_code(await master.raw_sdo(bytes((0x10,)) + bytes(7))) == 0x05040001
    assert gw.image.read("SYVAR", 0, "IN") == 0


async def test_block_transfers_are_refused(gw: Gateway, master: Master) -> None:
    for command in (0xA0, 0xC0):  # block upload, block download
        answer = await master.raw_sdo(struct.pack("<BHBL", command, 0x1000, 0, 0))
        assert abort_code(answer) == 0x05040001
        assert answer[1:4] == bytes((0x00, 0x10, 0x00))


# -- 10. COB-ID rules -----------------------------------------------------------------------------

@pytest.mark.parametrize(("index", "values", "why"), [
    (0x1400, [0x220], "the id changes while the RPDO is valid"),
    (0x1400, [0x80000210, 0x610], "an SDO request id"),
    (0x1400, [0x80000210, 0x050], "an NMT/SYNC range id"),
    (0x1400, [0x80000210, 0x701], "a heartbeat id"),
    (0x1400, [0xA0000210], "a 29-bit id"),
])
async def test_cob_id_rules(gw: Gateway, master: Master, index: int, values: list[int],
                            why: str) -> None:
    *first, refused = values
    for value in first:
        await master.download(index, 1, struct.pack("<L", value))
    stored = await master.upload(index, 1)
    error = await sdo_error(master.download(index, 1, struct.pack("<L", refused)))
    assert error == 0x06090030, why
    assert await master.upload(index, 1) == stored  # nothing changed


# -- 13. what reset node does ---------------------------------------------------------------------

async def test_reset_node_forgets_the_snd_sender_and_keeps_the_image(gw: Gateway,
                                                                     master: Master) -> None:
    assert await master.next(0x710) == b"\x00"
    gw.write("SK5", 200)  # the soft PLC's image ...
    await master.download(0x2000, 2, u8(0b100))  # ... also written by this master: SA10
    await master.download(0x2400, 2, u8(4))  # the SND sender: external P4
    master.nmt(0x81)  # reset node
    assert await master.next(0x710) == b"\x00"
    assert (gw.read("SK5"), gw.read("SA10")) == (200, 1)  # the image stays
    assert await master.upload(0x2100, 6) == u8(200)
    # the node's own application value is back to power-on: no sender written yet
    assert await sdo_error(master.download(0x2400, 3, u8(1))) == 0x08000022


# -- 12. identity and housekeeping objects masters read --------------------------------------------

async def test_identity_strings_by_segmented_upload(gw: Gateway, master: Master) -> None:
    from ncgate import __version__

    assert await master.upload(0x1008, 0) == b"ncgate CNC co-simulator gateway"  # 31 bytes
    assert await master.upload(0x100A, 0) == __version__.encode()
    assert len(await master.upload(0x1009, 0)) > 4
    assert await master.upload(0x1014, 0) == struct.pack("<L", 0x90)  # EMCY of node 16
    # a segmented upload with a wrong toggle bit is aborted, and closed
    answer = await master.raw_sdo(struct.pack("<BHB4x", 0x40, 0x1008, 0))
    assert answer[0] == 0x41 and int.from_bytes(answer[4:8], "little") == 31
    assert abort_code(await master.raw_sdo(bytes((0x70,)) + bytes(7))) == 0x05030000
    assert abort_code(await master.raw_sdo(bytes((0x60,)) + bytes(7))) == 0x05040001


async def test_sdo_timeout_never_blocks_the_loop_on_a_busy_server(clocked: Gateway,
                                                                  master: Master,
                                                                  clock: ManualClock) -> None:
    """The timeout fires on the loop; a request being served holds the server's lock and may
    itself wait for the loop (a write).  The timer must give way, not wait for the lock."""
    sdo = clocked.canopen_node.node.sdo  # type: ignore[union-attr]
    assert (await master.raw_sdo(struct.pack("<BHBL", 0x21, 0x2200, 1, 2)))[0] == 0x60
    held, release = threading.Event(), threading.Event()

    def serving() -> None:  # as the receive thread does while it serves a request
        with sdo._lock:
            held.set()
            release.wait(5)
    worker = threading.Thread(target=serving)
    worker.start()
    held.wait(5)
    clock.advance(1.0)  # returns at once: the timer gave way
    release.set()
    worker.join(5)
    assert sdo._mode == "download"  # left to the request in progress
