"""The live stream's source: trace events for every console client, kept once.

A trace listener only appends the typed event (it is on the path of every SND and WAI); at
most once per BATCH_S (at once when the last batch is older) the new events are rendered to
JSON, kept in one shared ring, and every waiting stream is woken.  So a stream sends at most
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
import json
from collections import deque

from ncgate.interpreter.engine.events import Event, as_dict

RING = 5000  # events kept for streams that connect or fall behind
BATCH_S = 0.05  # events reach the streams at most this often (bench/console_browser.py)


class EventFeed:
    def __init__(self, loop: asyncio.AbstractEventLoop, keep: int = RING) -> None:
        self._loop = loop
        self._pending: list[Event] = []
        self._ring: deque[tuple[int, str]] = deque(maxlen=keep)  # (seq, JSON)
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
        for event in pending:
            self._ring.append((event.seq, json.dumps(as_dict(event), separators=(",", ":"))))
            self.seq = event.seq
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
        """The events after ``seq`` as JSON texts, and how many were missed (out of the ring)."""
        ring = self._ring
        if not ring or ring[-1][0] <= seq:
            return [], 0
        first = ring[0][0]
        if seq < first - 1:
            return [text for _, text in ring], first - 1 - seq
        # The ring's sequence numbers are consecutive: the events after seq are its last
        # (last - seq) entries, read from the right end (cheap on a deque).
        count = ring[-1][0] - seq
        return [ring[-k][1] for k in range(count, 0, -1)], 0

    def close(self) -> None:
        self.closed = True
        if self._flush is not None:
            self._flush.cancel()
            self._flush = None
        self.wake()
