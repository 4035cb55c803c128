"""The one rate-limited log: a flood gives a bounded number of lines, and what it held back is
always said -- with the next line, or on its own once the flood stops."""

from __future__ import annotations

import asyncio
import logging

import pytest

from ncgate.gateway.ratelimit import RateLimitedLog

log = logging.getLogger("ncgate.test.ratelimit")


def lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == log.name]


def test_a_flood_gives_one_line_and_the_count_comes_with_the_next(
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    limited = RateLimitedLog(log, interval_s=3600.0)
    for i in range(621):
        limited.note(f"connect {i}")
    assert lines(caplog) == ["connect 0"]
    limited.window = float("-inf")  # the interval is over
    limited.note("connect 621")
    assert lines(caplog) == ["connect 0", "connect 621 (and 620 more like it)"]


def test_the_count_is_said_at_flush_even_when_nothing_follows(
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    limited = RateLimitedLog(log, interval_s=3600.0, burst=2)
    assert [limited.take() for _ in range(5)] == [True, True, False, False, False]
    limited.note("x")
    limited.flush()
    assert lines(caplog) == ["4 more like: x"]
    limited.flush()  # said once
    assert len(lines(caplog)) == 1


async def test_on_a_loop_the_count_is_said_once_the_flood_stops(
        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    said = asyncio.Event()

    class Flag(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if "more" in record.getMessage():
                said.set()

    handler = Flag()
    log.addHandler(handler)
    try:
        limited = RateLimitedLog(log, interval_s=0.05, held="%d more sync events")
        for _ in range(10):
            limited.note("event")
        async with asyncio.timeout(5):
            await said.wait()  # no further line came: the timer said it
    finally:
        log.removeHandler(handler)
    assert lines(caplog) == ["event", "9 more sync events"]
