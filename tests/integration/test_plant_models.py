"""Each plant model against its timing diagram (docs/plant.md), on the virtual clock.

The expected times are computed here from the documented rules (travel_ms, ramp_rpm_s, a
first-order lag's exp(-t/tau), ...), not taken from a run: a model that drifts from its
diagram fails, exact to one plant scan where the value moves continuously.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from ncgate.config import ConfigError, load_config
from ncgate.config.script import load_script
from ncgate.gateway.sim import run_sim

SCAN = 0.010  # plant.scan_ms = 10


def _sim(tmp_path: Path, models: str, script: str, until: float = 3.0,
         program: str = "N10 (DLY,5)\nN20 M30\n", extra: str = "") -> list[dict[str, Any]]:
    (tmp_path / "O1.nc").write_text(program)
    (tmp_path / "ncgate.toml").write_text(
        f'[nc]\nprocesses = 1\nmain = "O1"\n{extra}\n[plant]\nscan_ms = 10\n{models}')
    (tmp_path / "s.toml").write_text(script)
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "O1",
                     load_script(tmp_path / "s.toml"), until)
    return result.events


def _writes(events: list[dict[str, Any]], var: str) -> list[tuple[float, int, str]]:
    return [(e["t"], e["value"], e["who"]) for e in events
            if e["event"] == "write" and e["var"] == var]


def _edges(events: list[dict[str, Any]], var: str) -> list[tuple[float, int]]:
    """When ``var`` changed, and to what (the first write is its start value)."""
    out: list[tuple[float, int]] = []
    for t, value, _ in _writes(events, var):
        if not out or out[-1][1] != value:
            out.append((t, value))
    return out


DELAY = """
[[plant.model]]
name = "relay"
kind = "delay"
input = "SA20"
output = "SA30"
on_ms = 200
off_ms = 50
"""


def test_a_delay_switches_on_after_on_ms_off_after_off_ms_and_ignores_a_short_pulse(
        tmp_path: Path) -> None:
    script = """
[[write]]
at = 0.5
set = "SA20=1"
[[write]]
at = 1.0
set = "SA20=0"
[[write]]
at = 2.0
set = "SA20=1"
[[write]]
at = 2.1
set = "SA20=0"
"""
    events = _sim(tmp_path, DELAY, script)
    assert _edges(events, "SA30") == [(0.0, 0), (0.7, 1), (1.05, 0)]
    assert {who for _, _, who in _writes(events, "SA30")} == {"plant relay"}


CYLINDER = """
[[plant.model]]
name = "clamp"
kind = "cylinder"
extend = "SA20"
extended = "SA30"
retracted = "SA31"
position = "SYVAR10"
travel_ms = 300
retract_ms = 600
"""


def test_a_cylinder_leaves_its_end_at_once_and_arrives_after_its_travel_time(
        tmp_path: Path) -> None:
    script = """
[[write]]
at = 1.0
set = "SA20=1"
[[write]]
at = 2.0
set = "SA20=0"
"""
    events = _sim(tmp_path, CYLINDER, script)
    # At rest it is retracted; extending: retracted drops at 1.0, extended at 1.0 + 0.3.
    assert _edges(events, "SA31") == [(0.0, 1), (1.0, 0), (2.6, 1)]
    assert _edges(events, "SA30") == [(0.0, 0), (1.3, 1), (2.0, 0)]
    positions = _writes(events, "SYVAR10")
    # The position follows the stroke every scan: within one scan's travel of t/travel_ms.
    for t, value, _ in positions:
        if 1.0 <= t <= 1.3:
            assert abs(value - (t - 1.0) / 0.3 * 1000) <= SCAN / 0.3 * 1000 + 1
    assert (1.3, 1000) in [(round(t, 6), v) for t, v, _ in positions]
    assert positions[-1][:2] == (2.6, 0)


def test_a_cylinder_reversed_mid_stroke_comes_back_the_way_it_went(tmp_path: Path) -> None:
    script = """
[[write]]
at = 1.0
set = "SA20=1"
[[write]]
at = 1.1
set = "SA20=0"
"""
    events = _sim(tmp_path, CYLINDER, script)
    # A third of the stroke out (0.1 of 0.3 s), so a third of retract_ms (0.6 s) back.
    assert _edges(events, "SA31") == [(0.0, 1), (1.0, 0), (1.3, 1)]
    assert _edges(events, "SA30") == [(0.0, 0)]


def test_a_double_acting_cylinder_holds_mid_stroke_with_both_coils_off(tmp_path: Path) -> None:
    models = CYLINDER.replace('extend = "SA20"', 'extend = "SA20"\nretract = "SA21"')
    script = """
