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

No web library here (the HTTP side is :mod:`ncgate.gateway.web.console`).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque

from ncgate.interpreter.engine.events import Event, as_line

RING = 5000  # events kept for streams that connect or fall behind
BATCH_S = 0.05  # events reach the streams at most this often (bench/console_browser.py)
SINCE_MAX = 250  # events rendered for one read of the ring (about 0.5 ms); the rest next time


class EventFeed:
    def __init__(self, loop: asyncio.AbstractEventLoop, keep: int = RING) -> None:
        self._loop = loop
        self._pending: list[Event] = []
        # [seq, the event -- or its JSON once a stream asked for it]
        self._ring: deque[list[int | Event | str]] = deque(maxlen=keep)
        self._flush: asyncio.Handle | None = None
        self._tick: asyncio.Future[None] | None = None
        self._flushed_at = -1e9  # loop time of the last flush
        self.seq = 0  # the last event rendered
        self.closed = False

    def listen(self, event: Event) -> None:
        """The trace listener."""
        self._pending.append(event)
        if self._flush is None:
            due = self._flushed_at + BATCH_S - self._loop.time()
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
        tick, self._tick = self._tick, None
        if tick is not None and not tick.done():
            tick.set_result(None)

    async def wait(self, timeout_s: float) -> None:
        """Until new events are in (or the feed closes), at most ``timeout_s``."""
        if self._tick is None:
            self._tick = self._loop.create_future()
        # shield: one client's timeout must not cancel the future the others wait on
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout_s):
                await asyncio.shield(self._tick)

    def since(self, seq: int) -> tuple[list[str], int]:
        """The events after ``seq`` as JSON texts (at most SINCE_MAX: ask again for the
        rest), and how many were missed (out of the ring)."""
        ring = self._ring
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
        self.wake()
