"""The node's two threads (ARCHITECTURE.md, "The runtime"): python-can's receive thread hands
its work to the asyncio loop and never reads the engine; the loop owns the engine, the image
and the TPDOs' state.  A canopen master on the virtual bus; the interleavings that are rare by
chance are forced here, not waited for."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from typing import Any

import pytest

from ncgate.gateway import Gateway

from .conftest import Master


async def test_a_callback_the_loop_ran_before_its_handoff_returned_is_not_left_pending(
        gw: Gateway, master: Master, monkeypatch: pytest.MonkeyPatch) -> None:
    """The loop may run a callback handed over by the receive thread before
    ``call_soon_threadsafe`` has returned to that thread (1-2 in 20,000 RPDOs did, by chance).
    Forced here: a handoff from another thread returns only once the loop ran it."""
    node = gw.canopen_node
    assert node is not None
    loop = asyncio.get_running_loop()
    loop_thread = threading.get_ident()
    handoff = loop.call_soon_threadsafe

    def returns_once_run(callback: Callable[..., object], *args: Any,
                         context: Any = None) -> asyncio.Handle:
        ran = threading.Event()

        def run() -> None:
            try:
                callback(*args)
            finally:
                ran.set()

        handle = handoff(run, context=context)
        if threading.get_ident() != loop_thread:
            ran.wait(5)
        return handle

    monkeypatch.setattr(loop, "call_soon_threadsafe", returns_once_run)
    master.nmt(0x01)
    for value in range(1, 21):
        master.network.send_message(0x210, bytes((value,)) + bytes(7))  # RPDO1 -> SA bytes
    await master.barrier()  # an SDO status read: handed to the loop the same way
    assert await master.upload(0x2000, 1) == bytes((20,))  # every RPDO was applied
    assert not node._pending  # nothing the loop ran is still tracked as waiting
