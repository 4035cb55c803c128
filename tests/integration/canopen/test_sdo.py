"""SDO access to every manufacturer object, releases of waits, and every abort code of 3.3."""

from __future__ import annotations

import struct

import pytest
from canopen.sdo.exceptions import SdoAbortedError

from ncgate.gateway import Gateway
from ncgate.gateway.canopen.clock import ManualClock

from .conftest import Master, abort_code, i16, u8, u16


async def test_image_objects_read_and_write_the_live_image(gw: Gateway, master: Master) -> None:
    await master.download(0x2000, 2, u8(0b100))  # SA byte 1: bits 8..15 -> SA10
    assert gw.image.read("SA", 10, "bit") == 1
    gw.write("SA1.BY", 0x81)
    assert await master.upload(0x2000, 2) == u8(0x81)
    for index, sub, k in ((0x2100, 1, 0), (0x2100, 128, 127), (0x2103, 128, 511)):
        await master.download(index, sub, u8(200))
        assert gw.image.read("SK", k, "BY") == 200
        assert await master.upload(index, sub) == u8(200)
    await master.download(0x2201, 1, i16(-1234))  # SYVAR 128
    assert gw.image.read("SYVAR", 128, "IN") == -1234
    assert await master.upload(0x2201, 1) == i16(-1234)
    writes = [e for e in gw.trace if e["event"] == "write"]
    assert writes[0]["who"] == "canopen SDO 0x610"


async def test_standard_entries(gw: Gateway, master: Master) -> None:
    assert await master.upload(0x1000, 0) == struct.pack("<L", 0)
    assert await master.upload(0x1001, 0) == u8(0)
    assert await master.upload(0x1018, 0) == u8(4)
    assert await master.upload(0x1018, 4) == struct.pack("<L", 16)  # serial: the node id
    assert await master.upload(0x1800, 1) == struct.pack("<L", 0x40000190)  # no RTR
    assert await master.upload(0x1A00, 0) == u8(4)  # 4 processes in TPDO1
    assert await master.upload(0x1A00, 1) == struct.pack("<L", 0x25000108)
    assert await master.upload(0x1600, 3) == struct.pack("<L", 0x20000308)


async def test_sdo_writes_release_waits_and_the_mailbox_sends(gw: Gateway,
                                                              master: Master) -> None:
    await master.download(0x2400, 1, u16(1))  # cycle start
    await gw.wait_state(2, "WAIT_COND", timeout_s=5)
    await master.download(0x2100, 6, u8(200))  # SK5 = 200 releases P2
    await master.download(0x2000, 2, u8(0b100))  # SA10 = 1 releases P1
    await gw.wait_state(1, "WAIT_PROC", timeout_s=5)
    status = [await master.upload(0x2500, s) for s in range(1, 9)]
    assert status[0] == u8(2) and status[3] == u8(1) and status[4] == u8(4)  # waits for P4
    assert status[6] == struct.pack("<L", 1)  # one SND sent (to P4)
    last = [await master.upload(0x2600, s) for s in (2, 3, 4)]
    assert last == [u8(1), u8(4), u16(3)]
    await master.download(0x2400, 2, u8(4))  # sender: external P4
    await master.download(0x2400, 3, u8(1))  # target P1: sends
    await gw.wait_idle(timeout_s=5)
    assert gw.image.read("SYVAR", 3, "IN") == -7
    resume = next(e for e in gw.trace if e["event"] == "resume" and e["n"] == 4)
    assert resume["by"] == 4


async def test_status_objects_per_process(gw: Gateway, master: Master) -> None:
    await gw.start("BAD", process=3)  # division by zero: alarm AL101
    assert await master.upload(0x2502, 1) == u8(8)  # ALARM
    assert await master.upload(0x2502, 6) == u16(101)
    assert await master.upload(0x1001, 0) == u8(1)  # error register follows the alarm
    assert await master.upload(0x2503, 1) == u8(0)  # P4: idle


