"""A scenario script's mistakes (docs/script.md, docs/plant.md): each refused before anything
runs, exit 2, with a message that names the file and the dotted key and spells values as the
file does."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import ConfigError
from ncgate.config.script import load_script
from ncgate.gateway.cli.main import main

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
[symbols]
clamp_valve = "SA20"
clamp_closed = "SA30"
"""


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    (tmp_path / "O1.nc").write_text("N10 (WAI,SA30=1)\nN20 M30\n")
    config = tmp_path / "ncgate.toml"
    config.write_text(CELL)
    return config


def sim_error(cell: Path, script: str, capsys: pytest.CaptureFixture[str]) -> str:
    """What `ncgate sim` says of ``script`` on ``cell``, which it must refuse (exit 2)."""
    path = cell.parent / "s.toml"
    path.write_text(script)
    assert main(["sim", "--config", str(cell), "--script", str(path), "O1"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return err


@pytest.mark.parametrize(
    ("table", "message"),
    [
        # TOML's true, not Python's True
        ('target = "SA30"\nkind = "stuck"\nvalue = true',
         "fault[0].value: expected a whole number, got true"),
        ('target = "SA30"\nkind = "stuck"\nvalue = "1"',
         'fault[0].value: expected a whole number, got "1"'),
        ('target = "clamp"\nkind = "slow"\nfactor = false',
         "fault[0].factor: expected 1..1000, got false"),
        ('target = "SA30"\nkind = "never"\nfor_s = true',
         "fault[0].for_s: expected a time in seconds >= 0, got true"),
        ('target = "clamp"\nkind = 5', "fault[0].kind: expected one of stuck, wire_break"),
        # a clear takes no kind: it ends every fault of its target
        ('target = "clamp"\nclear = true\nkind = "never"',
         "fault[0].kind: a clear takes no kind: it clears every fault of its target (its "
         "keys: target, clear, at, when, after)"),
        ('target = "SA30"\nclear = true\nvalue = 1', "fault[0].value: a clear takes no value"),
        ('target = "clamp"', "fault[0].kind: missing (one of stuck, wire_break, chatter, "
         "slow, never"),
        ('kind = "never"', "fault[0].target: missing (a model, a model's output"),
    ],
)
def test_a_fault_s_mistake_names_its_key_and_spells_its_value_as_toml(
        tmp_path: Path, table: str, message: str) -> None:
    path = tmp_path / "s.toml"
    path.write_text(f"[[fault]]\n{table}\n")
    with pytest.raises(ConfigError) as caught:
        load_script(path)
    assert str(caught.value).startswith(f"{path}: ") and message in str(caught.value), (
        str(caught.value))


def test_an_expectation_without_a_name_is_known_by_its_key(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('[[expect]]\ncond = "SA30=1"\nby = 1\n')
    assert [e.name for e in load_script(path).expects] == ["expect[0]"]


@pytest.mark.parametrize(
    ("cond", "message"),
    [
        ("alarm AL99999", "no alarm has the code AL99999: the alarms' codes "
         "are those docs/diagnostics.md lists, AL101 .. AL172"),
        ("no alarm AL99999", "no alarm has the code AL99999"),
        ("alarm AL1450", "no alarm has the code AL1450 (did you mean AL140, AL145 or "
         "AL150?)"),
        ("alarm AL105", "no alarm has the code AL105: the alarms' codes"),  # (a crowd: 6)
        ("alarm 0", "no alarm has the code AL0"),
    ],
)
def test_an_alarm_no_alarm_has_is_refused_before_anything_runs(
        cell: Path, capsys: pytest.CaptureFixture[str], cond: str, message: str) -> None:
    """It ran, and said `FAIL x: no alarm AL99999` at the end (and `no alarm AL99999`
    passed whatever happened), while `SA30=2` is refused up front."""
    err = sim_error(cell, f'[[expect]]\nname = "x"\ncond = "{cond}"\nby = 1\n', capsys)
    assert f"s.toml: expect[0].cond: {message}" in err, err


def test_an_alarm_that_exists_is_taken(cell: Path, tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('[[expect]]\nname = "x"\ncond = "no alarm AL145"\nby = 0.1\n'
                    '[[expect]]\nname = "y"\ncond = "alarm al160"\nby = 0.1\n')
    assert main(["sim", "--config", str(cell), "--script", str(path), "O1"]) == 1

@pytest.mark.parametrize(
    ("section", "when", "message"),
    [
        ("write", "nosuch=1", "write[0].when: 'nosuch' is neither an image variable (SA30, SK4, "
         "SYVAR10) nor an I/O name of [symbols]"),
        ("write", "clamp_vlave=1", "write[0].when: 'clamp_vlave' is neither an image variable "
         "(SA30, SK4, SYVAR10) nor an I/O name of [symbols] (did you mean clamp_valve?)"),
        ("fault", "clamp_vlave=1", "fault[0].when: 'clamp_vlave' is neither"),
    ],
)
def test_a_when_on_a_name_that_names_nothing_says_i_o_names_are_taken_too(
        cell: Path, capsys: pytest.CaptureFixture[str], section: str, when: str,
        message: str) -> None:
    body = 'set = "SA20=1"' if section == "write" else 'target = "clamp"\nkind = "never"'
    err = sim_error(cell, f'[[{section}]]\nwhen = "{when}"\n{body}\n', capsys)
    assert f"s.toml: {message}" in err, err