[[write]]
at = 1.0
set = "SA20=1"
[[write]]
at = 1.15
set = "SA20=0"
[[write]]
at = 2.0
set = "SA20=1"
"""
    events = _sim(tmp_path, models, script)
    # Half the stroke by 1.15, held there, the other half (0.15 s) from 2.0.
    assert _edges(events, "SA30") == [(0.0, 0), (2.15, 1)]
    held = [v for t, v, _ in _writes(events, "SYVAR10") if 1.15 <= t < 2.0]
    assert held and set(held) == {500}


MOTOR = """
[[plant.model]]
name = "spindle"
kind = "motor"
run = "SA21"
reverse = "SA22"
speed = "SYVAR11"
at_speed = "SA32"
standstill = "SA33"
rated_rpm = 6000
ramp_rpm_s = 12000
tolerance = 5
"""


def test_a_motor_ramps_to_rated_speed_and_says_at_speed_within_its_tolerance(
        tmp_path: Path) -> None:
    script = """
[[write]]
at = 1.0
set = "SA21=1"
[[write]]
at = 2.0
set = "SA21=0"
"""
    events = _sim(tmp_path, MOTOR, script)
    # 5 % of 6000 rpm below rated: 5700 rpm at 12000 rpm/s, 0.475 s after the start.
    assert _edges(events, "SA32") == [(0.0, 0), (1.475, 1), (2.0, 0)]
    assert _edges(events, "SA33") == [(0.0, 1), (1.0, 0), (2.5, 1)]
    speeds = {round(t, 6): v for t, v, _ in _writes(events, "SYVAR11")}
    assert speeds[1.5] == 6000 and speeds[2.5] == 0
    for t, v in speeds.items():
        if 1.0 <= t <= 1.5:
            assert abs(v - (t - 1.0) * 12000) <= 1


def test_a_motor_reversed_runs_to_minus_rated(tmp_path: Path) -> None:
    script = """
[[write]]
at = 0.5
set = "SA22=1"
[[write]]
at = 0.5
set = "SA21=1"
"""
    events = _sim(tmp_path, MOTOR, script)
    assert _writes(events, "SYVAR11")[-1][:2] == (1.0, -6000)
    assert _edges(events, "SA32") == [(0.0, 0), (0.975, 1)]


LAG = """
[[plant.model]]
name = "pressure"
kind = "lag"
target = "SYVAR1"
actual = "SYVAR2"
time_constant_ms = 100
"""


def test_a_lag_follows_its_target_as_a_first_order_lag(tmp_path: Path) -> None:
    events = _sim(tmp_path, LAG, '[[write]]\nat = 1.0\nset = "SYVAR1=1000"\n')
    values = [(t, v) for t, v, _ in _writes(events, "SYVAR2") if t >= 1.0]
    assert values, "the lag wrote nothing"
    for t, v in values:
        expected = 1000 * (1 - math.exp(-(t - 1.0) / 0.1))
        assert abs(v - expected) <= 1, (t, v, expected)
    # Within half a unit of the target it is the target: at tau * ln(2 * 1000) after the step.
    settle = 1.0 + 0.1 * math.log(2000)
    assert values[-1][1] == 1000
    assert settle - SCAN <= values[-1][0] <= settle + 1e-6


def test_a_square_generator_and_a_counter_run_from_the_start(tmp_path: Path) -> None:
    models = """
[[plant.model]]
name = "blink"
kind = "generator"
output = "SA40"
period_ms = 200
duty = 0.25
[[plant.model]]
name = "parts"
kind = "generator"
shape = "counter"
output = "SYVAR5"
period_ms = 500
"""
    events = _sim(tmp_path, models, "", until=1.0)
    assert _edges(events, "SA40") == [(0.0, 1), (0.05, 0), (0.2, 1), (0.25, 0), (0.4, 1),
                                      (0.45, 0), (0.6, 1), (0.65, 0), (0.8, 1), (0.85, 0),
                                      (1.0, 1)]
    assert _edges(events, "SYVAR5") == [(0.0, 0), (0.5, 1), (1.0, 2)]


def test_a_switch_follows_the_part_programs_axis(tmp_path: Path) -> None:
    models = """