@pytest.mark.parametrize(("action", "code"), [
    ("upload 0x3000:0", 0x06020000),  # no object
    ("upload 0x2000:200", 0x06090011),  # no sub-index (128 SA bytes)
    ("download 0x2500:1", 0x06010002),  # read-only
    ("download 0x1018:1", 0x06010002),
    ("upload 0x2400:1", 0x06010001),  # write-only
    ("download16 0x2100:1=100", 0x06070010),  # U8 sent as 2 bytes, value fits: length
    ("download32 0x2200:1=5", 0x06070010),  # INTEGER16 sent as 4 bytes
    ("download16 0x2100:1=300", 0x06090030),  # a K byte > 255 in a wider type
    ("download8 0x2400:3=9", 0x06090030),  # an unknown SND target
    ("download16 0x2400:1=17", 0x06090030),  # an unknown command (1..16 are commands)
    ("download8 0x2410:1=201", 0x06090030),  # a feed override past 200 %
    ("download8 0x2411:1=101", 0x06090030),  # a rapid override past 100 %
    ("download8 0x2400:2=2", 0x06090030),  # an SND sender that is not external
])
async def test_abort_codes(gw: Gateway, master: Master, action: str, code: int) -> None:
    before = gw.image.snapshot()
    verb, target = action.split(" ")
    index_text, rest = target.split(":")
    index = int(index_text, 16)
    with pytest.raises(SdoAbortedError) as caught:
        if verb == "upload":
            await master.upload(index, int(rest))
        else:
            sub_text, _, value_text = rest.partition("=")
            width = {"download": 1, "download8": 1, "download16": 2, "download32": 4}[verb]
            await master.download(index, int(sub_text), int(value_text or 0).to_bytes(width,
                                                                                     "little"))
    assert caught.value.code == code
    assert gw.image.snapshot() == before  # nothing stored
    assert await master.upload(0x1000, 0) == b"\0\0\0\0"  # still serving


async def test_bad_command_specifier(gw: Gateway, master: Master) -> None:
    answer = await master.raw_sdo(bytes((0xE0, 0x00, 0x20, 0x01, 0, 0, 0, 0)))
    assert abort_code(answer) == 0x05040001
    assert answer[1:4] == bytes((0x00, 0x20, 0x01))  # it names the request's object


async def test_abandoned_segmented_transfer_times_out(clocked: Gateway, master: Master,
                                                      clock: ManualClock) -> None:
    gw = clocked
    # Initiate a segmented download of 2 bytes to SYVAR0, then send nothing more.
    init = struct.pack("<BHBL", 0x21, 0x2200, 1, 2)
    answer = await master.raw_sdo(init)
    assert answer[0] == 0x60  # initiate download response
    queue_ = master.frames[0x580 + master.node_id]
    clock.advance(0.999)
    sdo = gw.canopen_node.node.sdo  # type: ignore[union-attr]
    assert sdo._mode == "download"  # still open: no abort yet (an abort closes it)
    clock.advance(0.001)
    late = await master.next(0x580 + master.node_id, timeout_s=5.0)  # the node gives up
    assert abort_code(late) == 0x05040000 and queue_.empty()
    # a late segment is refused, and nothing was stored
    answer = await master.raw_sdo(bytes((0x0B, 1, 2, 0, 0, 0, 0, 0)))
    assert abort_code(answer) == 0x05040001
    assert gw.image.read("SYVAR", 0, "IN") == 0


async def test_segmented_download_completes(gw: Gateway, master: Master) -> None:
    await master.download(0x2200, 1, i16(-3), force_segment=True)
    assert gw.image.read("SYVAR", 0, "IN") == -3


