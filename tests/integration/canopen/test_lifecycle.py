"""The node's life cycle and its bridge to the loop: nothing scheduled from the CAN thread
runs after close, and an SDO answered with an abort never acts afterwards."""

from __future__ import annotations

import asyncio
import logging
import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from canopen.sdo.exceptions import SdoAbortedError

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.canopen.clock import ManualClock
from ncgate.gateway.canopen.codes import ABORT_GENERAL_ERROR
from ncgate.gateway.canopen.dictionary import SA_BYTES
from ncgate.gateway.errors import ListenError
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.events import Event

from .conftest import Master, u16, u32
from .test_sync_mapping import operational


@pytest.mark.parametrize("ncgate_config", [{"canopen.nmt_autostart": True}], indirect=True)
async def test_enter_and_leave_at_once_logs_nothing_amiss(
        master: Master, ncgate_config: Config, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING)
    async with Gateway(ncgate_config):
        pass
    await asyncio.sleep(0)  # one more turn: what the node left on the loop would run here
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []


# P1 sends to the external P4 (which never waits: no rendezvous) and dwells, again and again:
# an SND event, and two state changes (RUNNING, DWELL), every 20 us of wall time.
PUMP = '"TOP"N1(SND,4)\nN2(DLY,0.001)\nN3(BNC,TOP)\n'


@pytest.mark.parametrize("ncgate_config", [{"canopen.nmt_autostart": True,
                                            "canopen.hub": True}], indirect=True)
