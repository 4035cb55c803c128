"""What a master relies on when a machine stops, restarts and is diagnosed (issue 26, defects
1-7), each with a canopen master on the virtual bus (one through the hub) and against CiA 301
/ CiA 306.  Timers on a clock the test moves; every wait is on a frame or an answer."""

from __future__ import annotations

import queue
import struct

import pytest
from canopen.sdo.exceptions import SdoAbortedError

from ncgate.gateway import Gateway
from ncgate.gateway.canopen.clock import ManualClock

from .conftest import Master, abort_code, u8, u16

BOOT = 0x710
SDO_ANSWER = 0x590
EMCY = 0x90
TPDO3 = 0x390
MASTER_ID = 1


def u32(v: int) -> bytes:
    return struct.pack("<L", v)


async def sdo_error(call: object) -> int:
    with pytest.raises(SdoAbortedError) as caught:
        await call  # type: ignore[misc]
    return caught.value.code


def drain(q: queue.Queue[bytes]) -> list[bytes]:
    frames = []
    while not q.empty():
        frames.append(q.get_nowait())
    return frames


# -- 1. leaving OPERATIONAL discards buffered synchronous RPDOs ---------------------------------

@pytest.mark.parametrize("leave", [0x80, 0x02], ids=["pre-operational", "stopped"])
async def test_a_synchronous_rpdo_received_before_leaving_operational_is_never_applied(
        gw: Gateway, master: Master, leave: int) -> None:
    await master.download(0x1400, 2, u8(1))  # RPDO1 (SA bytes 0..7): at every SYNC
    master.nmt(0x01)
    master.network.send_message(0x210, bytes((85, 102, 119, 136)) + bytes(4))
    master.nmt(leave)  # before any SYNC
    master.nmt(0x01)
    master.sync()
    await master.barrier()
    assert [await master.upload(0x2000, s) for s in (1, 2, 3, 4)] == [u8(0)] * 4
    # what comes in OPERATIONAL is applied at the next SYNC, as before
    master.network.send_message(0x210, bytes((7,)) + bytes(7))
    master.sync()
    await master.barrier()
    assert await master.upload(0x2000, 1) == u8(7)


# -- 2. an NMT reset ends every SDO transfer, silently --------------------------------------------

async def test_reset_communication_ends_a_segmented_upload_silently(
        clocked: Gateway, master: Master, clock: ManualClock) -> None:
    assert await master.next(BOOT) == b"\x00"
    answer = await master.raw_sdo(struct.pack("<BHB4x", 0x40, 0x1008, 0))  # 31 bytes
    assert answer[0] == 0x41
    master.nmt(0x82)  # reset communication
    assert await master.next(BOOT) == b"\x00"
    clock.advance(1.0)  # the transfer's timeout: nothing is left to abort
    await master.barrier()
    answers = drain(master.frames[SDO_ANSWER])
    assert [a[0] for a in answers] == [0x4F]  # the barrier's own answer, no abort
    # an upload segment now continues nothing
    assert abort_code(await master.raw_sdo(bytes((0x60,)) + bytes(7))) == 0x05040001


async def test_reset_node_ends_a_segmented_download_silently(gw: Gateway,
                                                            master: Master) -> None:
    assert await master.next(BOOT) == b"\x00"
    assert (await master.raw_sdo(struct.pack("<BHBL", 0x21, 0x1017, 0, 2)))[0] == 0x60
    master.nmt(0x81)  # reset node
    assert await master.next(BOOT) == b"\x00"
    segment = bytes((0x0B,)) + u16(300) + bytes(5)  # the last segment: 2 bytes
    assert abort_code(await master.raw_sdo(segment)) == 0x05040001
    assert await master.upload(0x1017, 0) == u16(0)  # the power-on value
