"""SW006: an image variable a logic writes that another writer of the cell writes too (a
plant model's output, or the other ST task) -- each overwrites the other, and the image shows
whichever wrote last.  Said by `check` at the logic's line, and in the log of `sim` and `run`
as the logic's other warnings are."""

from __future__ import annotations

import contextlib
import json
import logging
from pathlib import Path

import pytest

from ncgate.config import load_config
from ncgate.gateway import Gateway
from ncgate.gateway.cli.main import main

from ..helpers import write_cell

CELL = """
[nc]
main = "O1"
[nc.storage]
MP0 = "."
[plc]
logic = "plc.st"
[plant]
logic = "plant.st"
[web]
enabled = false
[symbols]
clamp_closed = "SA30"
flags = "SA6.BY"
[[plant.model]]
name = "clamp"
kind = "cylinder"
extend = "SA20"
extended = "clamp_closed"
retracted = "SA31"
travel_ms = 300
[[plant.model]]
name = "lamp"
kind = "delay"
input = "SA21"
output = "SA51"
[[plant.model]]
name = "horn"
kind = "delay"
input = "SA22"
output = "SA49"
"""

PLC = """PROGRAM main
VAR i : INT := 40; END_VAR
SA[20] := TRUE;
clamp_closed := SA[20];
flags.3 := TRUE;
SYVAR[5] := 3;
SAB[4] := 7;
SA[i] := TRUE;
END_PROGRAM
"""

PLANT = """PROGRAM machine
SYVAR[5] := 4;
SA[33] := TRUE;
SA[31] := SA[20];
END_PROGRAM
"""


def _cell(folder: Path, plc: str = PLC, plant: str = PLANT) -> Path:
    write_cell(folder, CELL, {"O1": "N10 (DLY,1)\nN20 M30\n"})
    (folder / "plc.st").write_text(plc)
    (folder / "plant.st").write_text(plant)
    return folder / "ncgate.toml"