async def test_every_manufacturer_object(gw: Gateway, master: Master) -> None:
    """Upload every readable sub-index of the manufacturer area and download every writable
    one, checking each against the image or the process status."""
    od = master.node.object_dictionary
    checked = 0
    for index in sorted(i for i in od if 0x2000 <= i < 0x3000):
        obj = od[index]
        for sub in sorted(obj.subindices):
            var = obj.subindices[sub]
            if sub == 0:
                assert await master.upload(index, 0) == u8(len(obj.subindices) - 1)
                continue
            size = len(var) // 8
            if (index, sub) == (0x2400, 4):  # the N number of command words 13/14
                await master.download(index, sub, u16(40))
                assert await master.upload(index, sub) == u16(40)
                checked += 1
                continue
            if index in (0x2410, 0x2411):  # the overrides (issue 27): of process ``sub``
                external = gw.engine.processes[sub].external
                if external:  # no motion to override: refused
                    with pytest.raises(SdoAbortedError) as caught:
                        await master.download(index, sub, u8(50))
                    assert caught.value.code == 0x06090030
                else:
                    await master.download(index, sub, u8(50))
                    p = gw.engine.processes[sub]
                    assert (p.feed_override if index == 0x2410 else p.rapid_override) == 50
                    assert await master.upload(index, sub) == u8(50)
                checked += 1
                continue
            if var.access_type == "rw":  # image objects: write a distinct value, read it back
                value = (index * 7 + sub) % 100 + 1
                if index >= 0x2200:
                    value = -value
                await master.download(index, sub, value.to_bytes(size, "little", signed=True))
                area, at = (("SA", sub - 1) if index == 0x2000 else
                            ("SK", (index - 0x2100) * 128 + sub - 1) if index < 0x2200 else
                            ("SYVAR", (index - 0x2200) * 128 + sub - 1))
                view = "IN" if area == "SYVAR" else "BY"
                assert gw.image.read(area, at, view) == value, (hex(index), sub)
                assert await master.upload(index, sub) == value.to_bytes(size, "little",
                                                                         signed=True)
            elif var.access_type == "ro":  # status and last SND
                data = await master.upload(index, sub)
                assert len(data) == size
                if 0x2500 <= index < 0x2600:
                    status = gw.status(index - 0x2500 + 1)
                    expected = [int(status.state), status.n or 0, status.line,
                                int(status.wait_kind), status.wait_target, status.alarm_code,
                                status.snd_sent, status.snd_received][sub - 1]
                    assert int.from_bytes(data, "little") == expected
                if index == 0x2700:  # the PLC status: this config runs no logic (all 0)
                    assert int.from_bytes(data, "little") == 0
            else:  # write-only: the command record
                with pytest.raises(SdoAbortedError) as caught:
                    await master.upload(index, sub)
                assert caught.value.code == 0x06010001
            checked += 1
    assert checked == 128 + 512 + 256 + 4 + 4 * 8 + 4 + 6 + 2 * 4  # + the overrides


async def test_the_control_word_takes_the_commissioning_commands(gw: Gateway,
                                                                  master: Master) -> None:
    """0x2400:1 takes the Modbus command word's encoding (issue 27): 0x0203 resets process 2
    alone, 6/7 switch single block; a low byte that is no command is 0x06090030."""
    await master.download(0x2400, 1, u16(6))  # single block on, the cell
    await master.download(0x2400, 1, u16(1))  # cycle start: P1 stops after its first block
    await gw.wait_state(1, "STEP", timeout_s=5)
    await master.download(0x2400, 1, u16(7))  # single block off: it goes on
    await gw.wait_state(2, "WAIT_COND", timeout_s=5)
    await master.download(0x2400, 1, u16(0x0203))  # reset of process 2 alone
    await gw.wait_state(2, "IDLE", timeout_s=5)
    assert gw.status(1).state.name != "IDLE"  # P1 untouched
    with pytest.raises(SdoAbortedError) as caught:
        await master.download(0x2400, 1, u16(0x00FF))
    assert caught.value.code == 0x06090030
    ends = [(e["proc"], e["how"]) for e in gw.trace if e["event"] == "end"]
    assert ends == [(2, "reset")]


async def test_the_search_n_and_words_13_to_15(gw: Gateway, master: Master) -> None:
    """0x2400:4 holds the N number of control words 14 (a breakpoint) and 15 (clear them),
    as Modbus holding 2003 does (issue 27)."""
    await master.download(0x2400, 4, u16(40))
    await master.download(0x2400, 1, u16(0x020E))  # breakpoint at N40 of process 2
    # The command acts on the loop after the answer; a status read is served on the loop
    # after it (in order): once it is answered, the command has acted.
    await master.upload(0x2500, 1)
    assert [b.text for b in gw.engine.breakpoints] == ["P2 N40"]
    await master.download(0x2400, 1, u16(15))
    await master.upload(0x2500, 1)
    assert gw.engine.breakpoints == []
