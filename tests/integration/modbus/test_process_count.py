"""Up to 16 processes (issue 25, item 3): the default Modbus map is laid out for the process
count, and only a served map must fit.

Up to five processes the input registers stay where dashboards know them (status 100, SND log
200, PLC status 300); each five processes more move the SND log and the PLC status by 100, so
16 processes have their status at 100..419, the SND log at 500 and the PLC status at 600.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import ConfigError, load_config
from ncgate.gateway import Gateway
from ncgate.gateway.cli.main import main
from ncgate.gateway.modbus.map import ModbusMap
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.interpreter.engine import ProcessState

from ...helpers import write_cell

# P1 starts a program in each of P2..P16, which moves and then sends to P1; P1 waits for each
# in turn and ends.  Every process of the 16 runs, waits and sends.
SIXTEEN = ("[nc]\nprocesses = 16\nmain = \"MAIN\"\ntime_scale = 50.0\n"
           "[nc.storage]\nMP0 = \".\"\n")
PROGRAMS = {
    "MAIN": "".join(f"N{k}(EXE,{k},SUB)\n" for k in range(2, 17))
    + "".join(f"N{20 + k}(WAI,{k})\n" for k in range(2, 17)) + "N99M30\n",
    "SUB": "N1G1X5F600\nN2(SND,1)\nN3M30\n",
}


@pytest.mark.parametrize(("processes", "snd_log", "plc_status"), [
    (1, 200, 300), (5, 200, 300), (6, 300, 400), (10, 300, 400), (11, 400, 500),
    (16, 500, 600)])
def test_the_default_map_is_laid_out_for_the_process_count(
        processes: int, snd_log: int, plc_status: int) -> None:
    m = ModbusMap(load_config(None, {"nc.processes": processes}))
    bases = (m.STATUS_BASE, m.SND_LOG_BASE, m.PLC_BASE)
    assert bases == (100, snd_log, plc_status)
    assert m.STATUS_BASE + m.STATUS_STRIDE * processes <= m.SND_LOG_BASE


def test_a_region_set_in_the_config_stays_where_it_was_put() -> None:
    m = ModbusMap(load_config(None, {"nc.processes": 16, "modbus.map.snd_log": 1000,
                                     "modbus.map.plc_status": 2000}))
    bases = (m.SND_LOG_BASE, m.PLC_BASE)
    assert bases == (1000, 2000)


@pytest.mark.parametrize(("text", "message"), [
    ("[plc]\nk_bytes = 1024", "modbus.map.k_bytes: k_bytes (0..1023) overlaps syvars"),
    ("[modbus.map]\ncommand = 1254", "modbus.map.syvars: syvars (1000..1255) overlaps "
     "command (1254..1257)"),
    ("[modbus.map]\nstatus = 5", "modbus.map.status: status (5..104) overlaps info"),
    ("[modbus.map]\nsnd_log = 150", "modbus.map.status: status (100..199) overlaps snd_log "
     "(150..247)"),
    ("[modbus.map]\nsa_bytes = 65500", "modbus.map.sa_bytes: 65500..65627 runs past"),
    ("[modbus.map]\nplc_status = 65530", "modbus.map.plc_status: 65530..65543 runs past"),
])
def test_a_served_map_that_does_not_fit_names_the_file_and_the_key(
        tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "ncgate.toml"
    path.write_text(text)
    config = load_config(path)  # the config loads: check and sim serve no Modbus
    with pytest.raises(ConfigError) as caught:
        Gateway(config)
    assert str(caught.value).startswith(f"{path}: ")
    assert message in str(caught.value)


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    return write_cell(tmp_path, SIXTEEN, PROGRAMS)


def test_check_and_sim_take_16_processes(cell: Path, capsys: pytest.CaptureFixture[str]
                                         ) -> None:
    config = str(cell / "ncgate.toml")
    assert main(["check", "--config", config, str(cell / "MAIN.nc"),
                 str(cell / "SUB.nc")]) == 0
    assert main(["sim", "--config", config]) == 0
    out = capsys.readouterr().out
    assert "P16" in out and "every program ended" in out


def test_check_and_sim_take_a_map_that_would_not_fit_since_they_serve_no_modbus(
        cell: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = SIXTEEN + "[modbus.map]\nsnd_log = 200\n"  # status 100..419 runs over it
    (cell / "ncgate.toml").write_text(text)
    config = str(cell / "ncgate.toml")
    assert main(["check", "--config", config, str(cell / "MAIN.nc")]) == 0
    assert main(["sim", "--config", config]) == 0
    with pytest.raises(ConfigError, match=r"modbus\.map\.status: status \(100\.\.419\) overlaps "
                       r"snd_log \(200\.\.297\)"):
        Gateway(load_config(cell / "ncgate.toml"))


async def test_16_processes_over_modbus_tcp(cell: Path) -> None:
    config = ncgate_test_config(cell / "ncgate.toml")
    async with Gateway(config) as gw:
        host, port = gw.modbus_address
        async with VirtualPLC(host, port, config) as plc:
            info = await plc.client.read_input_registers(0, count=2, device_id=plc.unit)
            assert info.registers == [1, 16]  # map version, process count
            await plc.command(1)  # cycle start: MAIN in P1 starts SUB in P2..P16
            await gw.wait_idle(timeout_s=30)
            await plc.wait_state(16, ProcessState.IDLE)  # the kit finds P16 at 400
            # Every process's status, 100..419, in reads of six blocks (a read is at most
            # 125 registers).
            regs: list[int] = []
            for start in range(100, 420, 120):
                r = await plc.client.read_input_registers(
                    start, count=min(120, 420 - start), device_id=plc.unit)
                assert not r.isError(), r
                regs += r.registers
            blocks = [regs[20 * k:20 * k + 20] for k in range(16)]
            assert [b[0] for b in blocks] == [int(ProcessState.IDLE)] * 16
            # P2..P16 each sent one SND to P1, and ended at X5 (5000 µm).
            assert [b[6] << 16 | b[7] for b in blocks[1:]] == [1] * 15
            assert [b[12] << 16 | b[13] for b in blocks[1:]] == [5000] * 15
            assert blocks[0][8] << 16 | blocks[0][9] == 15  # P1 received 15
            # The SND log at 500 and the PLC status at 600 answer; 420..499 is not mapped.
            log = await plc.snd_log()
            assert len(log) == 15 and {s.sender for s in log} == set(range(2, 17))
            assert await plc.client.read_input_registers(600, count=14, device_id=plc.unit)
            gap = await plc.client.read_input_registers(420, count=1, device_id=plc.unit)
            assert gap.isError() and gap.exception_code == 2
