"""The node's life cycle and its bridge to the loop: nothing scheduled from the CAN thread
runs after close, and an SDO answered with an abort never acts afterwards."""

from __future__ import annotations

import asyncio
import logging
import threading
import time

import pytest
from canopen.sdo.exceptions import SdoAbortedError

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.canopen.codes import ABORT_GENERAL_ERROR
from ncgate.gateway.canopen.dictionary import SA_BYTES

from .conftest import Master


@pytest.mark.parametrize("ncgate_config", [{"canopen.nmt_autostart": True}], indirect=True)
async def test_enter_and_leave_at_once_logs_nothing_amiss(
        master: Master, ncgate_config: Config, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING)
    async with Gateway(ncgate_config):
        pass
    await asyncio.sleep(0)  # one more turn: what the node left on the loop would run here
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []


async def test_an_sdo_aborted_for_a_stalled_loop_is_never_applied(
        master: Master, gw: Gateway) -> None:
    master.node.sdo.RESPONSE_TIMEOUT = 5.0
    download = asyncio.ensure_future(asyncio.to_thread(
        master.node.sdo.download, SA_BYTES, 1, b"\x05"))
    await asyncio.sleep(0)  # the download's thread has started
    # The stimulus, not a wait: the loop stalls past the node's 2 s bridge timeout while
    # the request is on its way.
    time.sleep(2.5)  # noqa: ASYNC251 - the stalled loop is what is tested
    with pytest.raises(SdoAbortedError) as caught:
        await download
    assert caught.value.code == ABORT_GENERAL_ERROR
    await master.barrier()  # everything the node handed the loop has run
    assert gw.image.read("SA", 0, "BY") == 0  # the aborted write did not happen later
    assert not any(e["event"] == "write" for e in gw.trace)


async def test_sync_tpdos_go_out_while_the_loop_is_stalled(gw: Gateway, master: Master) -> None:
    """A SYNC's TPDOs are sampled and sent at the SYNC by the receive thread, from what the
    loop published: a stalled loop neither stops them nor makes them burst out afterwards."""
    from .test_sync_mapping import TPDO1, operational, set_type

    await set_type(master, 0x1800, 1)
    await operational(master)
    await master.barrier()
    arrivals: list[float] = []
    master.network.subscribe(TPDO1, lambda *_: arrivals.append(time.monotonic()))

    def syncs() -> None:
        for _ in range(20):  # 10 ms apart, from a thread of the master's own
            master.sync()
            time.sleep(0.01)

    sender = threading.Thread(target=syncs)
    stall_began = time.monotonic()
    sender.start()
    time.sleep(0.3)  # noqa: ASYNC251 - the stimulus: the loop stalls while the SYNCs come
    stall_ended = time.monotonic()
    await asyncio.to_thread(sender.join)
    await master.barrier()
    during = [t for t in arrivals if stall_began <= t <= stall_ended]
    assert len(during) >= 10, (len(during), len(arrivals))  # not held back by the stall
    assert len(arrivals) <= 20  # one per SYNC: nothing sent twice or in a late burst


async def test_a_stalled_loop_does_not_fake_a_lost_master(gw: Gateway, master: Master) -> None:
    """The master's heartbeats keep coming while an SDO write waits for a stalled loop: the
    receive thread is not held up by the write, so they are seen, and nobody is lost."""
    import struct as _struct

    master_id = 0x7F
    await master.download(0x1016, 1, _struct.pack("<L", master_id << 16 | 300))
    beating = threading.Event()

    def heartbeats() -> None:
        while not beating.is_set():  # every 50 ms, from a thread of the master's own
            master.network.send_message(0x700 + master_id, b"\x05")
            time.sleep(0.05)

    beater = threading.Thread(target=heartbeats)
    beater.start()
    try:
        await master.barrier()
        master.node.sdo.RESPONSE_TIMEOUT = 5.0
        write = asyncio.ensure_future(asyncio.to_thread(
            master.node.sdo.download, SA_BYTES, 2, b"\x04"))
        await asyncio.sleep(0)  # the write's thread has started
        time.sleep(1.0)  # noqa: ASYNC251 - the stimulus: the loop stalls 3x the consumer time
        await write  # answered once the loop runs again (within the bridge's 2 s)
        await master.barrier()
    finally:
        beating.set()
        await asyncio.to_thread(beater.join)
    assert gw.image.read("SA", 1, "BY") == 4
    assert not [e for e in gw.trace if e["event"] == "alarm"]  # no AL150: nobody was lost
