"""The engine on the wall clock (``ncgate run``, the ``Gateway`` API).

An engine timer becomes one loop timer (a delay from the driver's own monotonic clock); a
write from outside wakes its waits at once and schedules a run with ``call_soon`` --
event-driven, no polling between a write and the wake.  ``nc.time_scale`` makes simulated
time pass faster than the wall clock.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from ncgate.interpreter.engine import Engine

log = logging.getLogger("ncgate")
LAG_WARN_S = 0.1  # wall seconds behind the clock that are worth a warning
LAG_WARN_EVERY_S = 60.0  # at most one such warning a minute
# Blocks (and timers) the engine runs in one turn of the loop before the fieldbus gets one:
# about a millisecond of a dense dwell loop (nc.slice_blocks may be smaller).
TURN_BLOCKS = 1_000
# And at most this long of the wall clock: timers differ in weight (a plant model's is a write
# through the door, 30-50 us), and a hundred models switching at one instant held the loop
# 25 ms in one turn.  A poller's request waits for at most one turn (_yield), so the turn is
# what it pays: 1 ms turns left bench/plant.py's poller p99 beside 100 moving models at
# 2.8-3.7x quiet, 0.1 ms turns at 1.2-1.35x, with no cost seen in run's block throughput.
TURN_S = 0.0001
# But an engine BEHIND_S (wall seconds) or more behind the clock gets turns as long as a
# fieldbus round (the Modbus server's ROUND_S): a 0.1 ms turn a loop pass against a flood's
# 0.5 ms round left it a sixth of the loop, and the PLC scan (an engine timer) came 28 ms
# late under bench/storm.py's flood (5-6 ms with this).  Not from 1 ms behind: the plant
# bench's engine is often that far behind, and its poller's p99 paid the longer turns.
BEHIND_S = 0.005
TURN_BEHIND_S = 0.0005
# And the further behind, the longer: a turn of TURN_BEHIND_S for each BEHIND_S behind, up to
# TURN_BEHIND_MAX_S.  On a host where the cell's own work took 2/3 of a core, the flood's
# rounds left the engine too little even at 0.5 ms turns: it fell behind for good, and the
# PLC scan came 116-300 ms late with half its scans overrun (bench/storm.py, flood).  A poll
# waits for one turn at most: 2 ms keeps its p99 under bench/storm.py's 5 ms.
TURN_BEHIND_MAX_S = 0.001


def turn_length(behind_s: float) -> float:
    """How long (wall seconds) a turn of the engine may run when it is ``behind_s`` wall
    seconds behind the clock."""
    if behind_s < BEHIND_S:
        return TURN_S
    return min(TURN_BEHIND_MAX_S, TURN_BEHIND_S * behind_s / BEHIND_S)


class WallClockDriver:
    """Runs an :class:`Engine` on the asyncio loop's clock, ``time_scale`` times faster."""

    def __init__(self, engine: Engine, time_scale: float, loop: asyncio.AbstractEventLoop,
                 stall_s: float = 0.0) -> None:
        self.engine = engine
        self.scale = time_scale
        self.loop = loop
        self.stall_s = stall_s
        self._stall_timer: asyncio.TimerHandle | None = None
        self._stall_reported_at: float | None = None
        self._stall_due_at: float | None = None
        # The driver's own clock: the monotonic clock, not the loop's.  uvloop's loop.time()
        # counts whole milliseconds (libuv's uv_now), so every input stamped from it, the PLC
        # scan's lateness and each status read's "now" were whole milliseconds (times the
        # time scale) apart.  Loop timers are armed as delays from it (_at).
        self.t0 = time.monotonic()
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at: float | None = None
        self._soon: asyncio.Handle | None = None
        self.changed = asyncio.Event()
        # Turns of the engine run so far (each settle and each advance): what it shows may
        # have changed since a view of it was built (gateway/view.py).
        self.turns = 0
        self._turn = min(TURN_BLOCKS, engine.settings.slice_blocks)
        # How far (machine seconds) the engine is behind the clock: work that was due is not
        # done yet because the loop had no time for it (a write storm).  Shown in the status
        # (Modbus info register 8, the console) and warned about once a minute.
        self.lag_s = 0.0
        self.max_lag_s = 0.0
        self._lag_warned_at = float("-inf")
        engine.on_kick = self.kick
        engine.on_timer = lambda t: self.kick()
        engine.clock = self.now  # a status read sees the position now, not at the last input

    @property
    def behind(self) -> bool:
        """The engine is BEHIND_S (wall seconds) or more behind the clock: what is not on
        time (the console's streams) gives way."""
        return self.lag_s >= BEHIND_S * self.scale

    def now(self) -> float:
        """Simulated seconds since the driver started."""
        return (time.monotonic() - self.t0) * self.scale

    def catch_up(self) -> None:
        """Fire what is due up to now (a slice of it: the rest on the next turns), so that an
        input from outside acts after everything that was due before it."""
        now = (time.monotonic() - self.t0) * self.scale  # now(), inlined: every input
        engine = self.engine
        due = engine.next_timer()
        if (due is None or due > now) and not engine.has_unfinished:
            engine.set_time(now)  # nothing was due: the common case of a write storm
            return
        self._advance(now)

    def settle(self) -> None:
        """Run (a slice of) what an outside input made runnable, now; the rest soon."""
        self.engine.run_until_blocked(self._turn)
        self.turns += 1
        self.kick()

    def kick(self) -> None:
        if self._soon is None:
            self._soon = self.loop.call_soon(self._run)

    def _yield(self) -> None:
        """The rest of a turn that ran out of time, after what the loop's sockets have
        ready: a timer due now, not ``call_soon``.  asyncio runs a ``call_soon`` callback
        before it polls again, so a request that arrived during a turn waited for a second
        turn too; a due timer comes after the poll on both loops (uvloop polled between
        either way).
        """
        if self._soon is None:
            self._soon = self.loop.call_later(0, self._run)

    def _run(self, due: float | None = None) -> None:
        # Only the handle that fired is spent: clearing the other (a soon still pending
        # when the timer fired) orphaned it, and a turn that yielded queued one more --
        # behind the clock, a loop pass ran 6-7 turns before it polled again.
        if due is not None:
            self._timer = None
        else:
            self._soon = None
        # A loop timer may fire a hair early: never let time run backwards past what is due.
        # At most a slice of blocks at a time: a loop with no motion must leave the event
        # loop free to serve the fieldbus and signals; the rest runs on the next turn.
        self._advance(self.now() if due is None else max(self.now(), due))
        self._arm_stall()
        self.changed.set()

    def _advance(self, now: float) -> None:
        """A turn of the engine up to ``now``; what it leaves is the next turn's, and how
        far behind the clock that leaves the engine is its lag."""
        deadline = time.perf_counter() + turn_length(self.lag_s / self.scale)
        self.engine.turn_over = lambda: time.perf_counter() >= deadline
        more = False
        try:
            more = self.engine.advance_to(now, self._turn)
        finally:  # a callback that raised (a bug) is the loop's to log; the clock goes on
            self.turns += 1
            if more:
                self._yield()
            self._arm()
        if more:
            self._note_lag(now - self.engine.now)
        elif self.lag_s:
            self.lag_s = 0.0

    def _note_lag(self, lag: float) -> None:
        self.lag_s = max(0.0, lag)
        self.max_lag_s = max(self.max_lag_s, self.lag_s)
        wall = self.loop.time()
        if (self.lag_s / self.scale >= LAG_WARN_S
                and wall - self._lag_warned_at >= LAG_WARN_EVERY_S):
            self._lag_warned_at = wall
            log.warning("the engine is %.3f s of machine time behind the clock (nc.time_scale "
                        "%g): the loop is too busy to keep it; what is due runs late, in order",
                        self.lag_s, self.scale)

    def _arm(self) -> None:
        t = self.engine.next_timer()
        if t is None or (self._soon is not None and t <= self.now()):
            # None due, or due already and a turn is coming anyway: a timer beside it would
            # be a second turn before the loop polls again.
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
            return
        if self._timer is not None and self._timer_at == t:
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer_at = t
        self._timer = self._at(t, self._run, t)

    def _arm_stall(self) -> None:
        """nc.stall_s: when every process with a program has been blocked, and nothing has
        changed (no state, no image write), for stall_s simulated seconds, the trace says so
        (once per stall).  Outside can still end it: it is reported, not an alarm."""
        engine = self.engine
        due: float | None = None
        if self.stall_s and engine.stalled and self._stall_reported_at != engine.last_change:
            due = engine.last_change + self.stall_s  # None: no stall, or this one was reported
        if due == self._stall_due_at:
            return  # the timer in place is the right one (or none is needed)
        if self._stall_timer is not None:
            self._stall_timer.cancel()
            self._stall_timer = None
        self._stall_due_at = due
        if due is not None:
            self._stall_timer = self._at(due, self._stall_due)

    def _at(self, t: float, callback: Callable[..., object], *args: object
            ) -> asyncio.TimerHandle:
        """A loop timer for machine time ``t``: a delay on the loop's clock, which need not
        be ours (uvloop's is in whole milliseconds and rounds the delay, so the timer may
        come up to half a millisecond early: ``_run`` never lets time run back past what was
        due)."""
        delay = self.t0 + t / self.scale - time.monotonic()
        return self.loop.call_later(max(0.0, delay), callback, *args)

    def _stall_due(self) -> None:
        self._stall_timer = None
        self._stall_due_at = None
        engine = self.engine
        engine.set_time(self.now())
        if engine.stalled and engine.now >= engine.last_change + self.stall_s:
            self._stall_reported_at = engine.last_change
            engine.record_stall()
            self.changed.set()
        else:
            self._arm_stall()

    def close(self) -> None:
        for handle in (self._timer, self._soon, self._stall_timer):
            if handle is not None:
                handle.cancel()
        self.engine.on_kick = None
        self.engine.on_timer = None
        self.engine.turn_over = None
        self.engine.clock = None
