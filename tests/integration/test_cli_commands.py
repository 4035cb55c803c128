"""Issue 25, items 10-15: what the commands do at their edges -- `sim`'s verdict with PLC
logic, its end with `--until`, its options and signals; `run`'s refusal of programs it cannot
run; the wording of errors; the built-in cell's first run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ncgate.gateway.cli.main import main

from ..helpers import write_cell

FAULTY = """PROGRAM main
VAR q : INT; END_VAR
q := 100 / SYVAR[1];
SYVAR[2] := q;
END_PROGRAM
"""

# Presses NC.START for the next part whenever process 1 is idle, two more parts after the
# first, as a cell's PLC does (a rising edge is a cycle start: docs/plc.md).
NEXT_PART = """PROGRAM cell
VAR parts : INT; pressed : BOOL; END_VAR
IF pressed THEN
  NC.START := FALSE;
  pressed := FALSE;
ELSIF NC.P[1].IDLE AND parts < 2 THEN
  NC.START := TRUE;
  pressed := TRUE;
  parts := parts + 1;
END_IF
END_PROGRAM
"""


def events_of(path: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


# -- item 10: any alarm is exit 1 ------------------------------------------------------------


def test_sim_exits_1_when_the_plc_logic_faults(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "logic.st").write_text(FAULTY)
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'
                         '[plc]\nlogic = "logic.st"\n', {"A": "N1G1X10F600\nN2M30\n"})
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"),
                 "--trace", str(tmp_path / "t.jsonl")]) == 1
    out = capsys.readouterr().out
    assert "PLC alarm AL160" in out
    assert out.rstrip().endswith(": every program ended, 1 alarm")
    alarms = [e for e in events_of(tmp_path / "t.jsonl") if e["event"] == "alarm"]
    assert [(e["proc"], e["code"]) for e in alarms] == [(0, "AL160")]


# -- item 11: PLC logic keeps the simulation going to --until ---------------------------------


def test_sim_with_plc_logic_runs_to_until_so_the_plc_starts_the_next_parts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "cell.st").write_text(NEXT_PART)
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'
                         '[plc]\nlogic = "cell.st"\n', {"A": "N1G1X10F700\nN2G0X0\nN3M30\n"})
    config = str(tmp_path / "ncgate.toml")
    assert main(["sim", "--config", config, "--until", "30",
                 "--trace", str(tmp_path / "t.jsonl")]) == 0
    out = capsys.readouterr().out
    assert out.rstrip().endswith("simulated 30.000 s: stopped at --until")
    starts = [e["by"] for e in events_of(tmp_path / "t.jsonl") if e["event"] == "start"]
    assert starts == ["script", "plc cell.st:7", "plc cell.st:7"]
    # Without --until the run still ends when every process is idle.
    assert main(["sim", "--config", config, "--trace", str(tmp_path / "t.jsonl")]) == 0
    assert "every program ended" in capsys.readouterr().out
    assert [e["event"] for e in events_of(tmp_path / "t.jsonl")].count("start") == 1


def test_sim_with_a_script_entry_still_to_come_runs_to_until(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n',
               {"A": "N1G1X10F600\nN2M30\n"})
    (tmp_path / "script.toml").write_text('[[write]]\nat = 20.0\nset = "SYVAR3=7"\n')
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"), "--script",
                 str(tmp_path / "script.toml"), "--until", "30",
                 "--trace", str(tmp_path / "t.jsonl")]) == 0
    # The program ends at 1 s; the script's last input comes at 20 s, and nothing after it.
    assert capsys.readouterr().out.rstrip().endswith("simulated 20.000 s: every program ended")
    writes = [(e["t"], e["var"]) for e in events_of(tmp_path / "t.jsonl")
              if e["event"] == "write"]
    assert writes == [(20.0, "SYVAR3")]