async def test_no_engine_event_reaches_the_node_once_its_close_began(
        cell: Path, master: Master, gw: Gateway) -> None:
    """The engine runs on while the node closes (the hub's thread is stopped from a thread,
    and the loop serves meanwhile) and after (the gateway stops its clock after every
    adapter): its SNDs and state changes must not make the node send from then on.  They
    did: after ``network.disconnect()`` the send raised "Not connected to CAN bus" inside
    the driver's turn of the engine, in the loop's exception handler."""
    (cell / "PUMP.nc").write_text(PUMP)
    node = gw.canopen_node
    assert node is not None
    loop = asyncio.get_running_loop()
    failures: list[dict[str, Any]] = []
    enough = asyncio.Event()  # SNDs went on after the close, or something failed

    def on_error(_: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        failures.append(context)
        enough.set()

    closed = False
    snds_since = 0

    def count(event: Event) -> None:
        nonlocal snds_since
        if closed and isinstance(event, ev.Snd):
            snds_since += 1
            if snds_since >= 50:
                enough.set()

    previous = loop.get_exception_handler()
    loop.set_exception_handler(on_error)
    gw.engine.trace.subscribe(count)
    try:
        await gw.start("PUMP")
        await master.next(0x280 + master.node_id)  # TPDO2: an SND's frame went out
        sent = node.pdos.sent
        await node.close()
        closed = True
        async with asyncio.timeout(10):
            await enough.wait()
    finally:
        loop.set_exception_handler(previous)
    assert [str(c.get("exception") or c["message"]) for c in failures] == []
    assert snds_since >= 50  # the engine ran on after the close: its SNDs came
    assert node.pdos.sent == sent  # and none made the node send, nor did one while closing
    await node.close()  # again, as the gateway's exit does: nothing happens


@pytest.mark.parametrize("ncgate_config", [{"canopen.nmt_autostart": True}], indirect=True)
async def test_a_gateway_stopped_under_a_poller_sends_nothing_once_its_bus_is_gone(
        cell: Path, master: Master, ncgate_config: Config) -> None:
    """The SIGTERM of a gateway with a Modbus poller connected: the Modbus server, closed
    after the node, waits for its connections to be lost, and the engine runs meanwhile (the
    clock stops last).  Its SNDs reached the closed node, whose send raised "Not connected to
    CAN bus" in the driver's turn (the loop's exception handler; the engine stopped there)."""
    (cell / "PUMP.nc").write_text(PUMP)
    loop = asyncio.get_running_loop()
    failures: list[dict[str, Any]] = []
    previous = loop.get_exception_handler()
    loop.set_exception_handler(lambda _, context: failures.append(context))
    try:
        async with Gateway(ncgate_config) as gw:
            plc = VirtualPLC(*gw.modbus_address, ncgate_config)
            await plc.connect()  # a read answered: the server holds the connection
            try:
                await gw.start("PUMP")
                await master.next(0x280 + master.node_id)  # TPDO2: the SNDs' frames go out
            except BaseException:
                plc.close()
                raise
        plc.close()
    finally:
        loop.set_exception_handler(previous)
    assert [str(c.get("exception") or c["message"]) for c in failures] == []


async def test_no_timer_of_a_closed_node_acts(clocked: Gateway, master: Master,
                                             clock: ManualClock) -> None:
    """The deadlines the node watches (an RPDO's event timer, the SYNC's cycle period) were
    left armed by close: run out after it, they raised AL150 on the gateway and sent the
    EMCY on a bus that is gone ("Not connected to CAN bus")."""
    node = clocked.canopen_node
    assert node is not None
    await master.download(0x1400, 5, u16(100))  # RPDO1: at least every 100 ms
    await master.download(0x1006, 0, u32(10_000))  # a SYNC every 10 ms
    await master.download(0x1800, 5, u16(50))  # TPDO1's event timer
    await operational(master)
    master.network.send_message(0x210, bytes(8))  # RPDO1 and SYNC: their deadlines armed
    master.sync()
    await master.barrier()
    await node.close()
    armed = clock.pending()
    clock.advance(1.0)  # every deadline runs out
    assert not [e for e in clocked.trace if e["event"] == "alarm"]
    assert armed == 0  # nothing the node armed was left


async def test_a_node_whose_start_failed_leaves_the_bus(cell: Path) -> None:
    """The gateway closes only an adapter that started: a node whose hub could not listen
    stayed on the bus (its receive thread, its answers to SDO, its heartbeat) for as long as
    the process lived."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        config = ncgate_test_config(cell / "ncgate.toml", **{
            "canopen.hub": True, "canopen.hub_port": taken.getsockname()[1]})
        with pytest.raises(ListenError, match=r"canopen\.hub_port"):
            async with Gateway(config):
                pass
    bus = f'"Virtual bus channel {config.canopen.channel}"'  # its receive thread's name ends so
    assert [t.name for t in threading.enumerate() if t.name.endswith(bus)] == []


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

    # Each SYNC is either answered at once or, handled too late, dropped and counted: which,
    # depends on how the threads were scheduled, so the test counts both instead of the
    # frames that came within 0.3 s of wall time (at least 10 of 20 did, until a loaded
    # machine).
    assert gw.canopen_node is not None
    pdos = gw.canopen_node.pdos
    answered_before, dropped_before = pdos.sync_answered, pdos.sync_dropped

    def handled() -> tuple[int, int]:
        return pdos.sync_answered - answered_before, pdos.sync_dropped - dropped_before

    sender = threading.Thread(target=syncs)
    sender.start()
    # The stimulus: the loop stalls (this, its thread, never yields to it) until the node
    # has handled all 20 SYNCs and the master has heard every TPDO they sent: the receive
    # thread does it alone, or this never ends (the give-up is only a guard against a hang).
    sender.join()
    give_up = time.monotonic() + 60
    while (sum(handled()) < 20 or len(arrivals) < handled()[0]) and time.monotonic() < give_up:
        time.sleep(0.001)  # noqa: ASYNC251 - the loop stalls on purpose; another thread's counts
    answered, dropped = handled()
    during = len(arrivals)
    assert (answered + dropped, during) == (20, answered), (answered, dropped, during)
    assert answered  # some went out while the loop stood still
    await master.barrier()
    assert len(arrivals) == answered  # one per SYNC answered: nothing in a late burst


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