def test_check_names_every_variable_a_logic_shares_with_another_writer(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _cell(tmp_path)
    with contextlib.chdir(tmp_path):
        assert main(["check", "--config", "ncgate.toml"]) == 0  # warnings: it still runs
    out, err = capsys.readouterr()
    # (The config's files are said by their whole path, as every diagnostic of check.)
    said = [line.replace(f"{tmp_path}/", "") for line in out.splitlines() if "SW006" in line]
    assert said == [
        # The PLC writes a model's output, by its I/O name: said at the PLC's write.
        "plc.st:4:1: warning SW006: SA30 (clamp_closed) is written here and by plant model "
        "clamp (extended): each overwrites the other (a model's output is the machine's "
        "answer: read it, or drop the model)",
        # flags.3 is SA51, the lamp's output; flags' other bits (SA49: the horn's) are not
        # written by it.
        "plc.st:5:1: warning SW006: SA51 is written here and by plant model lamp (output): "
        "each overwrites the other (a model's output is the machine's answer: read it, or "
        "drop the model)",
        # Both tasks write one variable: said once, at the plant's line, naming the PLC's.
        "plant.st:2:1: warning SW006: SYVAR5 is written here and by the PLC's logic at "
        "plc.st:6:1: each overwrites the other (the plant's logic models the machine: it reads "
        "what the PLC writes)",
        "plant.st:3:1: warning SW006: SA33 is written here and by the PLC's logic at "
        "plc.st:7:1: each overwrites the other (the plant's logic models the machine: it reads "
        "what the PLC writes)",
        # The plant's logic writes a model's output.
        "plant.st:4:1: warning SW006: SA31 is written here and by plant model clamp "
        "(retracted): each overwrites the other (a model's output is the machine's answer: "
        "read it, or drop the model)",
    ], out
    assert "0 error(s), 5 warning(s)" in err
    # SA[i] (a place the logic computes) and SA[20] (read by the clamp, written by no one
    # else) are not said: the one is not known before the scan, the other is no conflict.
    assert "SA40" not in out and "SA20 " not in out


def test_a_cell_whose_writers_share_nothing_gets_no_sw006(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _cell(tmp_path, "PROGRAM main\nSA[20] := TRUE;\nflags.0 := TRUE;\nEND_PROGRAM\n",
          "PROGRAM machine\nSYVAR[5] := 4;\nEND_PROGRAM\n")
    with contextlib.chdir(tmp_path):
        assert main(["check", "--config", "ncgate.toml"]) == 0
    out, err = capsys.readouterr()
    assert "SW006" not in out and "0 warning(s)" in err


def test_sim_says_sw006_in_its_log(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    _cell(tmp_path)
    with contextlib.chdir(tmp_path), caplog.at_level(logging.WARNING, logger="ncgate"):
        assert main(["sim", "--config", "ncgate.toml", "--until", "0.1"]) == 0
    said = [r.getMessage() for r in caplog.records if "SW006" in r.getMessage()]
    assert len(said) == 5 and "plc.st:4:1: warning SW006: SA30 (clamp_closed)" in said[3], said


def test_a_suite_of_scenarios_says_its_cells_sw006_once(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """One cell, three scenarios: its five warnings once, not fifteen."""
    _cell(tmp_path)
    for name in ("a", "b", "c"):
        (tmp_path / f"{name}.toml").write_text('[[expect]]\nname = "x"\ncond = "P1 IDLE"\n'
                                               "by = 0.2\n")
    with contextlib.chdir(tmp_path), caplog.at_level(logging.WARNING, logger="ncgate"):
        main(["sim", "--config", "ncgate.toml", "--script", "a.toml", "--script", "b.toml",
              "--script", "c.toml"])
    said = [r.getMessage() for r in caplog.records if "SW006" in r.getMessage()]
    assert len(said) == 5, said


async def test_run_says_sw006_in_its_log_before_it_serves(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    config = load_config(_cell(tmp_path), overrides={"modbus.port": 0,
                                                     "canopen.enabled": False})
    with caplog.at_level(logging.WARNING, logger="ncgate"):
        async with Gateway(config):
            said = [r.getMessage() for r in caplog.records if "SW006" in r.getMessage()]
    assert len(said) == 5 and any("SYVAR5 is written here and by the PLC's logic" in s
                                  for s in said), said


def test_map_lists_what_the_plant_logic_reads_and_writes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _cell(tmp_path, plant="PROGRAM machine\nVAR i : INT; END_VAR\nSYVAR[5] := 4;\n"
          "SA[33] := SA[20] AND flags.2;\nclamp_closed := SYVAR[i] > 3;\nEND_PROGRAM\n")
    with contextlib.chdir(tmp_path):
        assert main(["map", "--config", "ncgate.toml", "--format", "json"]) == 0
        logic = json.loads(capsys.readouterr().out)["plant"][-1]
        assert logic == {"name": "(logic)", "kind": "st: plant.st, every 10 ms",
                         # flags.2: bit 2 of SA byte 6; SYVAR[i]: a place it computes
                         "reads": ["SA20", "SA50", "SYVAR[…]"],
                         "writes": ["SA30 (clamp_closed)", "SA33", "SYVAR5"]}
        assert main(["map", "--config", "ncgate.toml"]) == 0
        assert ("| (logic) | st: plant.st, every 10 ms | SA20, SA50, SYVAR[…] | "
                "SA30 (clamp_closed), SA33, SYVAR5 |") in capsys.readouterr().out


def test_sw006_counts_only_the_code_the_programs_run_reach(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A PROGRAM that plc.programs leaves out, and a FUNCTION_BLOCK with no instance, write
    nothing: no SW006 of theirs.  A block that the PROGRAM run has an instance of does."""
    config = _cell(tmp_path, "PROGRAM main\nVAR d : doer; END_VAR\nd();\nEND_PROGRAM\n"
                   "PROGRAM spare\nSA[31] := TRUE;\nEND_PROGRAM\n"
                   "FUNCTION_BLOCK doer\nSA[51] := TRUE;\nEND_FUNCTION_BLOCK\n"
                   "FUNCTION_BLOCK unused\nSA[49] := TRUE;\nEND_FUNCTION_BLOCK\n",
                   "PROGRAM machine\nEND_PROGRAM\n")
    config.write_text(config.read_text().replace('logic = "plc.st"\n',
                                                 'logic = "plc.st"\nprograms = ["main"]\n'))
    with contextlib.chdir(tmp_path):
        assert main(["check", "--config", "ncgate.toml"]) == 0
    out = capsys.readouterr().out
    said = [line.replace(f"{tmp_path}/", "") for line in out.splitlines() if "SW006" in line]
    assert said == ["plc.st:9:1: warning SW006: SA51 is written here and by plant model lamp "
                    "(output): each overwrites the other (a model's output is the machine's "
                    "answer: read it, or drop the model)"], out
