"""Structured Text as real libraries write it (OSCAT, blark's TwinCAT samples): the issue
"What the field found".  Each test failed before its fix."""

from __future__ import annotations

from collections.abc import Iterator

from ncgate.plc.scan import PlcState

from .st_harness import Plc, program


def _ticking(step_ns: int) -> Iterator[int]:
    now = 0
    while True:
        yield now
        now += step_ns


def test_a_straight_line_scan_over_the_watchdog_faults_and_counts_in_max_scan_us() -> None:
    # 3,000 assignments and no loop: the guard between loop chunks never runs.  The clock
    # the scan reads moves 100 ms at each look, so the scan takes longer than 1 ms whatever
    # the machine's speed.
    body = "\n".join(f"x := x + {i % 7};" for i in range(3000)) + "\nSA[1] := TRUE;"
    plc = Plc(program(body, "x : DINT;"))
    plc.runtime.watchdog_ms = 1
    ticks = _ticking(100_000_000)
    plc.runtime.clock_ns = lambda: next(ticks)
    plc.scan()
    status = plc.runtime.status
    assert status.state is PlcState.FAULT
    assert status.fault is not None and "watchdog" in status.fault.message
    assert status.max_scan_us >= 1000  # the faulted scan's time is counted
    assert plc.writes == []  # its outputs are dropped
    assert status.scans == 0
