"""The engine on the wall clock gives the loop's sockets their turn between its own turns.

A turn that runs out of time (``TURN_S``) goes on after what the sockets have ready: a
request that arrived while a turn ran is answered after that turn, not after the next one
too (docs/decisions.md, "A turn of the engine yields to the sockets").  Counted in turns,
not timed: each turn here runs one timer (``TURN_S`` = 0), and the first timer is what sends
the request.
"""

from __future__ import annotations

import asyncio
import itertools
import socket
import time
from collections.abc import Callable

import pytest

from ncgate.gateway import wallclock
from ncgate.gateway.wallclock import WallClockDriver

from ...helpers import make_sim

TIMERS = 20


def _loop_factory(kind: str) -> Callable[[], asyncio.AbstractEventLoop]:
    if kind == "uvloop":
        uvloop = pytest.importorskip("uvloop")
        return uvloop.new_event_loop  # type: ignore[no-any-return]
    return asyncio.new_event_loop


def _heard(kind: str, times: list[float], sent_at: tuple[int, ...],
           behind_s: float = 0.0) -> tuple[list[int], list[int]]:
    """Run engine timers at ``times`` on a wall-clock driver started ``behind_s`` ago (every
    timer before then is due at once); those numbered in ``sent_at`` send a request on a
    socket the loop reads.  The timers fired, in order, and for each request read, how many
    timers had fired when it was read."""
    engine = make_sim({"A": "N1M30\n"}).engine
    server, client = socket.socketpair()
    server.setblocking(False)
    fired: list[int] = []
    heard: list[int] = []

    def timer(i: int) -> None:
        fired.append(i)
        if i in sent_at:
            client.send(b"request")

    for i, t in enumerate(times):
        engine.call_at(t, lambda i=i: timer(i))

    async def main() -> None:
        loop = asyncio.get_running_loop()

        def readable() -> None:
            server.recv(64)
            heard.append(len(fired))

        loop.add_reader(server, readable)
        driver = WallClockDriver(engine, 1.0, loop)
        driver.t0 -= behind_s
        try:
            driver.kick()
            async with asyncio.timeout(10):
                while len(fired) < len(times):
                    driver.changed.clear()
                    await driver.changed.wait()
        finally:
            loop.remove_reader(server)
            driver.close()

    try:
        with asyncio.Runner(loop_factory=_loop_factory(kind)) as runner:
            runner.run(main())
    finally:
        server.close()
        client.close()
    return fired, heard