[[plant.model]]
name = "ref"
kind = "switch"
axis = "P1.X"
above = 100.0
output = "SA50"
"""
    # G1 X200 at F1200 mm/min (20 mm/s): X passes 100 at t = 5 s.
    program = "N10 G1 X200 F1200\nN20 M30\n"
    events = _sim(tmp_path, models, "", until=12.0, program=program)
    edges = _edges(events, "SA50")
    assert edges[0] == (0.0, 0)
    assert len(edges) == 2 and edges[1][1] == 1
    assert 5.0 < edges[1][0] <= 5.0 + SCAN + 1e-6


def test_an_nc_wait_on_an_end_switch_resumes_only_when_the_cylinder_arrives(
        tmp_path: Path) -> None:
    program = "N10 (WAI,SA30=1)\nN20 M30\n"
    events = _sim(tmp_path, CYLINDER, '[[write]]\nat = 0.5\nset = "SA20=1"\n', until=None,
                  program=program)
    resumes = [e for e in events if e["event"] == "resume"]
    assert [(e["t"], e["writer"]) for e in resumes] == [(0.8, "plant clamp")]


def test_a_force_wins_over_a_model(tmp_path: Path) -> None:
    from ncgate.gateway.door import Door
    from ncgate.gateway.wiring import build_runtime, start_plant
    from ncgate.inputs import Force

    (tmp_path / "ncgate.toml").write_text(f'[nc]\nprocesses = 1\n{CYLINDER}')
    runtime = build_runtime(load_config(tmp_path / "ncgate.toml"), closed=True)
    door = Door(runtime)
    start_plant(runtime, door.apply, closed=True)
    door.apply(Force("SA30", 0))
    runtime.engine.call_at(0.1, lambda: door.apply(__import__("ncgate.inputs").inputs.Write(
        "SA20", 1)))
    runtime.engine.advance_to(1.0)
    assert runtime.image.read("SA", 30, "bit") == 0  # the model says 1: the force wins
    assert runtime.plant is not None
    assert runtime.plant.models["clamp"].state == "extended"
    door.apply(Force("SA30", None))
    runtime.engine.call_at(1.1, lambda: door.apply(__import__("ncgate.inputs").inputs.Write(
        "SA20", 0)))
    runtime.engine.advance_to(3.0)
    assert runtime.image.read("SA", 31, "bit") == 1


@pytest.mark.parametrize(("models", "key", "words"), [
    ('[[plant.model]]\nname = "c"\nkind = "cylinder"\nextend = "SA1"\ntravel_ms = 100\n',
     "plant.model[0].extended", "needs an output"),
    ('[[plant.model]]\nname = "c"\nkind = "cylinder"\nextend = "SA1"\nextended = "SA2"\n',
     "plant.model[0].travel_ms", "missing"),
    ('[[plant.model]]\nname = "c"\nkind = "valve"\n', "plant.model[0].kind", "cylinder"),
    ('[[plant.model]]\nname = "m"\nkind = "motor"\nrun = "SA1"\nrated_rpm = 10\n'
     'ramp_rpm_s = 5\nextend = "SA2"\n', "plant.model[0].extend", "unknown key"),
    ('[[plant.model]]\nname = "g"\nkind = "generator"\noutput = "SA1"\nperiod_ms = 0\n',
     "plant.model[0].period_ms", "1 ms .. 1 h"),
    ('[[plant.model]]\nname = "s"\nkind = "switch"\naxis = "X"\noutput = "SA1"\nabove = 1\n',
     "plant.model[0].axis", "P1.X"),
    ('[[plant.model]]\nname = "s"\nkind = "switch"\naxis = "P1.X"\noutput = "SA1"\n'
     'above = 5\nbelow = 2\n', "plant.model[0].below", "would never close"),
    ('[[plant.fault]]\ntarget = "SA1"\nkind = "stuck"\n', "plant.fault[0].value", "missing"),
    ('[[plant.fault]]\ntarget = "SA1"\nkind = "melt"\n', "plant.fault[0].kind", "stuck"),
])
def test_a_bad_plant_table_names_the_file_and_the_dotted_key(
        tmp_path: Path, models: str, key: str, words: str) -> None:
    (tmp_path / "ncgate.toml").write_text(models)
    with pytest.raises(ConfigError) as caught:
        load_config(tmp_path / "ncgate.toml")
    assert f"ncgate.toml: {key}:" in str(caught.value)
    assert words in str(caught.value)


@pytest.mark.parametrize(("models", "key"), [
    ('[[plant.model]]\nname = "c"\nkind = "cylinder"\nextend = "SA1"\nextended = "SA9999"\n'
     'travel_ms = 100\n', "plant.model[0].extended"),
    ('[[plant.model]]\nname = "c"\nkind = "cylinder"\nextend = "SA1"\nposition = "SA2"\n'
     'travel_ms = 100\n', "plant.model[0].position"),
    ('[[plant.model]]\nname = "a"\nkind = "delay"\ninput = "SA1"\noutput = "SA2"\n'
     '[[plant.model]]\nname = "b"\nkind = "delay"\ninput = "SA3"\noutput = "SA2"\n',
     "plant.model[1].output"),
])
def test_a_model_whose_variables_do_not_fit_the_image_does_not_start(
        tmp_path: Path, models: str, key: str) -> None:
    (tmp_path / "O1.nc").write_text("N10 M30\n")
    (tmp_path / "ncgate.toml").write_text(f'[nc]\nmain = "O1"\n{models}')
    with pytest.raises(ConfigError) as caught:
        run_sim(load_config(tmp_path / "ncgate.toml"), "O1", load_script(None))
    assert f": {key}:" in str(caught.value)


def test_on_the_wall_clock_a_tick_over_its_budget_stretches_the_sampling_not_the_switches(
        tmp_path: Path) -> None:
    from ncgate.gateway.door import Door
    from ncgate.gateway.plant.plant import BUDGET, MAX_STRETCH
    from ncgate.gateway.wiring import build_runtime, start_plant

    (tmp_path / "ncgate.toml").write_text(f'[nc]\nprocesses = 1\n[plant]\nscan_ms = 1\n'
                                          f'{CYLINDER}')
    runtime = build_runtime(load_config(tmp_path / "ncgate.toml"), closed=False)
    plant = start_plant(runtime, Door(runtime).apply_on_time, closed=False)
    period = 0.001
    plant._budget(BUDGET * period * 1.5)  # a tick that took more than its share
    assert plant.stretch == 2 and plant.stretched == 1
    for _ in range(20):
        plant._budget(1.0)
    assert plant.stretch == MAX_STRETCH
    plant._budget(0.0)  # well under a quarter of the budget: back towards every scan
    assert plant.stretch == MAX_STRETCH // 2
    assert plant.status()["stretch"] == MAX_STRETCH // 2



def test_on_the_wall_clock_a_tick_due_to_go_on_round_robin_after_every_model_came_to_rest(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A tick that ran out of time leaves where the next one starts; if every model it did
    not get to comes to rest before then, the next tick has nothing to write (it raised
    ZeroDivisionError on the wall-clock driver's turn, seen under load with 100 models)."""
    from ncgate.gateway.door import Door
    from ncgate.gateway.plant import plant as plant_module
    from ncgate.gateway.wiring import build_runtime, start_plant

    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 1\n[plant]\nscan_ms = 1\n' + CYLINDER
        + CYLINDER.replace('"clamp"', '"door"').replace("SA20", "SA21").replace(
            "SA30", "SA32").replace("SA31", "SA33").replace("SYVAR10", "SYVAR11"))
    runtime = build_runtime(load_config(tmp_path / "ncgate.toml"), closed=False)
    plant = start_plant(runtime, Door(runtime).apply_on_time, closed=False)
    runtime.image.write([("SA", 20, "bit", 1), ("SA", 21, "bit", 1)], "test")  # both move
    runtime.engine.advance_to(0.0001, 100)
    assert len(plant._sampling) == 2
    monkeypatch.setattr(plant_module, "TICK_S", -1.0)  # out of time after the first model
    runtime.engine.turn_over = lambda: False
    runtime.engine.advance_to(0.001, 100)  # the tick at 1 ms writes one, leaves the other
    assert plant._next_in_turn == 1
    plant._sampling.clear()  # both came to rest before the next tick
    runtime.engine.advance_to(0.002, 100)  # the tick at 2 ms: nothing to write, no error
    assert plant._next_in_turn == 0


