"""The trace keeps everything (sim) or a ring of the latest events (run); listeners see all."""

from __future__ import annotations

import json

import pytest

from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.trace import Trace, to_jsonl


def record(trace: Trace, count: int) -> None:
    for i in range(count):
        trace.record(ev.Write, i / 10, 0, None, "SA10", i % 2, "test")


def test_a_trace_that_keeps_everything() -> None:
    trace = Trace()
    record(trace, 50)
    assert [e["seq"] for e in trace.events] == list(range(1, 51))


def test_a_ring_keeps_the_latest_events_and_listeners_hear_every_one() -> None:
    trace = Trace(keep=10)
    heard: list[int] = []
    trace.subscribe(lambda e: heard.append(e.seq))
    record(trace, 1000)
    assert [e["seq"] for e in trace.events] == list(range(991, 1001))
    assert heard == list(range(1, 1001))
    assert trace.seq == 1000


def test_a_listener_that_raises_stops_neither_the_others_nor_the_recording(
        caplog: pytest.LogCaptureFixture) -> None:
    """One failing adapter (a listener) must not abort the engine's step: the event is kept,
    the listeners after it hear it, and the failure is logged once with its traceback."""
    trace = Trace()
    heard: list[int] = []

    def broken(event: ev.Event) -> None:
        raise RuntimeError("Not connected to CAN bus")

    trace.subscribe(broken)
    trace.subscribe(lambda e: heard.append(e.seq))
    with caplog.at_level("ERROR", logger="ncgate.trace"):
        record(trace, 5)  # raised out of the first record before
    assert heard == [1, 2, 3, 4, 5]
    assert [e["seq"] for e in trace.events] == [1, 2, 3, 4, 5]
    failures = [r for r in caplog.records if r.name == "ncgate.trace"]
    assert len(failures) == 1 and failures[0].exc_info is not None
    assert "broken" in failures[0].getMessage() and "event 1" in failures[0].getMessage()
    assert [f.count for f in trace.listener_failures.values()] == [5]


def test_a_ring_of_zero_keeps_nothing_but_counts() -> None:
    trace = Trace(keep=0)
    trace.record(ev.Snd, 0.0, 1, ("A.nc", 3, 30), 2)
    assert trace.events == [] and trace.seq == 1 and trace.counter == 1
    with pytest.raises(ValueError):
        Trace(keep=-1)


def test_jsonl_has_six_decimals_and_the_spec_key_order() -> None:
    trace = Trace()
    trace.record(ev.Snd, 1.5, 1, ("A.nc", 3, 30), 2)
    line = to_jsonl(trace.events[0])
    assert line.startswith('{"seq": 1, "t": 1.500000, "event": "snd", "proc": 1, "prog": "A.nc"')
    assert json.loads(line)["to"] == 2


def test_a_failing_listeners_count_is_said_when_it_goes(caplog: pytest.LogCaptureFixture) -> None:
    """A burst of failures within the minute is not lost: its listener's unsubscribe says
    the count, and a second unsubscribe does nothing."""
    trace = Trace()

    def broken(event: ev.Event) -> None:
        raise OSError("disk full")

    unsubscribe = trace.subscribe(broken)
    with caplog.at_level("ERROR", logger="ncgate.trace"):
        record(trace, 7)
        unsubscribe()
        unsubscribe()
        record(trace, 1)  # heard by nobody now
    lines = [r.getMessage() for r in caplog.records if r.name == "ncgate.trace"]
    assert len(lines) == 2 and "failed 7 times in all" in lines[1]
    assert trace.listener_failures == {}
