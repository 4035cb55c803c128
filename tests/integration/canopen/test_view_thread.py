"""The cell's view and the node's two threads (ARCHITECTURE.md, "Who reads what, on which
thread"): the loop builds the view and publishes what the node maps into its snapshot; the
receive thread answers SYNCs and SDO reads from the snapshot or hands them to the loop, and
never builds a view itself."""

from __future__ import annotations

import struct
import threading
from typing import Any

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.view import ViewPublisher

from .conftest import Master
from .test_threads import TPDO3, map_status_on_sync


async def test_the_receive_thread_never_builds_a_view(
        gw: Gateway, master: Master, monkeypatch: pytest.MonkeyPatch) -> None:
    loop_thread = threading.get_ident()
    calls: list[tuple[str, bool]] = []  # (what, on the loop's thread)
    for name in ("current", "process", "status", "state", "last_snd", "plc_registers"):
        real = getattr(ViewPublisher, name)

        def recorded(self: ViewPublisher, *args: Any, _real: Any = real,
                     _name: str = name) -> Any:
            calls.append((_name, threading.get_ident() == loop_thread))
            return _real(self, *args)

        monkeypatch.setattr(ViewPublisher, name, recorded)
    # TPDO3 on every SYNC (test_threads); TPDO1 (the states, on change) as it is by default.
    await map_status_on_sync(master)
    master.nmt(0x01)
    await master.barrier()
    gw.command(1)  # MAIN: EXE 2 SIDE, then waits for SA10 at N2
    await gw.wait_state(1, "WAIT_COND", timeout_s=5)
    await gw.wait_state(2, "WAIT_COND", timeout_s=5)
    await master.barrier()
    for _ in range(5):
        master.sync()
        frame = await master.next(TPDO3)
    assert frame[:5] == struct.pack("<BHH", 3, 2, 2)  # WAIT_COND at N2, line 2
    assert await master.upload(0x2500, 6) == b"\x00\x00"  # an SDO read of the status: no alarm
    assert calls, "the node read nothing of the view"
    off_loop = [name for name, on_loop in calls if not on_loop]
    assert off_loop == []


async def test_the_error_register_takes_the_processes_not_the_whole_view(
        gw: Gateway, master: Master, monkeypatch: pytest.MonkeyPatch) -> None:
    # The whole view holds the plant too (a model's view costs about 0.8 us): the register,
    # read inside the alarm's and the reset's events for their EMCYs, takes the processes'.
    wholes: list[int] = []
    real = ViewPublisher.current

    def counted(self: ViewPublisher) -> Any:
        wholes.append(1)
        return real(self)

    monkeypatch.setattr(ViewPublisher, "current", counted)
    await gw.start("BAD", process=3)  # AL101 in P3
    code, register, _ = struct.unpack("<HB5s", await master.next(0x90))
    assert (code, register) == (0x6200, 1)
    gw.command(3)  # reset
    code, register, _ = struct.unpack("<HB5s", await master.next(0x90))
    assert (code, register) == (0, 0)
    assert await master.upload(0x1001, 0) == b"\x00"
    assert wholes == []
