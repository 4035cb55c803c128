"""Watching the PLC logic's variables from a test: ``await watch.until("cell.cycles", 2)``.

Event-driven: the value is checked after every scan (the runtime's scan listeners), never on
a timer.  A PLC that faults while a test waits ends the wait at once, with the fault.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from ncgate.gateway.app import Gateway
from ncgate.gateway.errors import GatewayError, WaitIdleTimeout
from ncgate.plc.scan import PlcState


class PlcFaulted(GatewayError, RuntimeError):
    """The PLC went to FAULT while a test waited on one of its variables."""


class PlcWatch:
    def __init__(self, gateway: Gateway) -> None:
        self.gateway = gateway

    def read(self, path: str) -> Any:
        """A variable now: ``"cell.answer.ET"``, ``"main.values[3]"``."""
        return self.gateway.plc.read(path)

    async def next_scan(self, timeout_s: float = 10.0) -> None:
        """Until the PLC has finished one more scan."""
        runtime = self.gateway.plc
        scanned = asyncio.Event()
        runtime.scan_listeners.append(scanned.set)
        try:
            async with asyncio.timeout(timeout_s):
                await scanned.wait()
        except TimeoutError:
            raise WaitIdleTimeout(f"no scan in {timeout_s:g} s (PLC "
                                  f"{runtime.status.state.name})") from None
        finally:
            runtime.scan_listeners.remove(scanned.set)

    async def until(self, path: str, expected: Any = None, *,
                    test: Callable[[Any], bool] | None = None, timeout_s: float = 10.0) -> Any:
        """Until ``path`` equals ``expected`` (or ``test(value)`` holds); returns the value."""
        runtime = self.gateway.plc
        check = test if test is not None else (lambda value: value == expected)
        scanned = asyncio.Event()
        runtime.scan_listeners.append(scanned.set)
        value = runtime.read(path)
        try:
            async with asyncio.timeout(timeout_s):
                while not check(value):
                    if runtime.status.state is PlcState.FAULT:
                        raise PlcFaulted(f"waiting for {path}: {runtime.status.fault}")
                    scanned.clear()
                    await scanned.wait()
                    value = runtime.read(path)
        except TimeoutError:
            want = "the test" if test is not None else repr(expected)
            raise WaitIdleTimeout(f"{path} is {value!r}, not {want}, after {timeout_s:g} s "
                                  f"(PLC {runtime.status.state.name})") from None
        finally:
            runtime.scan_listeners.remove(scanned.set)
        return value
