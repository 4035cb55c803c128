"""Absurd moves and durations are alarms at decode (issue 25, item 5): soft travel limits
(``[nc.limits]`` X .. C, AL131) and a bound on one block's duration (``nc.limits.block_s``,
AL132), in both dialects; a message never prints a 300-digit number."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from ncgate.gateway.cli.main import main
from ncgate.interpreter.diagnostics import fmt_number
from ncgate.interpreter.settings import AXES

from ...helpers import simulate
from .isg_harness import events, isg_sim

NO_TRAVEL_LIMITS = ((-math.inf, math.inf),) * len(AXES)


@pytest.mark.parametrize(("program", "line", "axis"), [
    ("N1E1=TAN(90)\nN2G1XE1F1000\nN3M30\n", 2, "X"),  # 1.6e16 mm
    ("N1G0Z-100001\nN2M30\n", 1, "Z"),  # just past -100 m
    ('N1G91\n"L"\nN2G0Y40000\n(BNC,L)\n', 3, "Y"),  # incremental steps walk out: the third
    ("N1G1C100000.5F600\nN2M30\n", 1, "C"),
])
def test_a_move_past_a_soft_travel_limit_is_al131_where_it_is_decoded(
        program: str, line: int, axis: str) -> None:
    sim = simulate({"A": program})
    (alarm,) = sim.events("alarm")
    assert (alarm["code"], alarm["line"], alarm["t"]) == ("AL131", line, 0.0)
    assert alarm["message"].startswith(axis)
    assert f"(nc.limits.{axis})" in alarm["message"]
    # Nothing of the block moved: the position is where the last good block left it.
    assert all(abs(v) <= 100_000 for v in sim.engine.status(1).position)


def test_the_limits_are_the_configured_ones_and_the_edge_is_inside() -> None:
    limits = ((-10.0, 20.0), *NO_TRAVEL_LIMITS[1:])
    sim = simulate({"A": "N1G0X20\nN2G0X-10\nN3M30\n"}, travel_limits=limits)
    assert sim.outcome == "idle" and not sim.events("alarm")
    sim = simulate({"A": "N1G0X20\nN2G0X20.001\nN3M30\n"}, travel_limits=limits)
    alarm = sim.first("alarm")
    assert (alarm["code"], alarm["line"]) == ("AL131", 2)
    assert alarm["message"] == "X20.001 is past the soft travel limit X20 (nc.limits.X)"


@pytest.mark.parametrize(("program", "line"), [
    ("N1G1X10F0.0000001\nN2M30\n", 1),  # 6e9 s: two centuries for 10 mm
    ("N1(DLY,86400.5)\nN2M30\n", 1),
    ("N1E1=TAN(90)\nN2(DLY,E1)\nN3M30\n", 2),
])
def test_a_block_longer_than_block_s_is_al132_where_it_is_decoded(program: str,
                                                                  line: int) -> None:
    sim = simulate({"A": program})
    (alarm,) = sim.events("alarm")
    assert (alarm["code"], alarm["line"], alarm["t"]) == ("AL132", line, 0.0)
    assert "nc.limits.block_s = 86400 s" in alarm["message"]
    assert sim.engine.now == 0.0


def test_block_s_is_configurable_and_a_block_of_exactly_that_long_runs() -> None:
    sim = simulate({"A": "N1G1X10F60\nN2(DLY,10)\nN3M30\n"}, block_limit_s=10.0)
    assert sim.outcome == "idle" and not sim.events("alarm") and sim.engine.now == 20.0
    sim = simulate({"A": "N1G1X10F59\nN2M30\n"}, block_limit_s=10.0)
    assert sim.first("alarm")["code"] == "AL132"


def test_with_no_limits_a_move_too_long_to_represent_is_still_al103() -> None:
    sim = simulate({"A": f"N1E1={'1' + '0' * 307}\nN2G1XE1F1\nN3M30\n"},
                   travel_limits=NO_TRAVEL_LIMITS, block_limit_s=math.inf)
    assert (sim.first("alarm")["code"], sim.first("alarm")["line"]) == ("AL103", 2)


@pytest.mark.parametrize(("program", "code"), [
    ("G01 X1E300 F1000\nM30\n", "AL131"),
    ("G00 Y-1E306\nM30\n", "AL131"),
    ("G01 X10 F0.0000001\nM30\n", "AL132"),
])
def test_isg_moves_are_held_to_the_same_limits(tmp_path: Path, program: str,
                                               code: str) -> None:
    result = isg_sim(tmp_path, program, processes=1)
    (alarm,) = events(result, "alarm")
    assert (alarm["code"], alarm["line"], alarm["t"]) == (code, 1, 0.0)


def test_isg_limits_come_from_nc_limits(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, "G00 X150\nM30\n", processes=1,
                     config="[nc.limits]\nX = [-100, 100]\n")
    (alarm,) = events(result, "alarm")
    assert alarm["code"] == "AL131"
    assert alarm["message"] == "X150 is past the soft travel limit X100 (nc.limits.X)"


@pytest.mark.parametrize(("value", "shown"), [
    (0.0, "0"), (-3.0, "-3"), (2.5, "2.5"), (999_999_999_999_999.0, "999999999999999"),
    (1e300, "1e+300"), (-1e306, "-1e+306"), (math.tan(math.radians(90)), "1.63312e+16"),
    (math.inf, "inf"), (-math.inf, "-inf"), (math.nan, "nan"), (1e-7, "1e-07"),
])
def test_a_number_in_a_message_is_never_hundreds_of_digits(value: float, shown: str) -> None:
    assert fmt_number(value) == shown


@pytest.mark.parametrize(("dialect", "program"), [
    ("nc110", "N1E1=TAN(90)\nN2G1XE1F1000\nN3M30\n"),
    ("nc110", "N1G1X10F0.0000001\nN2M30\n"),
    ("isg", "G01 X1E300 F1000\nM30\n"),
    ("isg", "G01 X10 F0.0000001\nM30\n"),
])
def test_the_sim_summary_of_an_absurd_block_is_an_alarm_in_a_few_digits(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], dialect: str, program: str) -> None:
    (tmp_path / "P.nc").write_text(program)
    (tmp_path / "ncgate.toml").write_text(
        f'[nc]\ndialect = "{dialect}"\nprocesses = 1\nmain = "P"\n[nc.storage]\nMP0 = "."\n')
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 1  # an alarm
    out = capsys.readouterr()
    text = out.out + out.err
    assert re.search(r"AL13[12]", text)
    assert not re.search(r"\d{17}", text), text
