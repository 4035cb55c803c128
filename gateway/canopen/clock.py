"""The CANopen node's timers: inhibit times, event timers, the heartbeat consumer and the SDO
timeout all run on one clock, so that a test can drive them instead of waiting on wall time.

    clock = ManualClock()
    async with Gateway(config, canopen_clock=clock) as gw:
        ...
        clock.advance(0.5)      # fires every timer due within the next 0.5 s, in order

:class:`LoopClock` (the default) runs the timers on the gateway's asyncio loop.  Both accept
``call_later`` from any thread (canopen calls the node from python-can's receive thread);
the callbacks always run on the loop's thread (:class:`ManualClock`: on the thread that calls
``advance``, which in a test is the loop's).
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import threading
import time
from collections.abc import Callable
from typing import Protocol


class Timer:
    """A pending callback; ``cancel()`` from any thread makes sure it does not run."""

    __slots__ = ("cancelled", "fn")

    def __init__(self, fn: Callable[[], None]) -> None:
        self.fn = fn
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True
        self.fn = _nothing  # (what it would have called is let go: no cycle through its owner)

    def fire(self) -> None:
        if not self.cancelled:
            self.cancelled = True
            fn, self.fn = self.fn, _nothing
            fn()


def _nothing() -> None:
    pass


class Clock(Protocol):
    def monotonic(self) -> float: ...

    def call_later(self, delay_s: float, fn: Callable[[], None]) -> Timer: ...


class UnlessClosed:
    """A clock whose timers do nothing once ``closed()`` says so: the node's.  Between the
    start of its close and the bus's disconnect, python-can's receive thread still served
    requests, and a timer one armed (an SDO transfer's timeout, the SYNC deadline) fired a
    second after close: a send on a bus no longer connected, a false "SYNC timeout"."""

    def __init__(self, inner: Clock, closed: Callable[[], bool]) -> None:
        self.inner = inner
        self._closed = closed

    def monotonic(self) -> float:
        return self.inner.monotonic()

    def call_later(self, delay_s: float, fn: Callable[[], None]) -> Timer:
        closed = self._closed

        def unless_closed() -> None:
            if not closed():
                fn()

        return self.inner.call_later(delay_s, unless_closed)


class LoopClock:
    """The asyncio loop's clock; a timer armed on another thread is handed to the loop."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self._thread = threading.get_ident()

    def monotonic(self) -> float:
        # Not loop.time(): uvloop's has a millisecond's resolution, too coarse for a 2 ms
        # inhibit time.  asyncio's loop.time() is this same clock.
        return time.monotonic_ns() / 1e9

    def call_later(self, delay_s: float, fn: Callable[[], None]) -> Timer:
        timer = Timer(fn)
        if threading.get_ident() == self._thread:
            self.loop.call_later(delay_s, timer.fire)
        else:
            due = self.loop.time() + delay_s
            self.loop.call_soon_threadsafe(lambda: self.loop.call_at(due, timer.fire))
        return timer


class ManualClock:
    """Time moves only when the test says so (:meth:`advance`)."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = start
        self._lock = threading.Lock()
        self._heap: list[tuple[float, int, Timer]] = []
        self._order = itertools.count()

    def monotonic(self) -> float:
        return self._now

    def call_later(self, delay_s: float, fn: Callable[[], None]) -> Timer:
        timer = Timer(fn)
        with self._lock:
            heapq.heappush(self._heap, (self._now + max(delay_s, 0.0), next(self._order), timer))
        return timer

    def pending(self) -> int:
        """Timers armed and not cancelled."""
        with self._lock:
            return sum(not t.cancelled for _, _, t in self._heap)

    def advance(self, seconds: float) -> None:
        """Move time on by ``seconds``, firing what falls due at its own time, in order
        (also timers that the callbacks arm within the step)."""
        end = self._now + seconds
        while True:
            with self._lock:
                if not self._heap or self._heap[0][0] > end:
                    self._now = end
                    return
                due, _, timer = heapq.heappop(self._heap)
                self._now = max(self._now, due)
            timer.fire()
