"""How things end and fail, tried as a hostile integrator: the CANopen node's close under a
master that keeps talking, a second close beside the first, and trace listeners that
unsubscribe or fail.  Real protocols (a canopen master on python-can's virtual bus, the
hub's TCP port), waits on events.  Each failed on the code before its fix.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.events import Event

from ..helpers import write_cell
from .canopen.conftest import CELL, PROGRAMS, connect_master

PUMP = '"TOP"N1(SND,4)\nN2(DLY,0.001)\nN3(BNC,TOP)\n'


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    return write_cell(tmp_path, CELL, {**PROGRAMS, "PUMP": PUMP})


def config_of(cell: Path, **overrides: object) -> Config:
    return ncgate_test_config(cell / "ncgate.toml", **overrides)


async def test_a_close_while_an_sdo_read_waits_for_the_loop_is_prompt(
        cell: Path, caplog: pytest.LogCaptureFixture) -> None:
    config = config_of(cell, **{"canopen.nmt_autostart": True})
    master = connect_master(config)
    try:
        async with Gateway(config) as gw:
            node = gw.canopen_node
            assert node is not None
            await asyncio.to_thread(master.node.sdo.upload, 0x2500, 1)  # booted, loop idle
            # The receive thread hands the loop a read (0x1001, the error register, is read
            # on the loop) while the loop is busy: blocked here until it did.  (Instrumented
            # at the node's own call_soon, which _on_loop uses.)
            handed = threading.Event()
            loop_thread = threading.get_ident()
            call_soon: Callable[[Callable[[], None]], None] = node.call_soon

            def spy(fn: Callable[[], None]) -> None:
                call_soon(fn)
                if threading.get_ident() != loop_thread:
                    handed.set()

            node.call_soon = spy  # type: ignore[method-assign]
            master.network.send_message(0x600 + master.node_id,
                                        bytes((0x40, 0x01, 0x10, 0, 0, 0, 0, 0)))
            assert handed.wait(5)  # the loop is busy until the read waits for it
            began = time.perf_counter()
            # the gateway's exit (a SIGTERM handled) begins before the loop got to the read
        took = time.perf_counter() - began
    finally:
        master.network.disconnect()
    # Before the fix the read waited out its 2 s on the receive thread while disconnect
    # joined that thread from the loop (the loop stood still), then failed as a bug would:
    # "SDO request ... failed" with a TimeoutError traceback.  Now close aborts it at once.
    failed = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert failed == [], (took, failed)


async def test_a_second_close_returns_once_the_node_is_closed(cell: Path) -> None:
    config = config_of(cell, **{"canopen.hub": True})
    async with Gateway(config) as gw:
        node = gw.canopen_node
        assert node is not None and node.hub_address is not None
        address = node.hub_address
        first = asyncio.create_task(node.close())
        await asyncio.sleep(0)  # the first close runs up to the hub's shutdown
        await node.close()  # the second: returns once the node is closed
        try:
            with socket.create_connection(address, timeout=1):
                listening = True
        except OSError:
            listening = False
        await first
    assert not listening, "the hub still accepted a connection after close() returned"


async def test_a_listener_that_unsubscribes_itself_leaves_the_next_its_event(
        cell: Path) -> None:
    async with Gateway(config_of(cell, **{"canopen.enabled": False})) as gw:
        trace = gw.engine.trace
        once: list[int] = []
        heard: list[int] = []
        enough = asyncio.Event()

        def one_shot(event: Event) -> None:
            once.append(event.seq)
            unsubscribe()

        def follower(event: Event) -> None:
            heard.append(event.seq)
            if len(heard) >= 3:
                enough.set()

        unsubscribe = trace.subscribe(one_shot)
        trace.subscribe(follower)
        await gw.start("PUMP")
        async with asyncio.timeout(10):
            await enough.wait()
    assert heard[0] == once[0], (once, heard[:3])


async def test_each_failing_listener_is_logged_once_with_its_traceback(
        cell: Path, caplog: pytest.LogCaptureFixture) -> None:
    async with Gateway(config_of(cell, **{"canopen.enabled": False})) as gw:
        snds = asyncio.Event()

        def adapter(what: str, on: type) -> Callable[[Event], None]:
            def on_event(event: Event) -> None:
                if isinstance(event, on):
                    raise RuntimeError(what)
            return on_event

        def count(event: Event) -> None:
            if isinstance(event, ev.Snd):
                snds.set()

        with caplog.at_level(logging.ERROR, logger="ncgate.trace"):
            gw.engine.trace.subscribe(adapter("disk full", ev.Start))
            gw.engine.trace.subscribe(adapter("socket gone", ev.Snd))
            gw.engine.trace.subscribe(count)
            await gw.start("PUMP")
            async with asyncio.timeout(10):
                await snds.wait()
    logged = [str(r.exc_info[1]) for r in caplog.records
              if r.name == "ncgate.trace" and r.exc_info]
    assert sorted(logged) == ["disk full", "socket gone"], logged
