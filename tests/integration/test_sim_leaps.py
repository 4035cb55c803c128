"""``sim`` leaps over the PLC's still scans (gateway/plc.py, ScanDriver._leap): the trace,
the report and the scans counted are those of a run that makes every scan, to the byte."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from ncgate.config import load_config
from ncgate.config.script import Script, load_script
from ncgate.gateway.examples import find_example
from ncgate.gateway.sim import SimResult, report, run_sim, write_trace
from ncgate.plc.st.stdlib import RUNNING

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


def test_sim_leaps_over_the_scans_of_a_running_timer_to_its_due(tmp_path: Path) -> None:
    """A program waits 30 s for the logic's TON (nothing else moves): ``sim`` leaps from
    the timer's start to its due -- the timer is called a handful of times, not at each of
    3,000 scans -- to the same bytes, scans counted, as scan by scan."""
    folder = tmp_path
    (folder / "MAIN.nc").write_text("N10 (WAI,SA12=1)\nN20 M30\n")
    (folder / "plc.st").write_text("PROGRAM p VAR t : TON; END_VAR "
                                   "t(IN := TRUE, PT := T#30s); SA[12] := t.Q; END_PROGRAM")
    (folder / "ncgate.toml").write_text('[nc]\nmain = "MAIN"\nstall_s = 60\n'
                                        '[plc]\nlogic = "plc.st"\n')
    config = load_config(folder / "ncgate.toml")
    before = next(RUNNING)
    every = run_sim(config, "MAIN", Script(None, ()), before_time=lambda t: None)
    calls_every = next(RUNNING) - before
    leapt = run_sim(config, "MAIN", Script(None, ()))
    calls_leapt = next(RUNNING) - before - calls_every - 1
    assert seen(leapt) == seen(every) and leapt.outcome == "idle"
    assert every.runtime.plc is not None and every.runtime.plc.status.scans > 3000
    assert calls_every > 3000 and calls_leapt < 10
