"""Forcing (issue 28, item 2): a forced variable keeps its value whatever writes it -- the PLC
logic every scan, a Modbus client, a program -- each attempt traced as overridden, until it is
released; through the door (API), recorded and replayed."""

from __future__ import annotations

from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.errors import InputRefused, Reason
from ncgate.gateway import Gateway
from ncgate.gateway.record import replay
from ncgate.gateway.testing.plc_kit import PlcWatch
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.inputs import Force, Var

LOGIC = """PROGRAM main
VAR n : INT; END_VAR
n := n + 1;
SA[20] := TRUE;          (* every scan *)
SYVAR[5] := n;
END_PROGRAM
"""


async def test_a_forced_bit_holds_against_plc_logic_and_a_modbus_writer(tmp_path: Path) -> None:
    (tmp_path / "logic.st").write_text(LOGIC)
    (tmp_path / "A.nc").write_text("N1(WAI,SA21=1)\nN2M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n[plc]\nlogic = "logic.st"\n'
        '[canopen]\nenabled = false\n')
    record = tmp_path / "session.jsonl"
    async with Gateway(ncgate_test_config(tmp_path / "ncgate.toml"), record=record) as gw:
        watch = PlcWatch(gw)
        await watch.until("main.n", 3)
        assert gw.read("SA20") == 1  # the logic wrote it
        gw.apply(Force(Var.parse("SA20"), 0))
        n = watch.read("main.n")
        await watch.until("main.n", n + 5)  # five scans more, each writing SA20 := TRUE
        assert gw.read("SA20") == 0
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            assert not (await client.write_coil(20, True, device_id=1)).isError()
            assert gw.read("SA20") == 0  # accepted, overridden
            # A byte write over the forced bit changes the other bits, not the forced one.
            assert not (await client.write_register(1502, 0xFF, device_id=1)).isError()
            assert gw.read("SA2.BY") == 0xEF and gw.read("SA20") == 0
        finally:
            client.close()
        with pytest.raises(InputRefused) as caught:
            gw.apply(Force(Var.parse("SA20"), 7))  # no bit value
        assert caught.value.reason is Reason.BAD_VALUE
        gw.apply(Force(Var.parse("SA20"), None))  # released: the logic writes it again
        n = watch.read("main.n")
        await watch.until("main.n", n + 2)
        assert gw.read("SA20") == 1
        trace = gw.trace
    forces = [(e["var"], e["value"]) for e in trace if e["event"] == "force"]
    assert forces == [("SA20", 0), ("SA20", None)]
    overridden = [e["who"].split()[0] for e in trace if e["event"] == "forced"]
    assert overridden[0] == "plc" and "modbus" in overridden  # the logic's and Modbus's tries
    lines = [line for line in record.read_text().splitlines() if '"input": "force"' in line]
    assert len(lines) == 2
    assert replay(record).divergence is None
