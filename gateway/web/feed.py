"""The live stream's source: trace events for every console client, kept once.

A trace listener only appends the typed event (it is on the path of every SND and WAI); at
most once per BATCH_S (at once when the last batch is older) the new events go into one
shared ring, and every waiting stream is woken.  An event is rendered to JSON when a stream
first asks for it (then kept rendered), at most SINCE_MAX at a time: with no page open
nothing is rendered, and a busy cell's 50 ms of events never make one long callback that
holds up the fieldbus (rendering a batch in the flush took 4 ms every 50 ms at the storm
bench's rate; 500 events a read with the JSON encoder took 6 ms, so the storm's 50 streams
held the poller up 10 ms at p99 -- events.as_line renders one in ~2 µs).  So a stream sends at most
one batch of events per BATCH_S whatever the rate: a PLC that writes 2,000 times a second
gives a page 20 messages, not 2,000 (one message per write put the page minutes behind).
A stream keeps only its position (a sequence number): memory does
not grow with clients or with time, and a client that reads slowly -- or not at all -- holds
nobody else up; if it falls out of the ring it is told how many events it missed.

Fifty streams are never woken at once: a batch wakes at most WAKE_PER_TURN of the streams
waiting for it in one loop turn, in the order they began waiting, and :class:`Turns` lets at
most so many go on in one turn, waking only those it lets go.  Before, one shared future woke
all fifty in one turn, and each turn woke every stream still waiting for a turn again, to
let eight go: about 175 wake-ups a batch, 5-11 ms of one loop turn at a time (bench/storm.py's
streams phase, where the PLC scan came 20-30 ms late).

No web library here (the HTTP side is :mod:`ncgate.gateway.web.console`).
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable

from ncgate.interpreter.engine.events import Event, as_line

RING = 5000  # events kept for streams that connect or fall behind
BATCH_S = 0.05  # events reach the streams at most this often (bench/console_browser.py)
# And while the engine is behind the clock: a page needs no more, and the streams' writes
# (a thousand a second for 50 pages) took the loop from the engine, whose PLC scan came
# 80-150 ms late (bench/storm.py, streams).
BATCH_BEHIND_S = 0.25
SINCE_MAX = 250  # events rendered for one read of the ring (about 0.5 ms); the rest next time
WAKE_PER_TURN = 8  # streams a batch wakes in one loop turn; the others in the next ones


class EventFeed:
    def __init__(self, loop: asyncio.AbstractEventLoop, keep: int = RING,
                 behind: Callable[[], bool] | None = None) -> None:
        """``behind``: whether the engine is behind the clock (then BATCH_BEHIND_S)."""
        self._loop = loop
        self._behind = behind
        self._pending: list[Event] = []
        # [seq, the event -- or its JSON once a stream asked for it]
        self._ring: deque[list[int | Event | str]] = deque(maxlen=keep)
        self._flush: asyncio.Handle | None = None
        # The streams waiting (wait), in the order they began: each its future and ticket.
        self._waiters: dict[asyncio.Future[None], int] = {}
        self._tickets = 0
        self._wake_below = 0  # a wake wakes the tickets below this (those waiting at it)
        self._waking: asyncio.Handle | None = None  # the next turn's share of a wake
        self._flushed_at = -1e9  # loop time of the last flush
        self.seq = 0  # the last event rendered
        self.closed = False

    def listen(self, event: Event) -> None:
        """The trace listener."""
        self._pending.append(event)
        if self._flush is None:
            behind = self._behind is not None and self._behind()
            due = self._flushed_at + (BATCH_BEHIND_S if behind else BATCH_S) - self._loop.time()
            self._flush = (self._loop.call_later(due, self.flush) if due > 0 else
                           self._loop.call_soon(self.flush))

    def flush(self) -> None:
        self._flush = None
        self._flushed_at = self._loop.time()
        pending, self._pending = self._pending, []
        ring = self._ring
        for event in pending:
            ring.append([event.seq, event])
        if pending:
            self.seq = pending[-1].seq
        self.wake()

    def wake(self) -> None:
        """Wake every stream waiting now (not one that begins waiting after), at most
        WAKE_PER_TURN of them in one loop turn, in the order they began waiting."""
        self._wake_below = self._tickets + 1
        if self._waking is None:
            self._wake_some()

    def _wake_some(self) -> None:
        self._waking = None
        waiters = self._waiters
        woken = 0
        while waiters and woken < WAKE_PER_TURN:
            future, ticket = next(iter(waiters.items()))
            if ticket >= self._wake_below:
                return
            del waiters[future]
            if not future.done():
                future.set_result(None)
                woken += 1
        if waiters and next(iter(waiters.values())) < self._wake_below:
            self._waking = self._loop.call_soon(self._wake_some)

    async def wait(self, timeout_s: float) -> None:
        """Until new events are in (or the feed closes), at most ``timeout_s``."""
        if self.closed:
            return
        future = self._loop.create_future()
        self._tickets += 1
        self._waiters[future] = self._tickets
        timer = self._loop.call_later(timeout_s, _resolve, future)
        try:
            await future
        finally:
            timer.cancel()
            self._waiters.pop(future, None)

    def since(self, seq: int) -> tuple[list[str], int]:
        """The events after ``seq`` as JSON texts (at most SINCE_MAX: ask again for the
        rest), and how many were missed (out of the ring)."""
        ring = self._ring
        seq = max(seq, 0)  # (before the first event: none was missed)
        if not ring or ring[-1][0] <= seq:  # type: ignore[operator]
            return [], 0
        first: int = ring[0][0]  # type: ignore[assignment]
        last: int = ring[-1][0]  # type: ignore[assignment]
        missed = first - 1 - seq if seq < first - 1 else 0
        # The ring's sequence numbers are consecutive: the events after seq are its last
        # (last - seq) entries, read from the right end (cheap on a deque).
        count = min(last - max(seq, first - 1), len(ring))
        out = []
        for k in range(count, max(count - SINCE_MAX, 0), -1):
            entry = ring[-k]
            item = entry[1]
            if not isinstance(item, str):
                item = entry[1] = as_line(item)  # type: ignore[arg-type]
            out.append(item)
        return out, missed

    def close(self) -> None:
        self.closed = True
        if self._flush is not None:
            self._flush.cancel()
            self._flush = None
        if self._waking is not None:
            self._waking.cancel()
            self._waking = None
        waiters, self._waiters = self._waiters, {}
        for future in waiters:  # all at once: they end
            _resolve(future)


class Turns:
    """At most ``per_turn`` tasks go on in one loop turn (:meth:`take`); the others wait for
    a later turn in the order they came, and each turn wakes only those it lets go."""

    def __init__(self, loop: asyncio.AbstractEventLoop, per_turn: int) -> None:
        self._loop = loop
        self.per_turn = per_turn
        self._count = 0  # gone on in this turn
        self._queue: deque[asyncio.Future[None]] = deque()
        self._next: asyncio.Handle | None = None  # the next turn's start

    async def take(self) -> None:
        """Go on in this loop turn if it has room (and nobody waits), else in a later one."""
        if self._count < self.per_turn and not self._queue:
            self._count += 1
            self._arm()
            return
        future = self._loop.create_future()
        self._queue.append(future)
        self._arm()
        try:
            await future
        except asyncio.CancelledError:
            if not future.done():
                self._queue.remove(future)
            raise

    def _arm(self) -> None:
        if self._next is None:
            self._next = self._loop.call_soon(self._new_turn)

    def _new_turn(self) -> None:
        self._next = None
        self._count = 0
        while self._queue and self._count < self.per_turn:
            future = self._queue.popleft()
            if not future.done():
                future.set_result(None)
                self._count += 1
        if self._count or self._queue:  # (the count starts again at the turn after)
            self._arm()

    def close(self) -> None:
        """Let every waiting task go on (to find what it serves closed)."""
        if self._next is not None:
            self._next.cancel()
            self._next = None
        queue, self._queue = self._queue, deque()
        for future in queue:
            _resolve(future)


def _resolve(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)
