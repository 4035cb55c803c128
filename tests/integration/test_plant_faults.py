"""Faults and scenarios (docs/plant.md): each fault kind through the sim script and through
the API, verdicts of [[expect]] on the virtual clock, the CLI's exit status and JUnit file,
and a session with a plant and faults recorded and replayed."""

from __future__ import annotations

import asyncio
import json
import logging
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from ncgate.config import ConfigError, load_config
from ncgate.config.script import load_script
from ncgate.errors import InputRefused, Reason
from ncgate.gateway import Gateway
from ncgate.gateway.cli.main import main
from ncgate.gateway.record import read_record
from ncgate.gateway.record import replay as run_replay
from ncgate.gateway.sim import run_sim
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.inputs import API, Force

CELL = """
[nc]
processes = 1
main = "O1"
[plant]
scan_ms = 10
[[plant.model]]
name = "clamp"
kind = "cylinder"
extend = "SA20"
extended = "SA30"
retracted = "SA31"
travel_ms = 300
[[plant.model]]
name = "pressure"
kind = "lag"
target = "SYVAR1"
actual = "SYVAR2"
time_constant_ms = 50
[symbols]
clamp_closed = "SA30"
"""


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    (tmp_path / "O1.nc").write_text("N10 (WAI,SA30=1)\nN20 M30\n")
    config = tmp_path / "ncgate.toml"
    config.write_text(CELL)
    return config


def _run(cell: Path, script: str, until: float | None = 3.0) -> Any:
    path = cell.parent / "s.toml"
    path.write_text(script)
    return run_sim(load_config(cell), "O1", load_script(path), until)


def _script(cell: Path, text: str) -> Any:
    """A script of ``text`` beside the cell, loaded."""
    path = cell.parent / "s.toml"
    path.write_text(text)
    return load_script(path)


def _with_faults(cell: Path, faults: str) -> None:
    """The cell with ``faults`` (``[[plant.fault]]`` tables) in its config."""
    cell.write_text(CELL.replace("[symbols]", faults + "[symbols]"))


def _edges(events: list[dict[str, Any]], var: str) -> list[tuple[float, int]]:
    out: list[tuple[float, int]] = []
    for e in events:
        if e["event"] == "write" and e["var"] == var and (not out or out[-1][1] != e["value"]):
            out.append((e["t"], e["value"]))
    return out


VALVE = '[[write]]\nat = 0.5\nset = "SA20=1"\n'


def test_never_keeps_the_cylinder_where_it_is_until_cleared(cell: Path) -> None:
    result = _run(cell, VALVE + '[[fault]]\ntarget = "clamp"\nkind = "never"\nat = 0.0\n'
                  '[[fault]]\ntarget = "clamp"\nclear = true\nat = 1.0\n')
    # Cleared at 1.0, it follows the valve that is on: arrives 0.3 s later.
    assert _edges(result.events, "SA30") == [(0.0, 0), (1.3, 1)]
    assert _edges(result.events, "SA31") == [(0.0, 1), (1.0, 0)]
    faults = [(e["event"], e["t"], e["target"], e["kind"], e["who"]) for e in result.events
              if e["event"] in ("fault", "fault_clear")]
    assert faults == [("fault", 0.0, "clamp", "never", "script fault[0]"),
                      ("fault_clear", 1.0, "clamp", "never", "script fault[1]")]


def test_slow_multiplies_the_travel_time(cell: Path) -> None:
    result = _run(cell, VALVE + '[[fault]]\ntarget = "clamp"\nkind = "slow"\nfactor = 3\n')
    assert _edges(result.events, "SA30") == [(0.0, 0), (1.4, 1)]


def test_stuck_holds_what_every_reader_sees_for_for_s_then_the_model_drives_again(
        cell: Path) -> None:
    result = _run(cell, VALVE + '[[fault]]\ntarget = "clamp.extended"\nkind = "stuck"\n'
                  'value = 1\nat = 0.1\nfor_s = 0.2\n')
    # Stuck at 1 from 0.1 to 0.3 (the NC's WAI resumes on it!), then the model's 0 again,
    # and its own 1 when the rod arrives at 0.8.
    assert _edges(result.events, "SA30") == [(0.0, 0), (0.1, 1), (0.3, 0), (0.8, 1)]
    resume = next(e for e in result.events if e["event"] == "resume")
    assert resume["t"] == 0.1 and resume["writer"] == "fault stuck clamp.extended"
    clear = next(e for e in result.events if e["event"] == "fault_clear")
    assert (clear["t"], clear["who"]) == (0.3, "for_s 0.2")


def test_a_clear_writes_again_only_what_the_image_no_longer_shows_of_the_models(
        cell: Path) -> None:
    """A value fault's clear gave every model's every output a write, unchanged, in the
    trace (the clamp's SA30 and SA31 and the pressure's SYVAR2 at each clear of anything);
    what was held is the one value the image shows wrong."""
    result = _run(cell, '[[fault]]\ntarget = "clamp.retracted"\nkind = "stuck"\nvalue = 0\n'
                  'at = 0.1\nfor_s = 0.2\n', until=1.0)
    at_clear = [(e["var"], e["value"], e["who"]) for e in result.events
                if e["event"] == "write" and e["t"] == 0.3]
    assert at_clear == [("SA31", 1, "plant clamp")]  # the model's own value, back


def test_a_stuck_input_wins_over_an_outside_write_and_a_force_wins_over_it(cell: Path) -> None:
    from ncgate.gateway.door import Door
    from ncgate.gateway.wiring import build_runtime, start_plant
    from ncgate.inputs import Fault, Force, Write

    runtime = build_runtime(load_config(cell), closed=True)
    door = Door(runtime)
    start_plant(runtime, door.apply, closed=True)
    door.apply(Fault.of("clamp_closed", "stuck", value=1))
    door.apply(Write("SA30", 0))
    assert runtime.image.read("SA", 30, "bit") == 1
    door.apply(Force("SA30", 0))
    assert runtime.image.read("SA", 30, "bit") == 0
    # No "forced" event for what the fault held: only the force's own.
    assert [e["event"] for e in runtime.trace.events].count("forced") == 0


