"""What the field found (the issue "What the field found"): the CLI's and the config's side
of each defect, through the real commands."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.gateway.cli.main import main

# --- item 8: the dialect hint keeps the sync codes --------------------------------------------


def _cell(tmp_path: Path, programs: dict[str, str], dialect: str = "nc110") -> str:
    (tmp_path / "ncgate.toml").write_text(
        f'[nc]\ndialect = "{dialect}"\nmain = "A"\nprocesses = 3\n[nc.storage]\nMP0 = "."\n')
    for name, text in programs.items():
        (tmp_path / f"{name}.nc").write_text(text)
    return str(tmp_path / "ncgate.toml")


def test_no_isg_hint_for_an_nc110_error_whose_sync_codes_isg_would_drop(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # An NC-110 program with an error (>= is no NC-110 comparison): ISG reads its
    # (EXE,…) and (WAI,…) as comments, so "reads without error as isg" would drop them.
    config = _cell(tmp_path, {"A": "N1(EXE,2,B)\nN2(WAI,SYVAR2>=5)\nN3(WAI,2)\nN4M30\n",
                              "B": "N1(SND,1)\nN2M30\n"})
    assert main(["check", str(tmp_path / "A.nc"), "--config", config]) == 1
    out, err = capsys.readouterr()
    assert "error NC002" in out
    assert "--dialect isg" not in err
    assert main(["sim", "A", "--config", config]) == 2
    assert "--dialect isg" not in capsys.readouterr().err


def test_the_hint_still_names_isg_for_a_file_without_nc110_sync_codes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = _cell(tmp_path, {"A": "N10 G01 X10 F600\nN20 #SIGNAL[ID1]\nN30 M30\n"})
    assert main(["check", str(tmp_path / "A.nc"), "--config", config]) == 1
    assert "reads without error as isg: give --dialect isg" in capsys.readouterr().err


# --- item 10: messages ---------------------------------------------------------------------


def test_a_record_cut_inside_its_header_says_so(tmp_path: Path) -> None:
    from ncgate.gateway.record import RecordError, read_record

    record = tmp_path / "session.jsonl"
    record.write_text('{"ncgate_record": 2, "config": "/x/ncgat')
    with pytest.raises(RecordError, match=r"session\.jsonl:1: cut inside its header"):
        read_record(record)
    record.write_text("")
    with pytest.raises(RecordError, match=r"session\.jsonl: empty"):
        read_record(record)


@pytest.mark.parametrize(("text", "said"), [
    ('[nc]\nmain = "A"\nmain = "B"\n', r"ncgate\.toml:3: nc\.main is given twice"),
    ('[nc]\nmain = "A"\n[modbus]\nport = 1\n[nc]\nprocesses = 3\n',
     r"ncgate\.toml:5: nc is given twice"),
    ('[nc.storage]\nMP0 = "."\n[nc]\nstorage.MP0 = "x"\n',
     r"ncgate\.toml:4: nc\.storage is given twice"),
])
def test_a_duplicate_toml_key_names_its_dotted_key(tmp_path: Path, text: str, said: str) -> None:
    from ncgate.config import ConfigError, load_config

    (tmp_path / "ncgate.toml").write_text(text)
    with pytest.raises(ConfigError, match=said):
        load_config(tmp_path / "ncgate.toml")


def test_iw001_for_an_unsectioned_isg_main_with_config(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The main program runs in channel 1: its own #SIGNAL SYN before its #WAIT, with no
    # #FLUSH, is the buffer deadlock, sections or none.
    config = _cell(tmp_path, {"A": "G01 X250 F300\n#SIGNAL SYN [ID88 CH1]\nG01 X370 F80\n"
                                    "#WAIT [ID88 CH1]\nM30\n"}, dialect="isg")
    assert main(["check", str(tmp_path / "A.nc"), "--config", config]) == 0
    assert "A.nc:4:1: warning IW001" in capsys.readouterr().out
    # Another program, started by nobody the check can see, may run anywhere: no warning.
    (tmp_path / "B.nc").write_text((tmp_path / "A.nc").read_text())
    assert main(["check", str(tmp_path / "B.nc"), "--config", config]) == 0
    assert "IW001" not in capsys.readouterr().out


# --- item 11: the timeline draws a feed hold --------------------------------------------------


def test_the_timeline_draws_a_feed_hold_from_the_trace() -> None:
    from ncgate.gateway.timeline import state_intervals

    from ..helpers import make_sim

    sim = make_sim({"A": "N10G1X10F600\nN20M30\n"})
    engine = sim.engine
    engine.start("A")
    engine.call_at(0.25, lambda: engine.hold(True, 1))
    engine.call_at(2.0, lambda: engine.cycle_start(process=1))
    sim.run()
    lanes, end_t = state_intervals(sim.events(), 5)
    assert [(s, e, state) for s, e, state, _ in lanes[1]] == [
        (0.0, 0.25, "RUNNING"), (0.25, 2.0, "HOLD"), (2.0, 2.75, "RUNNING")]
    assert end_t == 2.75


# --- item 4: every reader shows the block a stopped process stands after ----------------------


async def test_a_single_block_stop_shows_its_block_n_on_modbus_and_the_api(
        tmp_path: Path) -> None:
    from pymodbus.client import AsyncModbusTcpClient

    from ncgate.gateway import Gateway, load_config
    from ncgate.interpreter.engine import ProcessState

    config = _cell(tmp_path, {"A": "N10E1=1\nN20E1=2\nN30M30\n"})
    cfg = load_config(config, overrides={"modbus.port": 0, "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            assert not (await client.write_register(2000, 0x0106, device_id=1)).isError()
            assert not (await client.write_register(2000, 1, device_id=1)).isError()
            await gw.wait_state(1, "STEP", timeout_s=10)
            regs = (await client.read_input_registers(100, count=3, device_id=1)).registers
            # state, block N, line: after N10, on line 1
            assert regs == [int(ProcessState.STEP), 10, 1]
            status = gw.engine.status(1)
            assert (status.n, status.line) == (10, 1)
        finally:
            client.close()
