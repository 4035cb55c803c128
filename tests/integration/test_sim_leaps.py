"""``sim`` leaps over the PLC's still scans (gateway/plc.py, ScanDriver._leap): the trace,
the report and the scans counted are those of a run that makes every scan, to the byte."""

from __future__ import annotations

import io

import pytest

from ncgate.config import load_config
from ncgate.config.script import Script, load_script
from ncgate.gateway.examples import find_example
from ncgate.gateway.sim import SimResult, report, run_sim, write_trace

from .test_machine_example import SCENARIOS


def seen(result: SimResult) -> tuple[str, str, int, int]:
    trace, summary = io.StringIO(), io.StringIO()
    write_trace(result, trace)
    report(result, summary)
    plc = result.runtime.plc
    assert plc is not None
    return trace.getvalue(), summary.getvalue(), plc.status.scans, len(result.events)


@pytest.mark.parametrize("scenario", SCENARIOS, ids=[p.stem for p in SCENARIOS])
def test_a_machine_scenario_leaps_to_the_same_bytes_as_scan_by_scan(scenario: object) -> None:
    example = find_example("machine")
    config = load_config(example.config)
    assert example.main is not None
    script = load_script(scenario)  # type: ignore[arg-type]
    times: list[float] = []  # before_time hears every step of the clock: no leap then
    every = run_sim(config, example.main, script, before_time=times.append)
    leapt = run_sim(config, example.main, script)
    assert seen(leapt) == seen(every)
    assert leapt.runtime.engine.now == every.runtime.engine.now


def test_a_run_that_ends_inside_a_leap_counts_the_scans_it_passed() -> None:
    example = find_example("plclogic")  # the program ends while the PLC stands still
    config = load_config(example.config)
    assert example.main is not None
    every = run_sim(config, example.main, Script(None, ()), before_time=lambda t: None)
    leapt = run_sim(config, example.main, Script(None, ()))
    assert seen(leapt) == seen(every)
