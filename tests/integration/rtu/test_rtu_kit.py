"""The virtual-PLC kit over Modbus RTU: ``ncgate_rtu_line`` (a pty pair relayed in the test's
process, no socat) and ``rtu_plc`` (pymodbus's RTU client with the kit's helpers), as a
user's conftest.py uses them."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.gateway.testing.rtu_kit import PtyPair


@pytest.fixture
def ncgate_config(cell: Path, ncgate_rtu_line: PtyPair) -> Config:
    return ncgate_test_config(cell / "ncgate.toml",
                              **{"modbus.rtu.port": ncgate_rtu_line.gateway_end})


async def test_the_rtu_plc_plays_the_plc_through_a_whole_cell(ncgate_gateway: Gateway,
                                                               rtu_plc: VirtualPLC) -> None:
    plc = rtu_plc
    await plc.command(1)  # cycle start
    await plc.wait_state(2, "WAIT_COND")
    await plc.set("SK5", 200)
    await plc.wait_state(1, "WAIT_COND")
    await plc.set("SA10", 1)
    snd = await plc.next_snd()
    assert (snd.sender, snd.target) == (1, 4)
    await plc.send(4, 1)  # the external P4 answers through the mailbox
    await plc.wait_state(1, "IDLE")
    assert await plc.get("SYVAR3") == -7
    writers = {e["who"] for e in ncgate_gateway.trace if e["event"] == "write"}
    assert writers == {f"modbus-rtu {ncgate_gateway.config.modbus.rtu.port}",
                       "P1 N6"}  # the PLC's writes, and the program's SYVAR3=-7