@pytest.mark.parametrize("kind", ["asyncio", "uvloop"])
def test_a_request_that_arrives_during_a_turn_waits_for_that_turn_only(
        kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(wallclock, "TURN_S", 0.0)  # every turn is over after one timer
    fired, heard = _heard(kind, [0.0] * TIMERS, sent_at=(0,))  # arrives during the first turn
    assert fired == list(range(TIMERS))  # all of them, in order, each once
    assert heard == [1]  # read right after the turn it arrived in (asyncio gave 2 with call_soon)


def test_a_timer_that_raises_leaves_the_clock_running_for_the_next(
        caplog: pytest.LogCaptureFixture) -> None:
    engine = make_sim({"A": "N1M30\n"}).engine
    fired: list[str] = []

    def broken() -> None:
        raise ZeroDivisionError("a bug in a timer's callback")

    engine.call_at(0.0, broken)
    engine.call_at(0.002, lambda: fired.append("next"))

    async def main() -> None:
        driver = WallClockDriver(engine, 1.0, asyncio.get_running_loop())
        try:
            driver.kick()
            async with asyncio.timeout(10):  # hangs for ever if nothing re-arms the clock
                while not fired:
                    driver.changed.clear()
                    await driver.changed.wait()
        finally:
            driver.close()

    asyncio.run(main())
    assert fired == ["next"]
    assert "a bug in a timer's callback" in caplog.text  # the loop logged it


@pytest.mark.parametrize("kind", ["asyncio", "uvloop"])
def test_the_clock_reads_finer_than_a_millisecond(kind: str) -> None:
    """uvloop's loop.time() counts whole milliseconds: the driver's clock is its own, so an
    input (``catch_up``) and a status read (``now``) a tenth of a millisecond apart are a
    tenth of a millisecond apart, and a scan's lateness is in microseconds."""
    engine = make_sim({"A": "N1M30\n"}).engine
    seen: list[tuple[float, float]] = []

    async def main() -> None:
        driver = WallClockDriver(engine, 1.0, asyncio.get_running_loop())
        try:
            for _ in range(30):  # 30 readings 0.1 ms apart: 3 ms, a whole ms many times over
                mark = time.monotonic()
                while time.monotonic() - mark < 0.0001:
                    pass
                driver.catch_up()  # an input: the engine at the clock's now
                seen.append((driver.now(), engine.now))
        finally:
            driver.close()

    with asyncio.Runner(loop_factory=_loop_factory(kind)) as runner:
        runner.run(main())
    for (now_before, input_before), (now, input_at) in itertools.pairwise(seen):
        assert now > now_before, seen  # the old driver on uvloop: equal within each ms
        assert input_at > input_before, seen


@pytest.mark.parametrize("behind", [False, True])
def test_an_engine_behind_the_clock_gets_a_fieldbus_rounds_turn(
        monkeypatch: pytest.MonkeyPatch, behind: bool) -> None:
    """A turn is TURN_S (here: one timer); an engine BEHIND_S behind gets TURN_BEHIND_S (here:
    all of them), as long as a fieldbus round: under a flood's rounds the short turns left the
    PLC scan 28 ms late.  Counted in turns, not timed."""
    monkeypatch.setattr(wallclock, "TURN_S", 0.0)
    monkeypatch.setattr(wallclock, "TURN_BEHIND_S", 60.0)
    monkeypatch.setattr(wallclock, "TURN_BEHIND_MAX_S", 60.0)
    engine = make_sim({"A": "N1M30\n"}).engine
    fired: list[int] = []
    for i in range(TIMERS):
        engine.call_at(0.0, lambda i=i: fired.append(i))

    async def main() -> int:
        driver = WallClockDriver(engine, 1.0, asyncio.get_running_loop())
        # (as the last turn that ran out of time noted it)
        driver.lag_s = wallclock.BEHIND_S if behind else 0.0
        try:
            before = driver.turns
            driver.kick()
            while len(fired) < TIMERS:
                driver.changed.clear()
                await driver.changed.wait()
            return driver.turns - before
        finally:
            driver.close()

    turns = asyncio.run(main())
    assert turns <= 2 if behind else turns >= TIMERS  # (and the one that finds nothing left)
    assert fired == list(range(TIMERS))


def test_the_further_behind_the_longer_the_turn_up_to_a_poll_s_bound() -> None:
    """Under a flood on a host where the cell's own work took 2/3 of a core, 0.5 ms turns left
    the engine behind for good (the PLC scan 116-300 ms late): a turn grows with the lag,
    TURN_BEHIND_S for each BEHIND_S, and stops at TURN_BEHIND_MAX_S (what a poll may wait:
    2 ms put the poller's p99 over 5 ms)."""
    behind, turn = wallclock.BEHIND_S, wallclock.TURN_BEHIND_S
    assert wallclock.turn_length(0.0) == wallclock.turn_length(0.99 * behind) == \
        wallclock.TURN_S
    assert wallclock.turn_length(behind) == pytest.approx(turn)
    assert wallclock.turn_length(1.5 * behind) == pytest.approx(1.5 * turn)
    assert wallclock.turn_length(1000 * behind) == wallclock.TURN_BEHIND_MAX_S
    assert wallclock.TURN_S < turn < 1.5 * turn <= wallclock.TURN_BEHIND_MAX_S <= 0.001


@pytest.mark.parametrize("kind", ["asyncio", "uvloop"])
def test_behind_the_clock_a_loop_pass_runs_one_turn(
        kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Timers due in the past, at different times: each turn (one timer here) is followed by
    a poll, so a request that arrives during a turn is read after that turn.  The loop timer
    that fired used to drop the pending turn's handle without cancelling it, and each turn
    after queued one more: a pass ran 6-7 turns behind 100 switching plant models."""
    monkeypatch.setattr(wallclock, "TURN_S", 0.0)
    monkeypatch.setattr(wallclock, "TURN_BEHIND_S", 0.0)
    sent_at = (10, 25)  # timers that send a request while they run
    # Started 20 ms ago: every timer is due, the driver is behind.
    fired, heard = _heard(kind, [0.0001 * i for i in range(2 * TIMERS)], sent_at, 0.02)
    assert fired == list(range(2 * TIMERS))
    assert heard == [i + 1 for i in sent_at]  # each read right after the turn it came in
