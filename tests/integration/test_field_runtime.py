"""What the field found in the runtime (issue 25): each test failed on the code before it."""

from __future__ import annotations

from pathlib import Path

import aiohttp
from pymodbus.client import AsyncModbusTcpClient

from ncgate.gateway import Gateway, load_config
from ncgate.inputs import CommandKind
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import ProcessState


def _cell(tmp_path: Path, programs: dict[str, str], nc: str = "") -> Path:
    for name, text in programs.items():
        (tmp_path / f"{name}.nc").write_text(text)
    (tmp_path / "ncgate.toml").write_text(
        f'[nc]\nmain = "{next(iter(programs))}"\n{nc}[nc.storage]\nMP0 = "."\n')
    return tmp_path / "ncgate.toml"


async def test_an_alarm_keeps_its_block_line_and_file_in_the_live_status(
        tmp_path: Path) -> None:
    """Spec 3.2's block-N and line registers, and the console's lane, show where the alarm
    struck until a reset -- not line 1 and N0 of the program."""
    path = _cell(tmp_path, {"DZ": "N10G1X5F6000\nN20E1=0\nN30E2=5/E1\nN40M30\n"})
    cfg = load_config(path, overrides={"modbus.port": 0, "canopen.enabled": False,
                                       "web.port": 0})
    async with Gateway(cfg, console=True, cold=True) as gw:
        gw.command(CommandKind.CYCLE_START)
        await gw.wait_state(1, "ALARM", timeout_s=10)
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            regs = (await client.read_input_registers(100, count=6, device_id=1)).registers
        finally:
            client.close()
        host, port = gw.web_address
        async with (aiohttp.ClientSession(f"http://{host}:{port}") as http,
                    http.get("/api/status") as r):
            lane = (await r.json())["processes"][0]
    assert regs == [int(ProcessState.ALARM), 30, 3, 0, 0, int(AlarmCode.DIVISION_BY_ZERO)]
    assert (lane["line"], lane["n"], lane["block"]) == (3, 30, "N30E2=5/E1")
    assert lane["alarm"]["where"] == {"prog": "DZ.nc", "line": 3, "n": 30}
    assert lane["alarm"]["message"].startswith("DZ.nc:3 N30: ")


async def test_the_position_registers_move_during_a_move_with_no_input(tmp_path: Path) -> None:
    """X/Y/Z in the status registers follow the move as it runs; before, they stood at the
    position of the last input (or timer) until an unrelated write came."""
    path = _cell(tmp_path, {"M": "N1G1X100F600\nN2M30\n"})  # 10 mm/s: 10 s
    cfg = load_config(path, overrides={"modbus.port": 0, "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        gw.command(CommandKind.CYCLE_START)
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            seen: list[int] = []
            for _ in range(20_000):  # reads until X has moved twice (bounded, no sleeps)
                regs = (await client.read_input_registers(112, count=2,
                                                          device_id=1)).registers
                x_um = regs[0] << 16 | regs[1]
                if not seen or x_um != seen[-1]:
                    seen.append(x_um)
                if len(seen) >= 3:
                    break
            state = gw.status(1).state
        finally:
            client.close()
    assert len(seen) >= 3, f"X stood at {seen} for 20,000 reads"
    assert seen == sorted(seen) and seen[0] >= 0 and seen[-1] < 100_000
    assert state is ProcessState.RUNNING  # the move was under way, nothing else moved it


async def test_on_the_gateway_a_wait_for_a_process_the_operator_may_start_is_no_orphan(
        tmp_path: Path) -> None:
    """Seed 000 section 4: the operator starts each process.  P1 waits for P3, which no
    program starts; on the gateway that is not AL141 -- the operator starts L3 by hand, and
    P1 goes on."""
    path = _cell(tmp_path, {"L1": "N1(WAI,3)\nN2M30\n", "L3": "N1(SND,1)\nN2M30\n"})
    cfg = load_config(path, overrides={"modbus.enabled": False, "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        await gw.start("L1", 1)
        await gw.wait_state(1, "WAIT_PROC", timeout_s=10)
        await gw.start("L3", 3)  # the operator's start of P3
        await gw.wait_idle(timeout_s=10)
        trace = gw.trace
    assert [e for e in trace if e["event"] == "alarm"] == []
    assert next(e for e in trace if e["event"] == "resume" and e["proc"] == 1)["by"] == 3