def test_a_clear_gives_back_what_the_writers_last_wrote_in_their_name(cell: Path) -> None:
    """A wire mended: what no model drives shows again what its writers wrote -- the last
    write made under the hold (not stored, nor traced, meanwhile), or, with none, the value
    from before it.  (A clear kept the held value until the next write: a PLC that writes
    on change never did.)"""
    result = _run(cell, '[[write]]\nat = 0.0\nset = "SYVAR5=7"\n'
                  '[[write]]\nat = 0.0\nset = "SA40=1"\n'
                  '[[fault]]\ntarget = "SYVAR5"\nkind = "stuck"\nvalue = 3\nat = 0.1\n'
                  'for_s = 0.2\n[[write]]\nat = 0.2\nset = "SYVAR5=9"\n'
                  '[[fault]]\ntarget = "SA40"\nkind = "wire_break"\nat = 0.1\nfor_s = 0.4\n',
                  until=1.0)
    writes = [(e["t"], e["var"], e["value"], e["who"]) for e in result.events
              if e["event"] == "write" and e["var"] in ("SYVAR5", "SA40")]
    assert writes == [
        (0.0, "SYVAR5", 7, "script write[0]"), (0.0, "SA40", 1, "script write[1]"),
        (0.1, "SYVAR5", 3, "fault stuck SYVAR5"), (0.1, "SA40", 0, "fault wire_break SA40"),
        (0.3, "SYVAR5", 9, "script write[2]"),  # the clear: that last write, back
        (0.5, "SA40", 1, "script write[1]"),    # none under the hold: the value before it
    ]


def test_logic_writing_a_held_output_every_scan_is_not_traced_as_writing_the_faults_value(
        cell: Path) -> None:
    """The PLC sets SA21 every scan; a stuck SA21 = 0 held it.  The trace had "SA21 = 0
    by plc" at every scan (the logic never wrote 0), and a verdict named the PLC."""
    (cell.parent / "plc.st").write_text("PROGRAM ctl\nSA[21] := TRUE;\nEND_PROGRAM\n")
    cell.write_text(cell.read_text().replace("[plant]", '[plc]\nlogic = "plc.st"\n[plant]'))
    result = _run(cell, '[[fault]]\ntarget = "SA21"\nkind = "stuck"\nvalue = 0\nat = 0.1\n'
                  'for_s = 0.3\n[[expect]]\nname = "on"\ncond = "SA21=1"\nwithin = [0.2, 0.3]\n',
                  until=0.6)
    writes = [(e["t"], e["value"], e["who"]) for e in result.events
              if e["event"] == "write" and e["var"] == "SA21"]
    assert writes == [(0.0, 1, "plc"), (0.1, 0, "fault stuck SA21"), (0.4, 1, "plc")]
    (verdict,) = result.verdicts
    assert not verdict.ok
    assert verdict.line() == ("FAIL on: SA21 still 0 at 0.300 s (set by fault stuck SA21 at "
                              "0.100 s); fault stuck on SA21 (by script fault[0])")


def test_a_replaced_hold_gives_back_the_writers_value_not_the_first_holds(
        cell: Path) -> None:
    result = _run(cell, '[[write]]\nat = 0.0\nset = "SYVAR5=7"\n'
                  '[[fault]]\ntarget = "SYVAR5"\nkind = "stuck"\nvalue = 3\nat = 0.1\n'
                  '[[fault]]\ntarget = "SYVAR5"\nkind = "wire_break"\nlive_zero = -1\n'
                  'at = 0.2\nfor_s = 0.1\n', until=1.0)
    assert _edges(result.events, "SYVAR5") == [(0.0, 7), (0.1, 3), (0.2, -1), (0.3, 7)]


def test_two_faults_on_one_variable_by_two_names_hold_it_until_both_are_cleared(
        cell: Path) -> None:
    """stuck clamp.extended and stuck SA30 hold one variable: the first's clear released
    it (the image kept one hold a variable), and the program's WAI SA30=1 ended while the
    other was still listed."""
    result = _run(cell, VALVE + '[[fault]]\ntarget = "clamp.extended"\nkind = "stuck"\n'
                  'value = 0\nat = 0.1\n[[fault]]\ntarget = "clamp_closed"\nkind = "stuck"\n'
                  'value = 1\nat = 0.2\nfor_s = 0.1\n', until=2.0)
    # 1 from the second at 0.2; at its end (0.3) the first's 0 again, for good.
    assert _edges(result.events, "SA30") == [(0.0, 0), (0.2, 1), (0.3, 0)]
    resumes = [e for e in result.events if e["event"] == "resume"]
    assert [(e["t"], e["writer"]) for e in resumes] == [(0.2, "fault stuck clamp_closed")]


def test_a_chatter_gives_way_to_a_fault_injected_after_it_on_the_same_variable(
        cell: Path) -> None:
    """The chatter's timer placed its toggle over a stuck injected later under another
    name: SA30 went on toggling while the why-record named the stuck fault."""
    (cell.parent / "O1.nc").write_text("N10 (DLY,1)\nN20 M30\n")  # the cell runs on
    result = _run(cell, '[[fault]]\ntarget = "SA30"\nkind = "chatter"\nperiod_ms = 50\n'
                  'at = 0.1\n[[fault]]\ntarget = "clamp.extended"\nkind = "stuck"\nvalue = 0\n'
                  'at = 0.22\n', until=0.6)
    assert _edges(result.events, "SA30") == [(0.0, 0), (0.1, 1), (0.15, 0), (0.2, 1),
                                             (0.22, 0)]