def test_on_the_wall_clock_a_late_tick_arms_the_next_from_its_own_time(
        tmp_path: Path) -> None:
    """A tick the loop came to late arms the next one period after its own time, as a replay
    arms it: armed from the wall clock's now (skipping the ticks missed), a late tick came
    after the PLC scan it shares a grid time with, a replay put it before, and `sim --replay`
    of a time-scaled `run` diverged by a scan (a hostile try)."""
    from ncgate.gateway.door import Door
    from ncgate.gateway.wiring import build_runtime, start_plant

    (tmp_path / "ncgate.toml").write_text(f'[nc]\nprocesses = 1\n[plant]\nscan_ms = 1\n'
                                          f'{CYLINDER}')
    runtime = build_runtime(load_config(tmp_path / "ncgate.toml"), closed=False)
    plant = start_plant(runtime, Door(runtime).apply_on_time, closed=False)
    engine = runtime.engine
    runtime.image.write([("SA", 20, "bit", 1)], "test")  # the clamp moves: sampled
    engine.advance_to(0.0001, 100)
    assert plant._tick is not None and plant._tick.time == pytest.approx(0.001)
    engine.clock = lambda: 0.0105  # the wall clock when the tick at 1 ms runs: 9.5 ms late
    engine.advance_to(0.001, 100)
    assert plant._tick is not None and plant._tick.time == pytest.approx(0.002)


