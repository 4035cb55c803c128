"""The console's event feed renders lazily and in bounded pieces: a busy cell with no page open
costs a list append per event, and no read of the ring renders more than SINCE_MAX."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from ncgate.gateway.web.feed import (
    BATCH_BEHIND_S,
    BATCH_S,
    SINCE_MAX,
    WAKE_PER_TURN,
    EventFeed,
    Turns,
)
from ncgate.interpreter.engine import events as ev


async def test_nothing_is_rendered_until_asked_and_a_read_is_bounded() -> None:
    feed = EventFeed(asyncio.get_running_loop())
    for seq in range(1, 2001):
        feed.listen(ev.Hazard(seq, seq / 1000, 1, None, f"h{seq}"))
    feed.flush()
    assert feed.seq == 2000
    assert not any(isinstance(item, str) for _, item in feed._ring)  # nothing rendered yet
    texts, missed = feed.since(0)
    assert (len(texts), missed) == (SINCE_MAX, 0) and '"message": "h1"' in texts[0]
    texts, _ = feed.since(SINCE_MAX)  # the next piece, from where the first stopped
    assert f'"message": "h{SINCE_MAX + 1}"' in texts[0]
    rendered = sum(isinstance(item, str) for _, item in feed._ring)
    assert rendered == 2 * SINCE_MAX  # kept rendered for the next reader


class _Ticks:
    """Counts the loop's turns: a callback that schedules itself again each turn."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop, self.now, self._handle = loop, 0, loop.call_soon(self._tick)

    def _tick(self) -> None:
        self.now += 1
        self._handle = self.loop.call_soon(self._tick)

    def stop(self) -> None:
        self._handle.cancel()


async def test_a_batch_wakes_its_waiting_streams_a_few_per_loop_turn_in_order() -> None:
    """Fifty streams waiting for one batch: at most WAKE_PER_TURN go on in one loop turn, in
    the order they began waiting (one shared future woke all fifty in one turn: 5-11 ms that
    the PLC scan and the pollers waited behind).  A stream that begins waiting after the
    batch is not woken by it; a wait still ends at its timeout; close ends every wait."""
    loop = asyncio.get_running_loop()
    feed = EventFeed(loop)
    woke: list[tuple[int, int]] = []  # (stream, turn)
    late: list[asyncio.Task[None]] = []

    async def stream(n: int) -> None:
        await feed.wait(60)
        woke.append((n, ticks.now))
        if n == 0:  # a stream that begins waiting while the batch wakes the others
            late.append(asyncio.create_task(feed.wait(60)))

    tasks = [asyncio.create_task(stream(n)) for n in range(50)]
    await asyncio.sleep(0)  # all fifty wait
    ticks = _Ticks(loop)
    feed.listen(ev.Hazard(1, 0.001, 1, None, "h1"))  # a batch (flushed soon: none before)
    await asyncio.gather(*tasks)
    ticks.stop()
    assert [n for n, _ in woke] == list(range(50))
    per_turn = [sum(1 for _, t in woke if t == turn) for turn in {t for _, t in woke}]
    assert max(per_turn) <= WAKE_PER_TURN and len(per_turn) >= 50 // WAKE_PER_TURN
    assert not late[0].done()  # began waiting after the batch
    timed = asyncio.create_task(feed.wait(0.01))
    async with asyncio.timeout(5):
        await timed  # its timeout ends it
    feed.close()
    async with asyncio.timeout(5):
        await late[0]
    assert feed._waiters == {}


async def test_turns_let_a_few_tasks_go_on_per_loop_turn_and_wake_only_those() -> None:
    loop = asyncio.get_running_loop()
    turns = Turns(loop, 8)
    went: list[tuple[int, int]] = []

    async def task(n: int) -> None:
        await turns.take()
        went.append((n, ticks.now))

    ticks = _Ticks(loop)
    tasks = [asyncio.create_task(task(n)) for n in range(50)]
    cancelled = asyncio.create_task(turns.take())
    await asyncio.sleep(0)
    cancelled.cancel()  # a task that gives up its place in the queue leaves it
    await asyncio.gather(*tasks)
    ticks.stop()
    assert [n for n, _ in went] == list(range(50))
    per_turn = [sum(1 for _, t in went if t == turn) for turn in {t for _, t in went}]
    assert max(per_turn) <= 8
    assert all(future.done() for future in turns._queue) or not turns._queue
    # Each turn lets go only those it wakes: the ones still waiting stay asleep.
    waiting = [asyncio.create_task(turns.take()) for _ in range(24)]
    await asyncio.sleep(0)
    await asyncio.sleep(0)
    assert sum(t.done() for t in waiting) <= 8 + 8
    turns.close()  # the rest go on at once
    async with asyncio.timeout(5):
        await asyncio.gather(*waiting)


class _StillClock:
    """The running loop, but its clock stands still (a test reads what a delay was set to,
    not how long anything took)."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self.delays: list[float] = []

    def time(self) -> float:
        return 1000.0

    def call_later(self, delay: float, callback: Any, *args: Any) -> asyncio.TimerHandle:
        self.delays.append(delay)
        return self._loop.call_later(delay, callback, *args)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._loop, name)


async def test_while_the_engine_is_behind_a_batch_waits_longer() -> None:
    """The streams' writes took the loop from an engine behind the clock (the PLC scan
    80-150 ms late under 50 pages): while it is behind, the next batch is due BATCH_BEHIND_S
    after the last, not BATCH_S."""
    clock = _StillClock(asyncio.get_running_loop())
    behind = False
    feed = EventFeed(clock, behind=lambda: behind)  # type: ignore[arg-type]
    for late in (False, True):
        behind = late
        feed.flush()  # (at the clock's now)
        feed.listen(ev.Hazard(1, 0.0, 1, None, "next"))
        assert feed._flush is not None
        feed._flush.cancel()
        feed._flush = None
    assert clock.delays == pytest.approx([BATCH_S, BATCH_BEHIND_S])