def test_a_byte_fault_over_a_models_outputs_gives_them_back_to_the_model(cell: Path) -> None:
    """SA3.BY covers the clamp's SA30/SA31: its clear wrote the whole byte in the script's
    name (the model's switches too), and the model never named them again."""
    result = _run(cell, '[[write]]\nat = 0.0\nset = "SA24=1"\n'
                  '[[fault]]\ntarget = "SA3.BY"\nkind = "stuck"\nvalue = 0\nat = 0.1\n'
                  'for_s = 0.25\n[[write]]\nat = 0.2\nset = "SA25=1"\n', until=0.6)
    at_clear = [(e["var"], e["value"], e["who"]) for e in result.events
                if e["event"] == "write" and e["t"] == 0.35]
    assert ("SA31", 1, "plant clamp") in at_clear, at_clear  # the model's, in its name
    assert not any(who.startswith("script") for _, _, who in at_clear), at_clear
    image = result.runtime.image
    assert image.last_writer("SA", 31, "bit") == "plant clamp"


def test_wire_break_reads_zero_or_the_live_zero(cell: Path) -> None:
    result = _run(cell, '[[write]]\nat = 0.0\nset = "SYVAR1=1000"\n'
                  '[[fault]]\ntarget = "SYVAR2"\nkind = "wire_break"\nlive_zero = -4000\n'
                  'at = 0.5\n[[fault]]\ntarget = "SA31"\nkind = "wire_break"\nat = 0.5\n',
                  until=1.0)
    assert _edges(result.events, "SYVAR2")[-1] == (0.5, -4000)
    assert _edges(result.events, "SA31")[-1] == (0.5, 0)


def test_chatter_toggles_every_period_until_cleared(cell: Path) -> None:
    result = _run(cell, '[[fault]]\ntarget = "SA31"\nkind = "chatter"\nperiod_ms = 50\n'
                  'at = 1.0\nfor_s = 0.2\n', until=2.0)
    assert _edges(result.events, "SA31") == [(0.0, 1), (1.0, 0), (1.05, 1), (1.1, 0),
                                             (1.15, 1)]


def test_a_fault_on_a_condition_fires_when_it_first_holds(cell: Path) -> None:
    result = _run(cell, VALVE + '[[fault]]\ntarget = "clamp"\nkind = "never"\n'
                  'when = "SA20=1"\nafter = 0.1\n')
    # It leaves at 0.5 and stops a third of the way out at 0.6: neither switch on.
    assert _edges(result.events, "SA31") == [(0.0, 1), (0.5, 0)]
    assert _edges(result.events, "SA30") == [(0.0, 0)]


@pytest.mark.parametrize(("fault", "words"), [
    ('target = "nothing"\nkind = "never"', "plant model"),
    ('target = "clamp.speed"\nkind = "stuck"\nvalue = 1', "clamp drives"),
    ('target = "clamp.extended"\nkind = "never"', "the model's"),
    ('target = "SA30"\nkind = "exception"', "fieldbus"),
    ('target = "SYVAR2"\nkind = "stuck"\nvalue = 70000', "-32768..32767"),
])
def test_a_fault_that_cannot_be_is_an_error_naming_the_script_entry(
        cell: Path, fault: str, words: str) -> None:
    (cell.parent / "s.toml").write_text(f"[[fault]]\n{fault}\n")
    with pytest.raises(ConfigError) as caught:
        run_sim(load_config(cell), "O1", load_script(cell.parent / "s.toml"))
    assert "s.toml: fault[0].target:" in str(caught.value)
    assert words in str(caught.value)


# -- expectations -----------------------------------------------------------------------------

EXPECTS = """
[[expect]]
name = "clamp closes in time"
cond = "clamp_closed=1"
within = [0.7, 0.9]
[[expect]]
name = "P1 ends"
cond = "P1 IDLE"
by = 2.0
[[expect]]
name = "quiet"
cond = "no alarm"
always = true
"""


def test_the_good_case_passes_every_expectation(cell: Path) -> None:
    result = _run(cell, VALVE + EXPECTS, until=None)
    assert [v.line() for v in result.verdicts] == [
        "PASS clamp closes in time: clamp_closed=1 at 0.800 s",
        "PASS P1 ends: P1 IDLE at 0.800 s",
        "PASS quiet: no alarm in 0.000..2.000 s"]
    assert all(v.ok for v in result.verdicts)
    assert result.exit_status == 0
    assert result.runtime.engine.now == pytest.approx(2.0)  # the last window's end


def test_a_bad_case_fails_naming_the_value_who_set_it_and_the_model(cell: Path) -> None:
    result = _run(cell, VALVE + '[[fault]]\ntarget = "clamp"\nkind = "never"\n' + EXPECTS,
                  until=None)
    verdicts = {v.name: v for v in result.verdicts}
    bad = verdicts["clamp closes in time"]
    assert not bad.ok
    assert bad.line().startswith("FAIL clamp closes in time: SA30 still 0 at 0.900 s "
                                 "(set by plant clamp at 0.000 s)")
    assert "clamp retracted (fault: never)" in bad.line()
    assert not verdicts["P1 ends"].ok
    assert verdicts["quiet"].ok
    assert result.exit_status == 1


def test_an_expected_alarm_is_a_pass_and_an_always_that_breaks_says_when(cell: Path) -> None:
    (cell.parent / "ncgate.toml").write_text(CELL.replace("main = \"O1\"",
                                                          "main = \"O1\"\nwait_timeout_s = 1.0"))
    script = ('[[fault]]\ntarget = "clamp"\nkind = "never"\n'
              '[[expect]]\nname = "timeout"\ncond = "alarm AL143"\nby = 2.0\n'
              '[[expect]]\nname = "quiet"\ncond = "no alarm"\nalways = true\n') + VALVE
    result = _run(cell, script, until=None)
    lines = [v.line() for v in result.verdicts]
    assert lines[0].startswith("PASS timeout: P1 alarm AL143")
    assert lines[1].startswith("FAIL quiet: P1 alarm AL143")
    assert lines[1].endswith("at 1.000 s")
    assert result.exit_status == 1


