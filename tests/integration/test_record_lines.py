"""A record's lines that ``run --record`` can never have written are refused at load, naming
the file and line (exit 2): the plant's tick-budget lines the replay's plant would never meet,
and the values a message quotes are spelled as the JSON file has them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ncgate.gateway.cli.main import main

# Two models on a 10 ms tick: a cut leaves one model at least to the next tick.
TWO_LAGS = """
[nc]
processes = 1
main = "O1"
[nc.storage]
MP0 = "."
[plant]
scan_ms = 10
[[plant.model]]
name = "oil"
kind = "lag"
target = "SYVAR1"
actual = "SYVAR2"
time_constant_ms = 40
[[plant.model]]
name = "air"
kind = "lag"
target = "SYVAR3"
actual = "SYVAR4"
time_constant_ms = 60
"""


@pytest.fixture
def config(tmp_path: Path) -> Path:
    (tmp_path / "O1.nc").write_text("N10 M30\n")
    path = tmp_path / "ncgate.toml"
    path.write_text(TWO_LAGS)
    return path


def _replay(config: Path, lines: list[dict[str, object] | str]) -> int:
    """``sim --replay`` of a record of ``lines`` (a str: the line as it is) after its
    header, stopped at 1 s."""
    header = {"ncgate_record": 2, "config": str(config), "overrides": {}, "files": {}}
    record = config.parent / "r.jsonl"
    record.write_text("".join((x if isinstance(x, str) else json.dumps(x)) + "\n"
                              for x in (header, *lines, {"stop": 1.0})))
    return main(["sim", "--replay", str(record)])


def _said(capsys: pytest.CaptureFixture[str], config: Path, line: int) -> str:
    err = capsys.readouterr().err
    assert f"{config.parent / 'r.jsonl'}:{line}: " in err, err
    return err


@pytest.mark.parametrize(("lines", "said"), [
    # n out of what the budget decides, whatever the config
    ([{"plant": "stretch", "t": 0.02, "n": 128}], "a power of 2 from 1 to 64"),
    # a stretch moves a step a tick: 2x or 1/2 of the one before
    ([{"plant": "stretch", "t": 0.02, "n": 2}, {"plant": "stretch", "t": 0.04, "n": 8}],
     "the stretch was 2: the budget doubles or halves it (1 or 4)"),
    ([{"plant": "stretch", "t": 0.02, "n": 2}, {"plant": "stretch", "t": 0.04, "n": 2}],
     "(1 or 4)"),
    # no tick at 0, and ticks come one after the other, each deciding once
    ([{"plant": "cut", "t": 0, "n": 1}], "no tick of the plant is at 0"),
    ([{"plant": "cut", "t": 0.03, "n": 1}, {"plant": "cut", "t": 0.02, "n": 1}],
     "a cut at t=0.02 after one at t=0.03"),
    ([{"plant": "cut", "t": 0.03, "n": 1}, {"plant": "cut", "t": 0.03, "n": 1}],
     "in time order, once a tick"),
])
def test_a_budget_line_the_plant_never_decides_is_refused(
        config: Path, lines: list[dict[str, object]], said: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    assert _replay(config, lines) == 2
    err = _said(capsys, config, 1 + len(lines))
    assert said in err, err


def test_a_budget_line_off_the_plants_tick_grid_is_refused(
        config: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Ticks every plant.scan_ms from 0, times the stretch in force from the record's last
    stretch before: on the grid the lines replay, off it they are refused."""
    on_grid = [{"plant": "cut", "t": 0.01, "n": 1}, {"plant": "stretch", "t": 0.01, "n": 2},
               {"plant": "cut", "t": 0.04, "n": 1}, {"plant": "stretch", "t": 0.06, "n": 4},
               {"plant": "cut", "t": 0.12, "n": 1}]
    assert _replay(config, on_grid) == 0
    capsys.readouterr()
    assert _replay(config, [{"plant": "cut", "t": 0.015, "n": 1}]) == 2
    err = _said(capsys, config, 2)
    assert "a cut at t=0.015: not a tick of the plant (every plant.scan_ms 10" in err, err
    # 0.03 is a tick of 10 ms, not of 10 ms stretched to 2 scans at 0.01
    assert _replay(config, [{"plant": "stretch", "t": 0.01, "n": 2},
                            {"plant": "cut", "t": 0.03, "n": 1}]) == 2
    err = _said(capsys, config, 3)
    assert "x the stretch 2 in force from 0: t=0.02, 0.04" in err, err
    assert _replay(config, [{"plant": "stretch", "t": 0.01, "n": 2},
                            {"plant": "stretch", "t": 0.03, "n": 4}]) == 2
    _said(capsys, config, 3)


def test_a_cut_past_the_configs_models_is_refused(
        config: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _replay(config, [{"plant": "cut", "t": 0.01, "n": 2}]) == 2
    err = _said(capsys, config, 2)
    assert "after 2 models, but the config's plant has 2 models" in err, err
    config.write_text(TWO_LAGS.split("[[plant.model]]")[0])  # no model: no tick at all
    assert _replay(config, [{"plant": "stretch", "t": 0.01, "n": 2}]) == 2
    err = _said(capsys, config, 2)
    assert "the config's plant has no model" in err, err


@pytest.mark.parametrize(("line", "said"), [
    ('{"input": "command", "t": NaN, "who": "api", "peer": null, "command": "reset", '
     '"process": null}', '"t": expected a time >= 0, got NaN'),
    ('{"stop": Infinity}', '"stop": expected a time >= 0, got Infinity'),
])
def test_a_value_in_a_message_is_spelled_as_the_file_has_it(
        config: Path, line: str, said: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert _replay(config, [line]) == 2
    err = _said(capsys, config, 2)
    assert said in err, err
