"""The engine's timers: a heap of (time, order, timer); a cancelled timer stays in the heap with
no callback and is dropped when it reaches the top.  No clock is read here: whoever drives the
engine says what time it is (the virtual clock, or the wall clock in the gateway).

Timers of one time fire in the order they were armed, but a *late* timer fires after every
other timer of its time, those armed while its time's timers fire included: a script's entry,
which a replay of the session applies as a recorded input, after every timer of its time
(docs/decisions.md, "Script entries act after the timers of their instant").

A timer's time is snapped to the nanosecond (:func:`snapped`) as it enters the heap: an instant
worked out two ways -- a PLC scan at ``t0 + k * period``, a relay's switch point at ``now +
ms / 1000`` -- is two floats a hair apart (``201 * 0.01 + 0.2`` is ``2.2100000000000004``,
``221 * 0.01`` is ``2.21``), and which of its timers came first would be float noise, not the
arm order the rule above gives them."""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable

NS_PER_S = 1_000_000_000  # the resolution of machine time: one nanosecond


def snapped(t: float) -> float:
    """``t`` on the nanosecond grid: the one float every computation of an instant that
    differs from it by float noise (far less than half a nanosecond) gives."""
    return round(t * NS_PER_S) / NS_PER_S


def grid_index(t: float, period: float, side: Callable[[float], int]) -> int:
    """The index of the point of a grid (every ``period`` from 0) that ``t`` is on, within a
    nanosecond (or the float's own step, far out); else of the one ``side`` (math.floor:
    before, math.ceil: after) of it.  (An epsilon added to ``t / period`` is lost in the
    float far out -- a 1 ms plant tick at 32,769 s -- and a tick due at k * period found its
    next at k again, for ever: the clock stood still.)"""
    x = t / period
    k = round(x)
    return k if abs(t - k * period) <= 1e-9 + abs(t) * 1e-15 else side(x)


def due_time(t: float, now: float) -> float:
    """The time a timer asked for at ``t`` is armed at when the clock reads ``now``: ``t``,
    or now if ``t`` has passed, on the grid -- an off-grid now (the wall clock's) may give a
    hair before it, a timer due at once (``Engine.call_at``; a PLC's leap works out with it
    the times its scans one by one would have been armed at)."""
    return snapped(t if t > now else now)


class Timer:
    __slots__ = ("callback", "time")

    def __init__(self, time: float, callback: Callable[[], None] | None) -> None:
        self.time = time
        self.callback = callback

    def cancel(self) -> None:
        self.callback = None


# Added to a late timer's order: past any count of timers ever armed, so that a late timer
# comes after every other timer of its time, and the late ones among themselves in arm order;
# taken from an early timer's, which comes before every other timer of its time.  A *first*
# timer's order less FIRST puts it after the early ones and before the rest: an input applied
# first at its instant (run --script's start), after the plant's tick of that instant.
LATE = 1 << 62
FIRST = 1 << 61


class TimerHeap:
    def __init__(self) -> None:
        self._heap: list[tuple[float, int, Timer]] = []
        self._order = itertools.count()  # equal times fire in the order they were armed

    def push(self, t: float, callback: Callable[[], None], late: bool = False,
             early: bool = False, first: bool = False) -> Timer:
        """Arm ``callback`` at ``t`` (on the grid: :func:`snapped`); ``late``: after every
        other timer of that time; ``early``: before every other (the plant's tick, which
        samples what moves before anything else of its instant reads it); ``first``: after
        the early ones, before the others (an input applied first: ``Door.apply_first``)."""
        t = round(t * NS_PER_S) / NS_PER_S  # (snapped, inline: every timer comes here)
        timer = Timer(t, callback)
        order = next(self._order)
        if late:
            order += LATE
        elif early:
            order -= LATE
        elif first:
            order -= FIRST
        heapq.heappush(self._heap, (t, order, timer))
        return timer

    def live(self) -> int:
        """Timers armed and neither fired nor cancelled (a walk of the heap: for the rare
        question, not for every timer)."""
        return sum(1 for _, _, timer in self._heap if timer.callback is not None)

    def next_time(self) -> float | None:
        heap = self._heap
        while heap and heap[0][2].callback is None:
            heapq.heappop(heap)
        return heap[0][0] if heap else None

    def pop_early(self, t: float) -> Timer | None:
        """The next live timer due before ``t``, or early at ``t`` (taken off the heap), or
        None: what fires before an input applied first at ``t`` (a replay)."""
        heap = self._heap
        while heap and (heap[0][0] < t or (heap[0][0] == t and heap[0][1] < -FIRST)):
            _, _, timer = heapq.heappop(heap)
            if timer.callback is not None:
                return timer
        return None

    def pop_due(self, t: float) -> Timer | None:
        """The next live timer due at or before ``t`` (taken off the heap), or None."""
        heap = self._heap
        while heap and heap[0][0] <= t:
            _, _, timer = heapq.heappop(heap)
            if timer.callback is not None:
                return timer
        return None
