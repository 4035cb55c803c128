"""A cell for the Modbus tests: three processes, P4 external, fast clock, a free port."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import Config
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from ...helpers import write_cell

CELL = """
[nc]
processes = 4
main = "MAIN"
time_scale = 50.0
[nc.storage]
MP0 = "."
[[nc.process]]
number = 4
external = true
[modbus]
unit_ids = [1, 7]
idle_timeout_s = 30
"""
PROGRAMS = {
    # P1 starts P2, waits for the PLC's SA10, sends to the external P4, waits for P4's SND.
    "MAIN": "N1(EXE,2,SIDE)\nN2G1X10F600\nN3(WAI,SA10=1)\nN4#(SND,4)\nN5(WAI,4)\n"
            "N6SYVAR3=-7\nN7M30\n",
    "SIDE": "N1(WAI,SK5=200)\nN2G1Y5F600\nN3(REL)\n",
    "LONG": "N1G1X1000F60\nN2M30\n",  # 1000 s: something to hold and reset
    # 20 SNDs to the external P4 in one decoder run: more than a poller sees between two reads.
    "BURST": "".join(f"N{n}(SND,4)\n" for n in range(1, 21)) + "N21M30\n",
    "BURST16": "".join(f"N{n}(SND,4)\n" for n in range(1, 17)) + "N17M30\n",
}


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    return write_cell(tmp_path, CELL, PROGRAMS)


@pytest.fixture
def ncgate_config(cell: Path, request: pytest.FixtureRequest) -> Config:
    overrides = getattr(request, "param", {})
    return ncgate_test_config(cell / "ncgate.toml", **overrides)
