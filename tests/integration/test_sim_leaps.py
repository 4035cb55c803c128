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


LEAPT_PAST = """PROGRAM p
VAR a : TON; t : TON; END_VAR
a(IN := TRUE, PT := T#100MS);
IF NOT a.Q AND NOT SA[20] THEN
  t(IN := TRUE, PT := T#5S);
END_IF
SA[12] := a.Q AND SA[21];
END_PROGRAM
"""


@pytest.mark.parametrize("scenario", [
    "",  # the leap lands on a's due (0.1 s), and t is not called from then on
    '[[write]]\nat = 1.005\nset = "SA20=1"\n',  # ... or on a write that stops the call
    '[[command]]\nat = 1.005\ncommand = "reload_plc"\n[[write]]\nat = 1.005\nset = "SA20=1"\n',
])
def test_a_timer_the_scans_after_a_leap_do_not_call_reads_as_scan_by_scan(
        tmp_path: Path, scenario: str) -> None:
    """A running timer's ET is moved on as the scans a leap passed would have left it, also
    when the scan the leap lands on (at another timer's due, or after a write) no longer
    calls it, and when a reload carries it over (a hostile try: 10 ms against 90 ms and
    1,000 ms)."""
    (tmp_path / "MAIN.nc").write_text("N10 (WAI,SA12=1)\nN20 M30\n")
    (tmp_path / "plc.st").write_text(LEAPT_PAST)
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "MAIN"\nstall_s = 60\n'
                                          '[plc]\nlogic = "plc.st"\n')
    (tmp_path / "s.toml").write_text(scenario + '[[write]]\nat = 2.0\nset = "SA21=1"\n')
    config, script = load_config(tmp_path / "ncgate.toml"), load_script(tmp_path / "s.toml")
    every = run_sim(config, "MAIN", script, before_time=lambda t: None)
    leapt = run_sim(config, "MAIN", script)
    assert seen(leapt) == seen(every)
    assert every.runtime.plc is not None and leapt.runtime.plc is not None
    assert leapt.runtime.plc.read("p.t.ET") == every.runtime.plc.read("p.t.ET") > 10
