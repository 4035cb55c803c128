"""The one rate-limited log: a flood gives a bounded number of lines, and what it held back is
always said -- with the next line, or on its own once the flood stops."""

from __future__ import annotations

import asyncio
import logging

import pytest

from ncgate.gateway.ratelimit import LogFlood, RateLimitedLog

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


def test_a_library_flood_is_said_in_a_few_lines_with_its_count() -> None:
    """LogFlood, on a handler: a library's lines (asyncua logs an ERROR per refused request)
    of one template at most ``burst`` per interval; the count held back comes with the next
    line of that kind, or at flush; other kinds keep their own budget."""
    records: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append(record.getMessage())

    library = logging.getLogger("ncgate.test.library")
    library.propagate = False
    handler = Keep()
    flood = LogFlood(interval_s=3600.0, burst=2)
    handler.addFilter(flood)
    library.addHandler(handler)
    try:
        for i in range(1000):
            library.error("sending service fault response: %s (%s)", "refused", i)
        library.error("another kind %d", 1)
        assert records == ["sending service fault response: refused (0)",
                           "sending service fault response: refused (1)", "another kind 1"]
        for kind in flood._kinds.values():
            kind[0] = float("-inf")  # the interval is over
        library.error("sending service fault response: %s (%s)", "refused", 1000)
        assert records[-1] == "sending service fault response: refused (1000) (and 998 more " \
                              "like it)"
        for i in range(1001, 1004):
            library.error("sending service fault response: %s (%s)", "refused", i)
        flood.flush(library)
        assert records[-1] == "2 more like: sending service fault response: refused (1003)"
        flood.flush(library)  # said once
        assert len(records) == 6
    finally:
        library.removeHandler(handler)