PLANT_ST = """PROGRAM tank
VAR level : INT; END_VAR
(* the pump fills the tank 10 units a scan while SA20 is on; it drains 2 a scan *)
IF SA[20] THEN level := level + 10; ELSIF level > 0 THEN level := level - 2; END_IF;
SYVAR[7] := level;
SA[37] := level >= 100;
END_PROGRAM
"""


def test_the_plant_logic_is_a_second_st_task_whose_writes_are_the_plants(
        tmp_path: Path) -> None:
    (tmp_path / "tank.st").write_text(PLANT_ST)
    (tmp_path / "O1.nc").write_text("N10 (WAI,SA37=1)\nN20 M30\n")
    (tmp_path / "s.toml").write_text('[[write]]\nat = 0.5\nset = "SA20=1"\n')
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 1\nmain = "O1"\n[plant]\nlogic = "tank.st"\nscan_ms = 10\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "O1",
                     load_script(tmp_path / "s.toml"), None)
    writes = [e for e in result.events if e["event"] == "write" and e["var"] == "SA37"]
    assert writes[0]["who"] == "plant" and writes[0]["value"] == 1
    # 10 a scan from the scan after the write's (0.5 s: the scan of that instant comes
    # first, docs/script.md) on: 100 at the tenth, 0.60 s.
    assert writes[0]["t"] == pytest.approx(0.60)
    resume = next(e for e in result.events if e["event"] == "resume")
    assert (resume["t"], resume["writer"]) == (writes[0]["t"], "plant")
    assert result.runtime.plant is not None
    assert result.runtime.plant.status()["logic"]["state"] == "RUNNING"


