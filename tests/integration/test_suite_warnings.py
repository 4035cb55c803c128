"""The warnings of a cell's logic (SW001..SW005: what plc.strict = false accepts, an unknown
pragma, a RETAIN in the plant's logic) in the log of `sim`: a suite of scenarios runs each on
a runtime of its own, from the same logic, and says them with its first scenario only, as it
does SW006; a single scenario says them as before."""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path

import pytest

from ncgate.gateway.cli.main import main

from ..helpers import write_cell

CELL = """
[nc]
main = "O1"
[nc.storage]
MP0 = "."
[plc]
logic = "plc.st"
strict = false
[plant]
logic = "plant.st"
[web]
enabled = false
"""

# SW001 (DINT into INT), SW002 (AND_THEN), SW004 (an unknown pragma).
PLC = """PROGRAM main
VAR d : DINT := 5; i : INT; a, b, c : BOOL; END_VAR
i := d;
c := a AND_THEN b;
{{ printf("%d\\n", i); }}
END_PROGRAM
"""

# SW005: the plant keeps nothing across a restart.
PLANT = """PROGRAM machine
VAR RETAIN n : INT; END_VAR
n := n + 1;
END_PROGRAM
"""

SCENARIO = '[[expect]]\nname = "x"\ncond = "P1 IDLE"\nby = 0.2\n'

CODES = ("SW001", "SW002", "SW004", "SW005")


def _cell(folder: Path, scenarios: int) -> None:
    """The cell, and ``scenarios`` scenario scripts s0.toml, s1.toml, ..."""
    write_cell(folder, CELL, {"O1": "N10 M30\n"})
    (folder / "plc.st").write_text(PLC)
    (folder / "plant.st").write_text(PLANT)
    for n in range(scenarios):
        (folder / f"s{n}.toml").write_text(SCENARIO)


def _said(caplog: pytest.LogCaptureFixture) -> list[str]:
    """The logic's warnings the log holds, each by its code."""
    return sorted(code for r in caplog.records for code in CODES if f" {code}:" in r.getMessage())


def test_a_suite_says_each_of_its_logics_warnings_once_as_one_run_does(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Three scenarios from one cell: each warning once (with the first), not three times --
    as `sim` says them without a script, and with one."""
    _cell(tmp_path, 3)
    suite = ["--script", "s0.toml", "--script", "s1.toml", "--script", "s2.toml"]
    for runs in (["--until", "0.1"], ["--script", "s0.toml"], suite):
        caplog.clear()
        with contextlib.chdir(tmp_path), caplog.at_level(logging.WARNING, logger="ncgate"):
            assert main(["sim", "--config", "ncgate.toml", *runs]) == 0
        assert _said(caplog) == sorted(CODES), (runs, _said(caplog))
