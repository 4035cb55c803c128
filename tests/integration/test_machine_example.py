"""examples/machine: its scenario suite run as a user runs it (`ncgate sim --example machine`,
a process of its own), every expectation passing and listed in the JUnit file; and a bad case
without its fault failing, so that its expectations say something about the fault."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

from ..conftest import EXAMPLES

FOLDER = EXAMPLES / "machine"
SCENARIOS = sorted((FOLDER / "scenarios").glob("*.toml"))


def ncgate(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ncgate", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120, check=False)


def verdict_lines(out: str) -> list[str]:
    return [line for line in out.splitlines() if line.startswith(("PASS ", "FAIL "))]


def bit_edges(trace: Path, var: str) -> list[tuple[float, int]]:
    """Each change of ``var`` in a trace file, as (time, value)."""
    edges: list[tuple[float, int]] = []
    for line in trace.read_text().splitlines():
        e = json.loads(line)
        if e["event"] == "write" and e["var"] == var and (
                not edges or edges[-1][1] != e["value"]):
            edges.append((e["t"], e["value"]))
    return edges


def traced(tmp_path: Path, scenario: str, *extra: str, name: str = "t.jsonl") -> Path:
    """Run one of the suite's scenarios with a trace (passing: exit 0); the trace file."""
    trace = tmp_path / name
    done = ncgate("sim", "--config", str(FOLDER / "ncgate.toml"), "--script",
                  str(FOLDER / "scenarios" / f"{scenario}.toml"), *extra, "--trace",
                  str(trace), cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    return trace


def events_in(trace: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in trace.read_text().splitlines()]


def expects_of(path: Path) -> list[dict[str, Any]]:
    with path.open("rb") as f:
        expects: list[dict[str, Any]] = tomllib.load(f).get("expect", [])
    return expects


def test_the_suite_passes_and_its_junit_file_lists_every_scenario(tmp_path: Path) -> None:
    junit = tmp_path / "verdicts.xml"
    done = ncgate("sim", "--example", "machine", "--junit", str(junit), cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    lines = verdict_lines(done.stdout)
    assert lines and all(line.startswith("PASS ") for line in lines), done.stdout
    assert len(lines) == sum(len(expects_of(p)) for p in SCENARIOS)
    # a good case and at least five bad ones, each with an expectation and a fault (or,
    # program_reset_and_restarted, an operator's abort: an NC reset mid-program)
    assert len(SCENARIOS) >= 6 and (FOLDER / "scenarios" / "good.toml") in SCENARIOS
    for path in SCENARIOS:
        with path.open("rb") as f:
            table = tomllib.load(f)
        assert table.get("expect"), path.name
        assert bool(table.get("fault") or path.name == "program_reset_and_restarted.toml") \
            == (path.name != "good.toml"), path.name
    assert sum(bool(tomllib.loads(p.read_text()).get("fault")) for p in SCENARIOS) >= 5
    suites = {Path(s.get("name", "")).name: s for s in ET.parse(junit).getroot()}
    assert set(suites) == {p.name for p in SCENARIOS}
    for path in SCENARIOS:
        suite = suites[path.name]
        assert suite.get("failures") == "0"
        assert [case.get("name") for case in suite] == [e["name"] for e in expects_of(path)]


def test_a_bad_case_without_its_fault_fails_its_expectations(tmp_path: Path) -> None:
    """clamp_never_closes expects the PLC's clamp alarm and a held cell: with the clamp
    working they do not come, and the run says so (exit 1, a FAIL line each)."""
    lines = []
    for e in expects_of(FOLDER / "scenarios" / "clamp_never_closes.toml"):
        lines.append("[[expect]]")
        # a TOML basic string is a JSON string; numbers, lists and true are the same in both
        lines += [f"{key} = {json.dumps(value)}" for key, value in e.items()]
    script = tmp_path / "clamp_works.toml"
    script.write_text("\n".join(lines) + "\n", encoding="utf-8")
    done = ncgate("sim", "--example", "machine", "--script", str(script), cwd=tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    failed = {line.split(":")[0].removeprefix("FAIL ")
              for line in verdict_lines(done.stdout) if line.startswith("FAIL ")}
    assert {"clamp alarm", "cell holds", "spindle never starts", "no part counted"} <= failed



def test_the_operators_reset_clears_a_latched_alarm_once_its_cause_is_gone(
        tmp_path: Path) -> None:
    """A latched alarm holds the cell until alarm_reset (SA48) rises with its cause gone; a
    reset while the clamp is still jammed latches it again (a new user found no way to clear
    one but a restart of the gateway: restart_plc leaves a running PLC alone)."""
    script = tmp_path / "reset.toml"
    script.write_text(
        '[[fault]]\ntarget = "clamp"\nkind = "never"\nfor_s = 2.0\n'  # freed at 2 s
        '[[write]]\nat = 1.5\nset = "alarm_reset=1"\n'  # the cause is still there
        '[[write]]\nat = 1.6\nset = "alarm_reset=0"\n'
        '[[write]]\nat = 3.0\nset = "alarm_reset=1"\n'  # closed at 2.3 s: gone
        '[[expect]]\nname = "latched"\ncond = "clamp_alarm=1"\nwithin = [1.0, 1.1]\n'
        '[[expect]]\nname = "a reset with the cause there"\ncond = "clamp_alarm=1"\n'
        'within = [1.55, 2.9]\n'
        '[[expect]]\nname = "cleared by the reset"\ncond = "clamp_alarm=0"\n'
        'within = [3.0, 3.02]\n'
        '[[expect]]\nname = "the cell no longer held by the PLC"\ncond = "any_alarm=0"\n'
        'within = [3.0, 3.02]\n')
    trace = tmp_path / "t.jsonl"
    done = ncgate("sim", "--example", "machine", "--script", str(script), "--until", "4",
                  "--trace", str(trace), cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert len(verdict_lines(done.stdout)) == 4
    edges = bit_edges(trace, "SA50")
    # latched once, never let go by the first reset, let go by the second
    assert [v for _, v in edges if v == 1] == [1] and edges[-1][1] == 0, edges
    assert 1.0 < next(t for t, v in edges if v == 1) < 1.1
    assert 3.0 <= edges[-1][0] < 3.02


@pytest.mark.parametrize(("scenario", "alarm", "alarm_edges", "output"), [
    ("spindle_reset_while_slow", "SA52", [(3.24, 1), (4.21, 0)], "SA21"),
    ("io_device_silent", "SA54", [(4.02, 1)], "SA25"),
    ("door_switch_chatters", "SA51", [(4.27, 1)], "SA21"),
    ("coolant_pressure_low", "SA55", [(4.47, 1)], "SYVAR13")])
def test_a_reset_with_the_cause_still_there_leaves_the_alarm_not_one_scan_cleared(
        tmp_path: Path, scenario: str, alarm: str, alarm_edges: list[tuple[float, int]],
        output: str) -> None:
    """The scenarios' windows see moments; the trace sees every scan.  A reset while the
    program still asks for what the device did not do (the spindle's run-up at 3.5 s, M03 in
    force; the line pressure at 4.6 s, M08 in force; the tool change at 6.5 s, after the NC's
    AL145 dropped its strobe), or while the door switch chatters (5.525 s, reading closed),
    neither drops the alarm for a scan nor starts the device again; after the NC reset
    (4.0 s) a reset clears the spindle's.  (The rule before cleared the first three, and
    started the spindle: into the same fault, or for the 40 ms until the switch read open;
    the pressure had no alarm.)"""
    trace = traced(tmp_path, scenario)
    assert bit_edges(trace, alarm) == alarm_edges
    assert bit_edges(trace, output)[-1] == (alarm_edges[0][0], 0)  # off with the alarm


def overrides(trace: Path) -> list[tuple[float, int]]:
    """Each change of P1's feed override in a trace file, as (time, percent)."""
    return [(e["t"], e["feed"]) for e in map(json.loads, trace.read_text().splitlines())
            if e["event"] == "override"]


def test_a_reset_after_a_mended_fault_starts_nothing_until_a_cycle_start(
        tmp_path: Path) -> None:
    """coolant_wire_mended: the reset at 4.0 s clears the alarm with M03 and M08 in force
    and P1 held; the spindle and the pump start at the cycle start (4.3 s; the scan after
    it), not in between (they did at 4.0 s: a reset started the machine), and the feed
    stands at 0 % from the alarm until both are back (the cut resumed at once, the spindle
    at rest)."""
    trace = traced(tmp_path, "coolant_wire_mended")
    assert bit_edges(trace, "SA21") == [(2.23, 1), (3.47, 0), (4.31, 1)]  # spindle_run
    assert bit_edges(trace, "SYVAR13") == [(2.72, 600), (3.47, 0), (4.31, 600)]  # the pump
    # the cut waits for the spindle (at speed 4.79 s) and the pressure (4.83 s)
    assert [o for o in overrides(trace) if o[0] > 3.4] == [(3.47, 0), (4.83, 100)]


def test_an_alarm_with_the_cell_idle_moves_nothing(tmp_path: Path) -> None:
    """coolant_wire_break_idle: the wire breaks (0.5 s) with P1 idle, the door and the clamp
    open.  The PLC never turns a valve or the lock on (the rule before closed the clamp and
    the door, and locked it: an alarm drove the door shut on the operator's hand).  The
    scenario's windows see moments; the trace sees every scan."""
    trace = traced(tmp_path, "coolant_wire_break_idle")
    assert bit_edges(trace, "SA53") == [(0.51, 1)]  # coolant_alarm: the scan after the fault
    # clamp_valve, door_valve, door_lock: never written, the plant's switches never move
    assert [bit_edges(trace, var) for var in ("SA20", "SA22", "SA23")] == [[], [], []]
    assert bit_edges(trace, "SA42")[-1] == (0.0, 1)  # door_open


def test_after_an_alarm_with_the_cell_idle_one_cycle_start_starts_the_program(
        tmp_path: Path) -> None:
    """coolant_wire_mended_idle: the PLC's alarm (0.51 s, P1 idle) holds no idle program, so
    the one cycle start after the reset (1.2 s) starts PART.  (NC.HOLD_LEVEL := any_alarm held
    the idle P1, and that cycle start only released the hold: nothing started, no word of it
    but a hold event.)  A cycle start while the alarm stands is refused, by the config's
    inhibit input, not taken into a hold."""
    trace = traced(tmp_path, "coolant_wire_mended_idle")
    events = events_in(trace)
    assert not [e for e in events if e["event"] == "hold"]
    assert [(e["t"], e["by"]) for e in events if e["event"] == "start"] == [
        (0.0, "script"), (1.2, "script command[1]")]
    trace = traced(tmp_path, "coolant_wire_break_idle", name="refused.jsonl")
    events = events_in(trace)
    assert [(e["t"], e["message"]) for e in events if e["event"] == "hazard"] == [
        (1.0, "script command[1]: cycle_start: cycle start inhibit input SA49 is set")]
    assert [e["t"] for e in events if e["event"] == "start"] == [0.0]


def test_a_program_restarted_after_an_nc_reset_asks_afresh_and_the_aborted_one_is_no_part(
        tmp_path: Path) -> None:
    """program_reset_and_restarted: NC.P[1].M still reads 3 after the NC reset (2.4 s).  The
    restarted program's spindle waits for its own M03, after the tool change (the standing
    M03 started it as the part was clamped, 2.8 s: the changer never started, AL145 at
    7.8 s), and the aborted program counts no part (it counted one at 2.4 s)."""
    trace = traced(tmp_path, "program_reset_and_restarted", "--until", "8")
    assert bit_edges(trace, "SA21") == [(2.23, 1), (2.41, 0), (4.04, 1)]  # spindle_run
    assert bit_edges(trace, "SA25") == [(1.01, 1), (2.22, 0), (2.82, 1), (4.03, 0)]  # changer
    events = events_in(trace)
    assert not [e for e in events if e["event"] == "alarm"]
    assert bit_edges(trace, "SYVAR20") == []  # parts


@pytest.mark.parametrize("case", ["slow clamp", "fault only"])
def test_a_cell_the_plc_holds_ends_as_a_stall_naming_the_hold(tmp_path: Path,
                                                               case: str) -> None:
    """The field's report: a clamp slower than the PLC's 1 s (or one that never closes, a
    script with the fault and no expectation) has the PLC hold the cell for ever through
    NC.HOLD_LEVEL, and `sim` ran at 100 % CPU until killed (the timeout guards that).  It
    ends nc.stall_s (60 s) after the last change, a stall naming the held process, by whom
    and since when; the hold counts as waiting, not running."""
    if case == "slow clamp":
        args = ["--set", "plant.model.clamp.travel_ms=1200"]
        last_change, where = 1.2, "P1 PART.nc:5 N30 held since 1.010 s"
    else:
        script = tmp_path / "never.toml"
        script.write_text('[[fault]]\ntarget = "clamp"\nkind = "never"\n')
        args = ["--script", str(script)]
        last_change, where = 1.01, ("P1 PART.nc:4 N20 (WAI,SA30=1) waits for clamped (SA30=1) "
                                    "(now 0); held since 1.010 s")
    done = subprocess.run([sys.executable, "-m", "ncgate", "sim", "--config",
                           str(FOLDER / "ncgate.toml"), *args], cwd=tmp_path,
                          capture_output=True, text=True, timeout=90, check=False)
    assert done.returncode == 1, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == (f"[{last_change + 60:.3f}] stall: every process is blocked and "
                        "nothing can change")
    hold_line = next(i for i, text in enumerate(
        (FOLDER / "plc.st").read_text().splitlines(), 1) if "NC.HOLD_LEVEL :=" in text)
    assert lines[1].strip() == (f"{where} (feed hold by plc plc.st:{hold_line}): a cycle "
                                "start goes on")
    p1 = next(line.split() for line in lines if line.startswith("P1 "))
    assert (p1[3], p1[4], p1[-1]) == ("0.000", f"{last_change + 60:.3f}", "HOLD")
    assert lines[-1] == f"simulated {last_change + 60:.3f} s: stall"


def test_the_readme_names_every_scenario() -> None:
    readme = (FOLDER / "README.md").read_text(encoding="utf-8")
    assert readme.splitlines()[0].startswith("# machine: ")
    assert all(f"`{p.name}`" in readme for p in SCENARIOS)


EXTERNAL_SCENARIO = """
# clamp_never_closes with a real PLC: the test process over Modbus, the ST logic off.
[[fault]]
target = "clamp"
kind = "never"
[[expect]]
name = "the PLC raises its clamp alarm"
cond = "clamp_alarm=1"
by = 4.0
[[expect]]
name = "the cell holds"
cond = "P1 HOLD"
by = 4.0
[[expect]]
name = "never clamped"
cond = "clamped=0"
always = true
[[expect]]
name = "no NC alarm"
cond = "no alarm"
always = true
"""


async def _external_plc(port: int) -> None:
    """The part of plc.st this case needs, as a PLC over Modbus would run it: close and lock
    the door, say so, close the clamp, and give it 1 s before the clamp alarm and a hold."""
    import asyncio

    from pymodbus.client import AsyncModbusTcpClient

    coil = {"clamp_valve": 20, "door_valve": 22, "door_lock": 23, "door_ready": 33,
            "clamp_closed": 40, "door_closed": 43, "door_locked": 44, "clamp_alarm": 50}
    client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0)
    assert await client.connect()
    loop = asyncio.get_running_loop()

    async def until(name: str, timeout_s: float) -> bool:
        deadline = loop.time() + timeout_s
        while loop.time() < deadline:
            if (await client.read_coils(coil[name], count=1, device_id=1)).bits[0]:
                return True
            await asyncio.sleep(0.01)  # a PLC's scan: it polls its inputs
        return False

    try:
        await client.write_coil(coil["door_valve"], True, device_id=1)
        assert await until("door_closed", 5.0)
        await client.write_coil(coil["door_lock"], True, device_id=1)
        assert await until("door_locked", 5.0)
        await client.write_coil(coil["door_ready"], True, device_id=1)
        await client.write_coil(coil["clamp_valve"], True, device_id=1)
        if not await until("clamp_closed", 1.0):  # the PLC's watchdog on the clamp
            await client.write_coil(coil["clamp_alarm"], True, device_id=1)
            await client.write_register(2000, 2, device_id=1)  # feed hold
    finally:
        client.close()


async def test_a_bad_case_runs_on_the_wall_clock_with_an_external_plc(tmp_path: Path) -> None:
    """ncgate run --script with the ST logic off and a Modbus client as the PLC: the same
    clamp that never closes, judged on the wall clock."""
    import asyncio

    from .test_cli_run import start_run

    scenario = tmp_path / "clamp_never_closes.toml"
    scenario.write_text(EXTERNAL_SCENARIO)
    proc, port, lines = await start_run(
        FOLDER / "ncgate.toml", "--set", "plc.logic=[]", "--set", "nc.autostart=true",
        "--port", "0", "--no-web", "--set", "canopen.enabled=false", "--script", str(scenario))
    assert proc.stdout is not None
    async with asyncio.timeout(60):
        await _external_plc(port)
        rest = (await proc.stdout.read()).decode()
        code = await proc.wait()
    log = "".join(lines) + rest
    verdicts = verdict_lines(log)
    assert code == 0, log
    assert len(verdicts) == 4 and all(v.startswith("PASS ") for v in verdicts), log
    assert "clamp_alarm=1 at" in log


def test_until_before_the_scenarios_end_judges_no_moment_it_did_not_simulate(
        tmp_path: Path) -> None:
    """--until 3 holds for each scenario of the suite: each stops at 3 s (not at its last
    window, 10.5 s), a window it saw a moment of the condition in passes, and one it did not
    see the end of fails as not reached -- never judged at a time past the end."""
    done = ncgate("sim", "--example", "machine", "--until", "3", cwd=tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    out = done.stdout
    simulated = [line for line in out.splitlines() if line.startswith("simulated ")]
    assert len(simulated) == len(SCENARIOS), out
    assert all(line == "simulated 3.000 s: stopped at --until" for line in simulated), out
    assert "PASS clamp alarm: clamp_alarm=1 at 1.010 s" in out  # its window [1.0, 1.1]: seen
    assert ("FAIL coolant not ready: not reached: the run ended at 3.000 s, before the window "
            "[4.27, 4.3] s opened") in out
    assert ("FAIL no part counted: not reached: the run ended at 3.000 s, before the "
            "scenario's end at 10.500 s (parts=0 held from 0.000 to 3.000 s)") in out
    assert "12 scenarios: 19 of 80 expectations passed" in out


UNREACHED = """
[[expect]]
name = "clamped early"
cond = "clamped=1"
by = 20.0
[[expect]]
name = "cycle ends"
cond = "P1 IDLE"
by = 20.0
[[expect]]
name = "late window alarm"
cond = "any_alarm=0"
within = [20.0, 60.0]
[[expect]]
name = "quiet"
cond = "no alarm"
always = true
"""


def test_a_window_past_until_fails_as_not_reached(tmp_path: Path) -> None:
    script = tmp_path / "s.toml"
    script.write_text(UNREACHED)
    done = ncgate("sim", "--config", str(FOLDER / "ncgate.toml"), "--script", str(script),
                  "--until", "5", cwd=tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    lines = verdict_lines(done.stdout)
    assert lines[0] == "PASS clamped early: clamped=1 at 0.300 s"  # a moment of it was seen
    assert lines[1].startswith("FAIL cycle ends: not reached: the run ended at 5.000 s, before "
                               "the window [0, 20] s closed; P1 RUNNING, not IDLE, at 5.000 s")
    assert lines[2] == ("FAIL late window alarm: not reached: the run ended at 5.000 s, before "
                        "the window [20, 60] s opened")
    assert lines[3] == ("FAIL quiet: not reached: the run ended at 5.000 s, before the "
                        "scenario's end at 60.000 s (no alarm until then)")


@pytest.mark.parametrize("option", ["--junit", "--trace", "--gantt"])
def test_an_output_into_a_missing_folder_is_refused_before_the_suite_runs(
        tmp_path: Path, option: str) -> None:
    """(--trace and --gantt ran the whole run, then failed with a bare [Errno 2]: a new
    user's find.)"""
    script = ["--script", str(FOLDER / "scenarios" / "good.toml")] if option != "--junit" \
        else []
    done = ncgate("sim", "--example", "machine", *script, option,
                  str(tmp_path / "no" / "v.xml"), cwd=tmp_path)
    assert done.returncode == 2
    assert not verdict_lines(done.stdout)  # nothing ran
    assert f"{option} {tmp_path / 'no' / 'v.xml'}: no folder" in done.stderr


@pytest.mark.parametrize(("target", "said"), [
    ("out", "is a folder: name a file in it"),
    ("afile/v.xml", "'afile' is a file, not a folder")])
def test_an_output_onto_a_folder_or_under_a_file_is_refused_before_the_run(
        tmp_path: Path, target: str, said: str) -> None:
    """(A hostile try: --trace onto a folder ran the whole run, then '[Errno 21] Is a
    directory'; under a file it said 'no folder'.)"""
    (tmp_path / "out").mkdir()
    (tmp_path / "afile").write_text("")
    done = ncgate("sim", "--example", "machine", "--trace", target, cwd=tmp_path)
    assert done.returncode == 2
    assert not verdict_lines(done.stdout)  # nothing ran
    assert f"--trace {target}: {said}" in done.stderr

def test_junit_names_the_scenarios_by_their_place_in_the_example(tmp_path: Path) -> None:
    junit = tmp_path / "v.xml"
    done = ncgate("sim", "--example", "machine", "--junit", "v.xml", cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    names = [s.get("name") for s in ET.parse(junit).getroot()]
    assert names == [f"machine/scenarios/{p.name}" for p in SCENARIOS]
    assert {c.get("classname") for s in ET.parse(junit).getroot() for c in s} == set(names)
    assert f"== machine/scenarios/{SCENARIOS[0].name}" in done.stdout


async def test_run_script_plays_a_shipped_scenario_with_the_st_logic(tmp_path: Path) -> None:
    """ncgate run --script good.toml as shipped (the ST logic as the PLC, no client): the
    scenario starts PART itself and its windows count from that start, so it passes on the
    wall clock as in sim."""
    import asyncio

    from .test_cli_run import start_run

    proc, _port, lines = await start_run(
        FOLDER / "ncgate.toml", "--port", "0", "--no-web", "--set", "canopen.enabled=false",
        "--script", str(FOLDER / "scenarios" / "good.toml"))
    assert proc.stdout is not None
    async with asyncio.timeout(60):  # it ends by itself at its last window's end
        rest = (await proc.stdout.read()).decode()
        code = await proc.wait()
    log = "".join(lines) + rest
    verdicts = verdict_lines(log)
    assert len(verdicts) == len(expects_of(FOLDER / "scenarios" / "good.toml")), log
    assert all(v.startswith("PASS ") for v in verdicts), log
    assert code == 0, log


async def test_run_script_stopped_early_fails_what_it_did_not_reach(tmp_path: Path) -> None:
    """A SIGINT before the windows close: what was seen passes, the rest is not reached."""
    import asyncio
    import signal

    from .test_cli_run import start_run

    script = tmp_path / "s.toml"
    script.write_text(UNREACHED)
    proc, _port, lines = await start_run(
        FOLDER / "ncgate.toml", "--port", "0", "--no-web", "--set", "canopen.enabled=false",
        "--script", str(script))
    assert proc.stdout is not None
    async with asyncio.timeout(60):
        while "P1 resumes at PART.nc:3 N10" not in lines[-1]:  # door locked: the cycle goes on
            line = (await proc.stdout.readline()).decode()
            assert line, "".join(lines)
            lines.append(line)
        proc.send_signal(signal.SIGINT)
        rest = (await proc.stdout.read()).decode()
        code = await proc.wait()
    log = "".join(lines) + rest
    verdicts = verdict_lines(log)
    assert code == 1, log
    assert verdicts[0].startswith("PASS clamped early: clamped=1 at "), log
    assert verdicts[1].startswith("FAIL cycle ends: not reached: the run ended at "), log
    assert "before the window [0, 20] s closed; P1 " in verdicts[1]
    assert verdicts[2].startswith("FAIL late window alarm: not reached:"), log
    assert verdicts[3].startswith("FAIL quiet: not reached:"), log