@pytest.mark.parametrize("until", [None, 600.0])
def test_a_cell_with_plc_and_plant_logic_that_stands_still_ends_as_a_stall(
        tmp_path: Path, until: float | None) -> None:
    """Each scan driver saw the other's next scan as work still to come: a stalled cell
    with both ran for ever (and to --until, exit 0) where either alone ended as a stall."""
    (tmp_path / "tank.st").write_text(PLANT_ST)
    (tmp_path / "plc.st").write_text("PROGRAM ctl\nSA[21] := TRUE;\nEND_PROGRAM\n")
    (tmp_path / "O1.nc").write_text("N10 (WAI,SA99=1)\nN20 M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 1\nmain = "O1"\nstall_s = 2\n[plc]\nlogic = "plc.st"\n'
        '[plant]\nlogic = "tank.st"\nscan_ms = 10\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "O1", load_script(None), until)
    stall = [e for e in result.events if e["event"] == "stall"]
    assert len(stall) == 1 and stall[0]["t"] == pytest.approx(2.0, abs=0.011)
    assert result.runtime.engine.now < 3.0


def test_a_sim_with_st_tasks_leaves_nothing_alive_after_it(tmp_path: Path) -> None:
    """The scan drivers' registry (for the stall rule) kept every engine that ran an ST
    task alive, with its image and trace: a sweep's worker grew with every variant."""
    import gc
    import weakref

    (tmp_path / "tank.st").write_text(PLANT_ST)
    (tmp_path / "O1.nc").write_text("N10 M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 1\nmain = "O1"\n[plant]\nlogic = "tank.st"\n')
    engines = []
    for _ in range(3):
        result = run_sim(load_config(tmp_path / "ncgate.toml"), "O1", load_script(None))
        engines.append(weakref.ref(result.runtime.engine))
        del result
    gc.collect()
    assert [e() for e in engines] == [None, None, None]


def test_sim_until_runs_on_for_the_plant_logics_cycle_start(tmp_path: Path) -> None:
    """plant.md: the plant logic's NC outputs are its own; with --until a closed run
    stopped when every program had ended, before the plant's NC.START at 1 s (run obeyed
    it; the same ST as PLC logic did too)."""
    (tmp_path / "starter.st").write_text(
        "PROGRAM starter\nVAR t : TON; END_VAR\nt(IN := TRUE, PT := T#1s);\n"
        "NC.START := t.Q;\nEND_PROGRAM\n")
    (tmp_path / "PART.nc").write_text("N10 G4 X0.1\nN20 M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 1\nmain = "PART"\n[plant]\nlogic = "starter.st"\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "PART", load_script(None), 3.0)
    starts = [e for e in result.events if e["event"] == "start"]
    assert [e["t"] for e in starts] == [0.0, pytest.approx(1.0)], starts
    assert result.runtime.engine.now == pytest.approx(3.0)


@pytest.mark.parametrize("command", ["reset", "restart_plc"])
def test_a_faulted_plant_logic_is_restarted_as_a_faulted_plc_is(
        tmp_path: Path, command: str, caplog: pytest.LogCaptureFixture) -> None:
    """Both commands answered 200 and left the plant logic in FAULT for good."""
    (tmp_path / "p.st").write_text(
        "PROGRAM p\nVAR d : INT; n : INT; END_VAR\nIF SA[50] THEN SYVAR[1] := 10 / d; END_IF;\n"
        "n := n + 1;\nSYVAR[2] := n;\nEND_PROGRAM\n")
    (tmp_path / "O1.nc").write_text("N10 M30\n")
    (tmp_path / "s.toml").write_text(
        '[[write]]\nat = 0.1\nset = "SA50=1"\n[[write]]\nat = 0.2\nset = "SA50=0"\n'
        f'[[command]]\nat = 0.3\ncommand = "{command}"\n')
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 1\nmain = "O1"\n[plant]\nlogic = "p.st"\nscan_ms = 10\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "O1",
                     load_script(tmp_path / "s.toml"), 0.5)
    alarms = [e for e in result.events if e["event"] == "alarm"]
    assert len(alarms) == 1 and "plant logic fault" in alarms[0]["message"]
    assert "plant logic fault: " in caplog.text and "PLC fault" not in caplog.text
    plant = result.runtime.plant
    assert plant is not None and plant.status()["logic"]["state"] == "RUNNING"
    counts = [e["t"] for e in result.events if e["event"] == "write" and e["var"] == "SYVAR2"]
    assert counts[-1] == pytest.approx(0.5)  # scanning again after the restart at 0.3


def test_plant_programs_name_programs_of_the_plant_logic(tmp_path: Path) -> None:
    (tmp_path / "tank.st").write_text(PLANT_ST)
    (tmp_path / "O1.nc").write_text("N10 M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "O1"\n[plant]\nlogic = "tank.st"\nprograms = ["pump"]\n')
    with pytest.raises(ConfigError) as caught:
        run_sim(load_config(tmp_path / "ncgate.toml"), "O1", load_script(None))
    assert "plant.programs[0]: no PROGRAM pump in plant.logic" in str(caught.value)


def test_a_relay_switched_by_a_scan_is_seen_by_the_scan_on_ms_later(tmp_path: Path) -> None:
    """docs/plant.md: a delay's output switches on_ms after its input, and the PLC's first
    scan at or after that sees it.  The PLC sets the coil at its scan at 2.01 s (201 * 0.01 s
    as a float is 2.0100000000000002); the relay's 200 ms end at the scan at 2.21 s, which
    sees the contact -- not the one after: as floats the relay's 2.01 + 0.2 is a hair past the
    scan's 221 * 0.01, and the nanosecond grid makes them one instant."""
    (tmp_path / "plc.st").write_text(
        "PROGRAM ctl\nSA[20] := SA[19];\nSA[21] := SA[30];\nEND_PROGRAM\n")
    events = _sim(tmp_path, DELAY, '[[write]]\nat = 2.005\nset = "SA19=1"\n',
                  extra='[plc]\nlogic = "plc.st"\n')
    assert _edges(events, "SA20")[-1] == (2.01, 1)  # the coil, by the scan after the write
    assert _edges(events, "SA30")[-1] == (2.21, 1)  # the contact, 200 ms on
    assert _edges(events, "SA21")[-1] == (2.21, 1)  # seen by the scan of that instant