def test_the_cli_runs_each_script_as_a_scenario_and_writes_junit(
        cell: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good, bad = cell.parent / "good.toml", cell.parent / "bad.toml"
    good.write_text(VALVE + EXPECTS)
    bad.write_text(VALVE + '[[fault]]\ntarget = "clamp"\nkind = "never"\n' + EXPECTS)
    junit = cell.parent / "verdicts.xml"
    status = main(["sim", "--config", str(cell), "--script", str(good), "--script", str(bad),
                   "--junit", str(junit), "O1"])
    out = capsys.readouterr().out
    assert status == 1
    assert f"== {good}" in out and f"== {bad}" in out
    assert out.count("PASS ") == 4 and out.count("FAIL ") == 2
    assert "2 scenarios: 4 of 6 expectations passed" in out
    suites = ET.parse(junit).getroot()
    assert suites.get("tests") == "6" and suites.get("failures") == "2"
    assert [s.get("name") for s in suites] == [str(good), str(bad)]
    failures = [c.get("name") for s in suites for c in s if c.find("failure") is not None]
    assert failures == ["clamp closes in time", "P1 ends"]
    assert main(["sim", "--config", str(cell), "--script", str(good), "O1"]) == 0


def test_an_expectation_that_cannot_be_read_names_its_key(cell: Path) -> None:
    (cell.parent / "s.toml").write_text('[[expect]]\nname = "x"\ncond = "SA30=1"\n')
    with pytest.raises(ConfigError) as caught:
        load_script(cell.parent / "s.toml")
    assert "s.toml: expect[0]: give exactly one of within" in str(caught.value)


# -- through the API and the console -----------------------------------------------------------

async def test_faults_through_the_api_and_the_console_are_traced_and_shown(
        cell: Path) -> None:
    config = ncgate_test_config(cell, **{"nc.time_scale": 20.0})
    async with Gateway(config, console=True) as gw:
        await gw.start("O1")
        gw.fault("clamp", "never")
        gw.write("SA20", 1)
        status = gw.plant.status()
        assert status["faults"][0]["kind"] == "never"
        assert "fault: never" in gw.describe_blocked()
        host, port = gw.web_address
        base = f"http://{host}:{port}"
        async with aiohttp.ClientSession() as http:
            async with http.post(f"{base}/api/fault", json={"target": "nope", "kind": "never"}
                                 ) as answer:
                assert answer.status == 422
            async with http.post(f"{base}/api/fault", json={"target": "clamp",
                                                            "kind": "melt"}) as answer:
                assert answer.status == 422
            async with http.post(f"{base}/api/fault", json={"clear": "clamp"}) as answer:
                assert answer.status == 200 and await answer.json() == []
            await gw.wait_idle(timeout_s=10)  # the rod arrives once the fault is gone
            async with http.post(f"{base}/api/fault", json={
                    "target": "SYVAR2", "kind": "stuck", "value": 7, "for_s": 100}) as answer:
                assert answer.status == 200
                assert (await answer.json())[0]["params"] == {"value": 7}
            async with http.get(f"{base}/api/status") as answer:
                plant = (await answer.json())["plant"]
            assert [m["name"] for m in plant["models"]] == ["clamp", "pressure"]
            assert plant["models"][0]["state"] == "extended"
            assert plant["faults"][0]["target"] == "SYVAR2"
            assert gw.read("SYVAR2") == 7
            async with http.post(f"{base}/api/fault", json={"clear": "all"}) as answer:
                assert answer.status == 200
        events = [(e["event"], e["target"], e["who"].split(" ")[0]) for e in gw.trace
                  if e["event"] in ("fault", "fault_clear")]
        assert events == [("fault", "clamp", "api"), ("fault_clear", "clamp", "web"),
                          ("fault", "SYVAR2", "web"), ("fault_clear", "SYVAR2", "web")]
        with pytest.raises(InputRefused) as caught:
            gw.fault("SA30", "slow")
        assert caught.value.reason is Reason.UNKNOWN_VARIABLE


async def test_a_session_with_a_plant_and_faults_replays_and_matches(
        cell: Path, tmp_path: Path) -> None:
    record = tmp_path / "session.jsonl"
    overrides = {"modbus.port": 0, "nc.time_scale": 20.0}
    config = ncgate_test_config(cell, **overrides)
    async with Gateway(config, record=record, overrides=overrides) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        await gw.start("O1")
        gw.fault("clamp", "slow", factor=2)
        gw.fault("modbus", "delay", ms=1)
        await plc.set("SA20", 1)
        await gw.wait_idle(timeout_s=10)
    recording = read_record(record)
    kinds = [line["input"] for line in map(json.loads, record.read_text().splitlines())
             if "input" in line]
    assert kinds == ["start", "fault", "fault", "write"]  # the plant's writes are not inputs
    result = run_replay(record)
    assert result.divergence is None, result.divergence
    assert result.compared >= 4
    assert any(e["event"] == "fault" for e in recording.events)
    # The Modbus fault acted in the session (the record holds what it did): the replay,
    # which serves no fieldbus, does not call it a fault with no effect.
    assert [e for e in result.events if e["event"] == "fault" and e["target"] == "modbus"]
    assert not [e for e in result.events if e["event"] == "hazard"]


async def test_a_fault_the_replay_refuses_is_named_before_the_divergence_it_causes(
        cell: Path, tmp_path: Path) -> None:
    """Replayed on a cell without the clamp, the session's clamp fault is refused: that is
    the cause, and was said only if no process diverged (a hostile try's edits)."""
    record = tmp_path / "session.jsonl"
    overrides = {"modbus.port": 0, "nc.time_scale": 20.0}
    config = ncgate_test_config(cell, **overrides)
    async with Gateway(config, record=record, overrides=overrides) as gw:
        await gw.start("O1")
        gw.fault("clamp", "slow", factor=3)
        gw.write("SA20", 1)
        await gw.wait_idle(timeout_s=10)
    other = tmp_path / "other"
    other.mkdir()
    (other / "O1.nc").write_text("N10 (WAI,SA30=1)\nN20 M30\n")
    (other / "ncgate.toml").write_text(CELL.replace('name = "clamp"', 'name = "vice"'))
    result = await asyncio.to_thread(run_replay, record, other / "ncgate.toml")
    assert result.divergence is not None
    assert result.divergence.startswith("replay diverges at the input of line "), (
        result.divergence)
    assert "no such" in result.divergence or "clamp" in result.divergence
    assert "; then " in result.divergence, result.divergence  # the resume came sooner


async def test_the_kits_plant_helper_beside_a_virtual_plc(cell: Path) -> None:
    from ncgate.gateway.errors import WaitIdleTimeout
    from ncgate.gateway.testing.plant_kit import PlantKit

    config = ncgate_test_config(cell, **{"modbus.port": 0, "nc.time_scale": 10.0})
    async with Gateway(config) as gw, VirtualPLC(*gw.modbus_address, gw.config) as plc:
        plant = PlantKit(gw)
        await plant.fault("clamp", "slow", factor=2)
        await plc.set("SA20", 1)
        await plant.wait_state("clamp", "extended", timeout_s=10)
        assert plant.state("clamp")["fault"] == "slow"
        assert await plc.get("SA30") == 1
        await plant.clear()
        assert plant.faults() == []
        with pytest.raises(WaitIdleTimeout) as caught:
            await plant.wait_state("clamp", "retracted", timeout_s=0.2)
        assert "clamp extended" in str(caught.value)
        with pytest.raises(KeyError):
            plant.state("nothing")


async def test_the_kits_wait_state_hears_a_change_that_writes_nothing(cell: Path) -> None:
    """A cylinder stopped mid-stroke by a fault writes nothing (its switches are both off
    already): wait_state heard only image writes, and came back at its timeout."""
    from ncgate.gateway.errors import GatewayError
    from ncgate.gateway.testing.plant_kit import PlantKit

    # A twentieth of real time: the fault comes well inside the stroke (6 s of wall time),
    # however busy the machine.
    config = ncgate_test_config(cell, **{"modbus.port": 0, "nc.time_scale": 0.05})
    async with Gateway(config) as gw:
        plant = PlantKit(gw)
        with pytest.raises(ValueError, match="a cylinder is never 'extendd'"):
            await plant.wait_state("clamp", "extendd")
        gw.write("SA20", 1)
        await plant.wait_state("clamp", "extends", timeout_s=10)
        waiting = asyncio.create_task(plant.wait_state("clamp", "stopped mid-stroke",
                                                       timeout_s=60))
        await asyncio.sleep(0)  # (it waits now)
        assert not waiting.done()
        gw.fault("clamp", "never")
        await asyncio.wait_for(waiting, 10)  # not the 60 s of its timeout
    with pytest.raises(GatewayError, match="not running"):  # (it timed out, a GatewayError)
        await plant.wait_state("clamp", "extended", timeout_s=30)


def test_ncgate_map_lists_what_each_model_reads_and_writes(
        cell: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["map", "--config", str(cell), "--format", "json"]) == 0
    plant = json.loads(capsys.readouterr().out)["plant"]
    assert plant[0] == {"name": "clamp", "kind": "cylinder", "reads": {"extend": "SA20"},
                        "writes": {"extended": "SA30", "retracted": "SA31"}}
    assert main(["map", "--config", str(cell)]) == 0
    assert "| pressure | lag | target SYVAR1 | actual SYVAR2 |" in capsys.readouterr().out


def test_a_window_that_closes_before_the_run_says_how_things_stood_then(cell: Path) -> None:
    script = VALVE + ('[[expect]]\nname = "early clamp"\ncond = "SA30=1"\nwithin = [0.0, 0.6]\n'
                      '[[expect]]\nname = "early end"\ncond = "P1 IDLE"\nwithin = [0.1, 0.6]\n'
                      '[[expect]]\nname = "late end"\ncond = "P1 IDLE"\nby = 2.0\n')
    result = _run(cell, script, until=None)
    lines = [v.line() for v in result.verdicts]
    # At 0.6 s the clamp was on its way (it arrives at 0.8 s) and P1 waited for it; by the
    # run's end (2.0 s) both had changed: the verdicts say how things stood at 0.6 s.
    assert lines[0] == ("FAIL early clamp: SA30 still 0 at 0.600 s (set by plant clamp at "
                        "0.000 s); clamp extends, 100 of 300 ms")
    assert lines[1] == ("FAIL early end: P1 WAIT_COND, not IDLE, at 0.600 s (since "
                        "0.000 s)")
    assert lines[2] == "PASS late end: P1 IDLE at 0.800 s"


@pytest.mark.parametrize(("target", "kind", "params", "read"), [
    ("clamp.retracted", "wire_break", {}, lambda v: v == 0),
    ("SYVAR2", "wire_break", {"live_zero": -4000}, lambda v: v == -4000),
    ("SA31", "stuck", {"value": 0}, lambda v: v == 0),
])
async def test_each_value_fault_through_the_api_holds_what_readers_see_until_cleared(
        cell: Path, target: str, kind: str, params: dict[str, Any], read: Any) -> None:
    config = ncgate_test_config(cell, **{"nc.time_scale": 10.0})
    async with Gateway(config) as gw:
        var = {"clamp.retracted": "SA31"}.get(target, target)
        before = gw.read(var)
        gw.fault(target, kind, **params)
        assert read(gw.read(var))
        gw.write(var, before)  # whatever writes it, the fault holds
        assert read(gw.read(var))
        gw.clear_fault(target)
        assert gw.read(var) == before  # the model writes what it drives again


async def test_a_clients_coil_written_under_a_hold_is_its_value_after_the_clear(
        cell: Path) -> None:
    """The real PLC (a Modbus client) sets the clamp valve while a wire break holds it at
    0: the clamp does not move; the clear mends the wire, and the valve is the client's 1
    again -- in the client's name -- and the clamp extends."""
    from ncgate.gateway.testing.plant_kit import PlantKit

    config = ncgate_test_config(cell, **{"modbus.port": 0, "nc.time_scale": 10.0})
    async with Gateway(config) as gw, VirtualPLC(*gw.modbus_address, gw.config) as plc:
        plant = PlantKit(gw)
        gw.fault("SA20", "wire_break")
        await plc.set("SA20", 1)
        assert await plc.get("SA20") == 0
        assert plant.state("clamp")["state"] == "retracted"
        gw.clear_fault("SA20")
        assert await plc.get("SA20") == 1
        writer = gw.image.last_writer("SA", 20, "bit")
        assert writer is not None and writer.startswith("modbus"), writer
        await plant.wait_state("clamp", "extended", timeout_s=10)


async def test_chatter_through_the_api_toggles_on_the_wall_clock(cell: Path) -> None:
    config = ncgate_test_config(cell, **{"nc.time_scale": 10.0})
    async with Gateway(config) as gw:
        seen: list[int] = []
        changed = asyncio.Event()

        def heard(changes: Any, writer: str) -> None:
            if writer == "fault chatter SA31":
                seen.append(gw.read("SA31"))
                changed.set()

        gw.image.subscribe(heard)
        gw.fault("SA31", "chatter", period_ms=20)
        async with asyncio.timeout(10):
            while len(seen) < 4:
                changed.clear()
                await changed.wait()
        assert seen[:4] in ([0, 1, 0, 1], [1, 0, 1, 0])
        gw.clear_fault("SA31")
        assert gw.read("SA31") == 1  # the clamp at rest is retracted: the model's value


def test_a_wait_on_a_process_the_script_will_start_again_is_no_orphan(tmp_path: Path) -> None:
    """O1 starts O2 in P2 and ends; O2 waits for P1.  The script's cycle start at 5 s runs
    O1 again, which sends: no AL141 at 0 s (an orphan wait) and no AL111 at 5 s."""
    (tmp_path / "O1.nc").write_text('N1(BGT,SYVAR1,0,SECOND)\nN2(EXE,2,O2)\nN3SYVAR1=1\n'
                                    'N4M30\n"SECOND"N5(SND,2)\nN6M30\n')
    (tmp_path / "O2.nc").write_text("N1(WAI,1)\nN2M30\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nprocesses = 2\nmain = "O1"\n'
                                          '[nc.storage]\nMP0 = "."\n')
    (tmp_path / "s.toml").write_text('[[command]]\nat = 5.0\ncommand = "cycle_start"\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "O1",
                     load_script(tmp_path / "s.toml"))
    alarms = [e for e in result.events if e["event"] == "alarm"]
    assert alarms == [], alarms
    resume = next(e for e in result.events if e["event"] == "resume" and e["proc"] == 2)
    assert resume["t"] == 5.0 and resume["by"] == 1
    assert result.exit_status == 0


@pytest.mark.parametrize(("script", "key"), [
    ('[[expect]]\nname = "a"\ncond = "FOO=1"\nby = 1\n', "expect[0].cond"),
    ('[[expect]]\nname = "a"\ncond = "P9 IDLE"\nby = 1\n', "expect[0].cond"),
    ('[[expect]]\nname = "a"\ncond = "alarm XYZ"\nby = 1\n', "expect[0].cond"),
    ('[[fault]]\ntarget = "SA31"\nkind = "chatter"\nperiod_ms = 1e-9\n', "fault[0].period_ms"),
    ('[[fault]]\ntarget = "clamp"\nkind = "slow"\nfactor = 1e308\n', "fault[0].factor"),
    ('[[fault]]\ntarget = "modbus"\nkind = "delay"\nms = 1e12\n', "fault[0].ms"),
    ('[[fault]]\ntarget = "clamp"\nkind = "never"\nfor_s = 1e9\n', "fault[0].for_s"),
    # A second hostile try: a slow factor below 1 sped a 1 ms generator up past the 1 ms
    # bound (a sim that never got on, its memory growing); a fault's `after` had no day
    # bound; a clear of a typo was a hazard in a run that passed; a condition on a value the
    # variable cannot hold was judged (SA30=2 never, SA30#2 always); a control character or
    # a newline in a name made --junit unreadable or forged a verdict line.
    ('[[fault]]\ntarget = "clamp"\nkind = "slow"\nfactor = 0.001\n', "fault[0].factor"),
    ('[[fault]]\ntarget = "clamp"\nkind = "never"\nwhen = "SA20=1"\nafter = 1e300\n',
     "fault[0].after"),
    ('[[fault]]\ntarget = "nosuch"\nclear = true\n', "fault[0].target"),
    ('[[expect]]\nname = "a"\ncond = "SA30=2"\nby = 1\n', "expect[0].cond"),
    ('[[expect]]\nname = "a"\ncond = "SA30#2"\nby = 1\n', "expect[0].cond"),
    ('[[expect]]\nname = "a"\ncond = "SYVAR2>99999"\nby = 1\n', "expect[0].cond"),
    ('[[write]]\nwhen = "SA30=7"\nset = "SA20=1"\n', "write[0].when"),
    ('[[expect]]\nname = "a\\u0000"\ncond = "SA30=1"\nby = 1\n', "expect[0].name"),
    ('[[expect]]\nname = "a\\nPASS fake: ok"\ncond = "SA30=1"\nby = 1\n', "expect[0].name"),
])
def test_a_hostile_scenario_is_a_usage_error_naming_its_key(
        cell: Path, script: str, key: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Found by a hostile try: each was a traceback (exit 70), a hang (a chatter every
    nanosecond) or accepted; each is one line naming the file and the key, exit 2."""
    (cell.parent / "s.toml").write_text(script)
    assert main(["sim", "--config", str(cell), "--script", str(cell.parent / "s.toml"),
                 "O1"]) == 2
    err = capsys.readouterr().err
    assert f"s.toml: {key}:" in err and "Traceback" not in err, err


def test_a_generator_faster_than_a_millisecond_is_refused(tmp_path: Path) -> None:
    (tmp_path / "ncgate.toml").write_text(
        '[[plant.model]]\nname = "g"\nkind = "generator"\noutput = "SA61"\n'
        'period_ms = 1e-9\n')
    with pytest.raises(ConfigError, match=r"plant.model\[0\].period_ms: expected a period"):
        load_config(tmp_path / "ncgate.toml")


async def test_the_api_refuses_what_no_fault_is_and_a_clear_of_nothing_known(
        cell: Path) -> None:
    config = ncgate_test_config(cell, **{"web.port": 0})
    async with Gateway(config, console=True) as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            for body in ({"target": "modbus", "kind": "delay", "ms": 1e12},
                         {"target": "SA31", "kind": "chatter", "period_ms": 1e-9},
                         {"target": "clamp", "kind": "slow", "factor": 1e308},
                         {"clear": "nosuch"}):
                async with http.post("/api/fault", json=body) as answer:
                    assert answer.status == 422, body
            async with http.post("/api/fault", json={"clear": "clamp"}) as answer:
                assert answer.status == 200  # a known target with no fault: nothing to clear
        assert gw.plant.faults == []


def test_a_condition_on_a_name_that_names_nothing_says_so_and_the_closest(
        cell: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`cond = "clampd=1"` said "unexpected 'clampd'; expected SYVAR, a number, ..." with no
    word of I/O names (a new user's find)."""
    (cell.parent / "s.toml").write_text('[[expect]]\nname = "a"\ncond = "clamp_closd=1"\n'
                                        'by = 1\n')
    assert main(["sim", "--config", str(cell), "--script", str(cell.parent / "s.toml"),
                 "O1"]) == 2
    assert ("s.toml: expect[0].cond: 'clamp_closd' is neither an image variable (SA30, SK4, "
            "SYVAR10) nor an I/O name of [symbols] (did you mean clamp_closed?)"
            in capsys.readouterr().err)


def test_a_scenario_of_always_expectations_is_judged_to_until_and_needs_it(
        cell: Path, tmp_path: Path) -> None:
    """Cut at its last timed entry (a write at 0), an `always` was judged over 0 s and
    passed what broke at the stroke's end; `when` instead of `at` gave the opposite verdict.
    With no window it has no end of its own: `sim` asks for --until (run to the cell idle, a
    program that loops never ended, and a PLC's last change came a scan after the end)."""
    for trigger in ('at = 0', 'when = "SA31=1"'):
        script = (f'[[write]]\n{trigger}\nset = "SA20=1"\n[[expect]]\n'
                  'name = "never closed"\ncond = "SA30=0"\nalways = true\n')
        result = _run(cell, script, until=1.0)
        assert [v.line() for v in result.verdicts] == [
            "FAIL never closed: SA30=0 stopped holding at 0.300 s (SA30 = 1, set by plant "
            "clamp at 0.300 s)"], trigger
        assert result.exit_status == 1
        with pytest.raises(ConfigError, match=r"every expectation is 'always'.*--until"):
            _run(cell, script, until=None)


def test_several_scripts_are_each_checked_before_the_first_runs(
        cell: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good, bad = cell.parent / "good.toml", cell.parent / "bad.toml"
    good.write_text(VALVE + EXPECTS)
    bad.write_text('[[expect]]\nname = "a"\ncond = "SA30==1"\nby = 1\n')
    junit = cell.parent / "verdicts.xml"
    status = main(["sim", "--config", str(cell), "--script", str(good), "--script", str(bad),
                   "--script", str(good), "--junit", str(junit), "O1"])
    captured = capsys.readouterr()
    assert status == 2
    assert "bad.toml: expect[0].cond:" in captured.err
    assert "PASS" not in captured.out and "==" not in captured.out  # none ran
    assert not junit.exists()


def test_verdicts_of_a_run_stopped_on_the_wall_clock_say_when_it_was_stopped(
        cell: Path) -> None:
    """The engine's time moves at its events: a `run --script` stopped after seconds of
    nothing said it ended at the last event's time.  The verdicts' end is the clock's now."""
    from ncgate.gateway.scenario import Expectations
    from ncgate.gateway.wiring import build_runtime

    path = cell.parent / "s.toml"
    path.write_text('[[expect]]\nname = "late"\ncond = "SA30=1"\nwithin = [30, 31]\n')
    runtime = build_runtime(load_config(cell), closed=False)
    expectations = Expectations(runtime, load_script(path))
    expectations.start()
    engine = runtime.engine
    engine.clock = lambda: engine.now + 5.5  # the wall clock, 5.5 s past the last event
    assert [v.line() for v in expectations.verdicts()] == [
        "FAIL late: not reached: the run ended at 5.500 s, before the window [30, 31] s "
        "opened"]


def test_a_fieldbus_fault_in_sim_is_said_to_have_no_effect(cell: Path) -> None:
    """sim serves no fieldbus: a modbus or canopen fault of a scenario is traced and does
    nothing, so the same file could pass in `run` and fail in `sim` with no word why (a new
    user's try).  The report says so."""
    result = _run(cell, '[[fault]]\ntarget = "modbus"\nkind = "no_reply"\n' + VALVE)
    hazards = [(e["t"], e["message"]) for e in result.events if e["event"] == "hazard"]
    assert hazards == [(0.0, "a modbus fault (no_reply, by script fault[0]) acts on modbus, "
                        "which sim does not serve: traced, with no effect")]


def test_a_fieldbus_fault_of_the_config_in_sim_is_said_to_have_no_effect(cell: Path) -> None:
    """The hazard was said of the script's entries only: a config's [[plant.fault]] on the
    fieldbus (here at 1 s, said as it comes) passed in silence."""
    _with_faults(cell, '[[plant.fault]]\ntarget = "canopen"\nkind = "emcy"\ncode = 0x5000\n'
                 'at = 1.0\n')
    result = _run(cell, VALVE)
    hazards = [(e["t"], e["message"]) for e in result.events if e["event"] == "hazard"]
    assert hazards == [(1.0, "a canopen fault (emcy, by plant plant.fault[0]) acts on "
                        "canopen, which sim does not serve: traced, with no effect")]


def test_run_refuses_a_bad_script_before_anything_serves(
        cell: Path, caplog: pytest.LogCaptureFixture,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A PLC that connected at once wrote to a gateway that then refused its script."""
    (cell.parent / "bad.toml").write_text(
        '[[expect]]\nname = "a"\ncond = "clamp_closd=1"\nby = 1\n')
    with caplog.at_level(logging.INFO):
        status = main(["run", "--config", str(cell), "--port", "0", "--no-web", "--set",
                       "canopen.enabled=false", "--script", str(cell.parent / "bad.toml")])
    assert status == 2
    assert "bad.toml: expect[0].cond:" in capsys.readouterr().err
    assert not [r for r in caplog.records if "Modbus TCP on" in r.getMessage()]


async def test_a_fault_on_a_fieldbus_the_gateway_does_not_serve_is_said_to_have_no_effect(
        cell: Path) -> None:
    """canopen.enabled = false: a heartbeat_stop was 200 and logged as if it acted."""
    config = ncgate_test_config(cell, **{"canopen.enabled": False, "modbus.port": 0})
    async with Gateway(config) as gw:
        gw.fault("canopen", "heartbeat_stop")
        gw.fault("modbus", "delay", ms=10)  # served: nothing to say
        gw.fault("canopen", "pdo_stop")
        hazards = [e["message"] for e in gw.trace if e["event"] == "hazard"]
        assert hazards == [
            "a canopen fault (heartbeat_stop, by api) acts on canopen, which this gateway "
            "does not serve: traced, with no effect",
            "a canopen fault (pdo_stop, by api) acts on canopen, which this gateway does not "
            "serve: traced, with no effect"]


async def test_a_config_fault_on_a_fieldbus_the_gateway_does_not_serve_is_said_at_start(
        cell: Path) -> None:
    """The config's faults are armed as the plant starts, after the adapters: one on the
    CANopen node of a gateway that serves none is said to have no effect, one on the Modbus
    server it serves is not."""
    _with_faults(cell, '[[plant.fault]]\ntarget = "canopen"\nkind = "pdo_stop"\n'
                 '[[plant.fault]]\ntarget = "modbus"\nkind = "delay"\nms = 5\n')
    config = ncgate_test_config(cell, **{"canopen.enabled": False, "modbus.port": 0})
    async with Gateway(config) as gw:
        both = asyncio.Event()

        def heard(event: dict[str, Any]) -> None:
            if {e["target"] for e in gw.trace if e["event"] == "fault"} == {"canopen",
                                                                              "modbus"}:
                both.set()

        gw.runtime.trace.subscribe(heard)
        heard({})
        await asyncio.wait_for(both.wait(), 10)
        assert [e["message"] for e in gw.trace if e["event"] == "hazard"] == [
            "a canopen fault (pdo_stop, by plant plant.fault[0]) acts on canopen, which "
            "this gateway does not serve: traced, with no effect"]


async def test_a_force_released_on_a_models_output_shows_the_model_again(cell: Path) -> None:
    """A model writes what changes: the forced value stayed after the release until the
    model's next change -- a running spindle read at standstill and at speed at once (a
    hostile try).  The clamp at rest is retracted: SA30 forced to 1 reads 0 again."""
    config = ncgate_test_config(cell, **{"modbus.port": 0, "canopen.enabled": False})
    async with Gateway(config) as gw:
        gw.force("SA30", 1)
        assert gw.read("SA30") == 1
        gw.force("SA30", None)
        assert gw.read("SA30") == 0
        last = [e for e in gw.trace if e["event"] == "write" and e["var"] == "SA30"][-1]
        assert (last["value"], last["who"]) == (0, "plant clamp")
        gw.force("SA31", 0)  # (retracted: the clamp at rest reads 1)
        gw.apply(Force(None, None, API))  # every force released (the console's Unforce)
        assert gw.read("SA31") == 1


async def test_a_fault_clear_writes_no_forced_event_of_a_forced_models_output(
        cell: Path) -> None:
    """Each clear had every model write what the image did not show: a forced output is
    never shown, so every clear of any fault put a `forced` event of it in the trace."""
    config = ncgate_test_config(cell, **{"modbus.port": 0, "canopen.enabled": False})
    async with Gateway(config) as gw:
        gw.force("SA31", 0)
        before = [e for e in gw.trace if e["event"] == "forced"]
        for _ in range(3):
            gw.fault("SYVAR2", "stuck", value=5)
            gw.clear_fault("SYVAR2")
        assert [e for e in gw.trace if e["event"] == "forced"] == before
        assert gw.read("SA31") == 0


async def test_a_failed_scenario_on_a_late_machine_says_the_machine_was_late(
        cell: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`run --script` on a loaded host: FAIL "SA53 still 0 at 3.500 s", and only the log
    said the engine was behind, 39 scans skipped (a hostile try): the verdicts blamed the
    cell.  The note says what was late; a scenario that passed needs none."""
    from ncgate.gateway.cli.serve import _Scenario

    config = ncgate_test_config(cell, **{"modbus.port": 0, "canopen.enabled": False,
                                         "nc.autostart": False})
    script = _script(cell, '[[expect]]\nname = "never"\ncond = "SA77=1"\nby = 0.01\n')
    async with Gateway(config) as gw:
        scenario = _Scenario(gw, script, asyncio.Event())
        await scenario.start()
        assert scenario.late() == ""
        assert gw._driver is not None
        gw._driver.max_lag_s = 0.101  # as a loop too busy for the time scale leaves it
        assert scenario.finish() == 1
    err = capsys.readouterr().err
    assert ("note: the engine fell up to 0.101 s of machine time behind the clock "
            "(nc.time_scale 1): a FAIL may be this machine's load") in err, err
