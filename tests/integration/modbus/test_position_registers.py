"""A position beyond its register saturates (issue 25, item 5): the X/Y/Z µm registers are an
int32 pair, so a position past +-2,147,483,647 µm reads as that bound, never wrapped to the
other sign, and a position too large for any integer does not fail the read (it used to close
the connection with OverflowError).  Over real Modbus TCP on loopback."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from ...helpers import write_cell

CELL = """
[nc]
dialect = "{dialect}"
processes = 1
main = "MOVE"
time_scale = 50.0
[nc.storage]
MP0 = "."
[nc.limits]
X = [{lo}, {hi}]
Y = [{lo}, {hi}]
"""


def _signed(hi: int, lo: int) -> int:
    value = hi << 16 | lo
    return value - (1 << 32) if value & 0x8000_0000 else value


async def _positions(tmp_path: Path, dialect: str, lo: str, hi: str, program: str
                     ) -> tuple[int, int, int]:
    cell = write_cell(tmp_path, CELL.format(dialect=dialect, lo=lo, hi=hi), {"MOVE": program})
    config = ncgate_test_config(cell / "ncgate.toml")
    async with Gateway(config) as gw:
        host, port = gw.modbus_address
        async with VirtualPLC(host, port, config) as plc:
            await plc.command(1)
            await gw.wait_idle(timeout_s=30)
            assert not [e for e in gw.trace if e["event"] == "alarm"]
            for _ in range(2):  # the connection survives the read and answers again
                regs = await plc.status(1)
            return (_signed(*regs[12:14]), _signed(*regs[14:16]), _signed(*regs[16:18]))


async def test_positions_past_the_int32_range_read_as_its_bounds(tmp_path: Path) -> None:
    # 3 km either way (limits widened to 10 km): 3e9 µm does not fit an int32.
    positions = await _positions(tmp_path, "nc110", "-1E7", "1E7",
                                 "N1G1X3000000Y-3000000Z1.5F1000000000\nN2M30\n")
    assert positions == (2_147_483_647, -2_147_483_648, 1500)


async def test_a_position_too_large_for_any_integer_reads_as_the_bound(tmp_path: Path) -> None:
    # ISG reads exponents: X1E306 at F1E308 is a 0.6 s move to a position whose µm are inf.
    positions = await _positions(tmp_path, "isg", "-inf", "inf",
                                 "G01 X1E306 Y-1E306 F1E308\nM30\n")
    assert positions == (2_147_483_647, -2_147_483_648, 0)


async def test_a_read_that_fails_inside_the_gateway_answers_04_and_keeps_the_connection(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Whatever goes wrong while a register read is answered (a bug of ours, as the
    OverflowError was), the poller gets exception 04 and its connection stays: the next read
    is answered."""
    from pymodbus.client import AsyncModbusTcpClient

    from ncgate.gateway.modbus import map as modbus_map

    cell = write_cell(tmp_path, CELL.format(dialect="nc110", lo="-inf", hi="inf"),
                      {"MOVE": "N1M30\n"})
    async with Gateway(ncgate_test_config(cell / "ncgate.toml")) as gw:
        real = modbus_map.process_registers

        def failing(engine: object, k: int) -> list[int]:
            return [1 << 40, *real(engine, k)[1:]]  # type: ignore[arg-type]

        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            monkeypatch.setattr(modbus_map, "process_registers", failing)
            failed = await client.read_input_registers(100, count=4, device_id=1)
            monkeypatch.setattr(modbus_map, "process_registers", real)
            answered = await client.read_input_registers(100, count=4, device_id=1)
        finally:
            client.close()
    assert failed.isError() and failed.exception_code == 4
    assert not answered.isError() and answered.registers[0] == 0  # IDLE
