"""The pytest kit's ``plant`` fixture as a user's suite takes it: beside ``virtual_plc``, a
fault rehearsed over Modbus (docs/testing.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.plant_kit import PlantKit
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config


@pytest.fixture
def ncgate_config(tmp_path: Path) -> Config:
    (tmp_path / "O1.nc").write_text("N10 (WAI,SA30=1)\nN20 M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 1\nmain = "O1"\ntime_scale = 10.0\n[nc.storage]\nMP0 = "."\n'
        '[[plant.model]]\nname = "clamp"\nkind = "cylinder"\nextend = "SA20"\n'
        'extended = "SA30"\nretracted = "SA31"\ntravel_ms = 300\n')
    return ncgate_test_config(tmp_path / "ncgate.toml")


async def test_a_clamp_that_never_closes_keeps_the_program_waiting(
        ncgate_gateway: Gateway, virtual_plc: VirtualPLC, plant: PlantKit) -> None:
    await plant.fault("clamp", "never")
    await ncgate_gateway.start("O1")
    await virtual_plc.set("SA20", 1)  # the PLC closes the clamp
    await ncgate_gateway.wait_state(1, "WAIT_COND")
    assert plant.state("clamp")["state"] == "retracted"
    assert await virtual_plc.get("SA30") == 0
    await plant.clear("clamp")
    await plant.wait_state("clamp", "extended")
    await ncgate_gateway.wait_idle(timeout_s=10)
