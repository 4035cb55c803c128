"""Auxiliary functions ([nc.aux], issue 28 item 1): the handshake's edges -- nothing output
without the table, a handshake of none, an acknowledge with no strobe, one left on, the
timeout, a reset, a plain code crossing a pending handshake, the ISG dialect, the config's
errors, the map, the run log, a recorded session.  The PLC is the sim script (virtual clock):
its writes come at the times it gives."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ncgate.config import ConfigError, load_config
from ncgate.config.script import load_script
from ncgate.gateway import Gateway
from ncgate.gateway.sim import run_sim
from ncgate.gateway.testing import replay
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

EventDict = dict[str, Any]


def _cell(tmp_path: Path, program: str, aux: str | None = 'handshake = "before_motion"',
          nc: str = "lookahead = 0", dialect: str = "nc110") -> Path:
    table = f"[nc.aux]\n{aux}\n" if aux is not None else ""
    (tmp_path / "ncgate.toml").write_text(
        f'[nc]\nmain = "A"\ndialect = "{dialect}"\n{nc}\n[nc.storage]\nMP0 = "."\n'
        f"[canopen]\nenabled = false\n{table}")
    (tmp_path / "A.nc").write_text(program)
    return tmp_path / "ncgate.toml"


def _sim(config: Path, script: str = "", until: float | None = None) -> Any:
    path = config.parent / "script.toml"
    path.write_text(script)
    return run_sim(load_config(config), "A", load_script(path), until)


def _events(result: Any, *kinds: str) -> list[EventDict]:
    return [e for e in result.events if e["event"] in kinds]


def test_without_an_aux_table_no_word_is_output(tmp_path: Path) -> None:
    result = _sim(_cell(tmp_path, "N10G1X10F600M08S1000T5\nN20M30\n", aux=None))
    assert result.outcome == "idle"
    assert not _events(result, "aux", "write", "wait")


def test_a_handshake_of_none_outputs_the_value_and_nothing_waits(tmp_path: Path) -> None:
    result = _sim(_cell(tmp_path, "N10M08S1000T1.1H7\nN20M00\nN30M30\n",
                        aux='handshake = "none"'))
    assert result.outcome == "stall" or result.outcome == "idle"
    aux = _events(result, "aux")
    # M, S, T (the tool number: T1.1 is tool 1, offset 1), H; M00 and M30 keep their meaning.
    assert [(e["code"], e["handshake"], e["strobe"]) for e in aux] == [
        ("M8", "none", None), ("S1000", "none", None), ("T1", "none", None),
        ("H7", "none", None)]
    writes = [(e["var"], e["value"]) for e in _events(result, "write")]
    assert writes == [("SYVAR192", 8), ("SYVAR193", 1000), ("SYVAR194", 1), ("SYVAR195", 7)]
    assert not _events(result, "wait")


def test_an_acknowledge_with_no_strobe_is_a_plc_side_hazard_and_nothing_else(
        tmp_path: Path) -> None:
    script = '[[write]]\nat = 0.5\nset = "SA960=1"\n'
    result = _sim(_cell(tmp_path, "N10(DLY,1)\nN20M30\n"), script)
    assert result.outcome == "idle" and result.alarms == 0
    (hazard,) = _events(result, "hazard")
    assert hazard["t"] == 0.5 and hazard["proc"] == 1
    assert "PLC-side error" in hazard["message"] and "SA960" in hazard["message"]
    assert "script write[0]" in hazard["message"]


def test_an_acknowledge_left_on_must_drop_and_rise_again(tmp_path: Path) -> None:
    # The PLC sets the acknowledge before any strobe (a hazard), M08 comes at 1.0 with it
    # still on: the NC waits for it to drop (1.5) and rise (2.0), drops its strobe, and goes
    # on when the PLC drops it (2.5).
    script = "".join(f'[[write]]\nat = {t}\nset = "SA960={v}"\n'
                     for t, v in ((0.5, 1), (1.5, 0), (2.0, 1), (2.5, 0)))
    result = _sim(_cell(tmp_path, "N10(DLY,1)\nN20M08\nN30M30\n"), script)
    assert result.outcome == "idle"
    assert [e["t"] for e in _events(result, "hazard")] == [0.5, 1.0]
    assert [(e["event"], e["t"]) for e in _events(result, "aux", "aux_ack", "resume")] == [
        ("aux", 1.0), ("aux_ack", 2.0), ("resume", 2.5)]
    strobe = [(e["value"], e["t"]) for e in _events(result, "write") if e["var"] == "SA896"]
    assert strobe == [(1, 1.0), (0, 2.0)]


def test_an_acknowledge_that_does_not_come_in_time_is_al145(tmp_path: Path) -> None:
    result = _sim(_cell(tmp_path, "N10G1X10F600M08\nN20M30\n",
                        aux='handshake = "before_motion"\ntimeout_s = 2'))
    (alarm,) = _events(result, "alarm")
    assert alarm["code"] == "AL145" and alarm["t"] == 2.0 and alarm["n"] == 10
    assert "M08" in alarm["message"]
    # The NC withdraws its strobe: the PLC sees the function gone.
    assert [(e["value"], e["t"]) for e in _events(result, "write") if e["var"] == "SA896"] == [
        (1, 0.0), (0, 2.0)]


def test_a_reset_withdraws_a_pending_strobe(tmp_path: Path) -> None:
    script = '[[command]]\nat = 1.0\ncommand = "reset"\n'
    result = _sim(_cell(tmp_path, "N10M08\nN20M30\n"), script)
    assert [(e["value"], e["t"]) for e in _events(result, "write") if e["var"] == "SA896"] == [
        (1, 0.0), (0, 1.0)]
    assert _events(result, "end")[0]["how"] == "reset"


def test_after_motion_outputs_when_the_motion_ends_and_the_next_block_waits(
        tmp_path: Path) -> None:
    # G1 X60 at F600: 6 s.  The PLC answers 0.5 s after the strobe, drops 0.25 s after.
    script = ('[[write]]\nwhen = "SA896=1"\nafter = 0.5\nset = "SA960=1"\n'
              '[[write]]\nwhen = "SA960=1"\nafter = 0.25\nset = "SA960=0"\n')
    result = _sim(_cell(tmp_path, "N10G1X60F600M09\nN20SYVAR5=1\nN30M30\n",
                        aux='codes = { M9 = "after_motion" }'), script)
    assert result.outcome == "idle"
    got = [(e["event"], e["t"]) for e in _events(result, "aux", "aux_ack", "resume")]
    assert got == [("aux", 6.0), ("aux_ack", 6.5), ("resume", 6.75)]
    n20 = next(e for e in _events(result, "write") if e["var"] == "SYVAR5")
    assert n20["t"] == 6.75  # the next block waited for the acknowledge's end


def test_a_plain_code_that_crosses_a_pending_handshake_is_a_hazard_naming_it(
        tmp_path: Path) -> None:
    result = _sim(_cell(tmp_path, "N10G1X60F600M08\nN20SYVAR5=1\nN30M30\n",
                        nc="lookahead = 16"), until=1.0)
    (hazard,) = _events(result, "hazard")
    assert hazard["n"] == 20 and hazard["t"] == 0.0
    assert "before the PLC acknowledged M08 above it (N10)" in hazard["message"]


def test_the_isg_dialect_runs_the_same_handshake(tmp_path: Path) -> None:
    script = ('[[write]]\nwhen = "SA897=1"\nafter = 0.5\nset = "SA961=1"\n'
              '[[write]]\nwhen = "SA961=1"\nafter = 0.25\nset = "SA961=0"\n')
    config = _cell(tmp_path, "%channel1\nN10 G01 X60 F600 S1200\nN20 M30\n",
                   aux='codes = { S = "after_motion" }', dialect="isg")
    result = _sim(config, script)
    assert result.outcome == "idle"
    got = [(e["event"], e.get("code"), e["t"]) for e in
           _events(result, "aux", "aux_ack", "resume")]
    assert got == [("aux", "S1200", 6.0), ("aux_ack", "S1200", 6.5), ("resume", None, 6.75)]


@pytest.mark.parametrize(("table", "key"), [
    ('codes = { X8 = "none" }', "nc.aux.codes.X8"),
    ('codes = { M30 = "before_motion" }', "nc.aux.codes.M30"),
    ('codes = { M8 = "later" }', "nc.aux.codes.M8"),
    ('codes = { M8 = "none", M08 = "after_motion" }', "nc.aux.codes.M08"),
    ('handshake = "always"', "nc.aux.handshake"),
    ('value = "SA10"', "nc.aux.value"),
    ('value = "SYVAR250"', "nc.aux.value"),  # P5's H would be SYVAR269: outside 256
    ('strobe = "SA1020"', "nc.aux.strobe"),
    ('ack = "SA900"', "nc.aux.ack"),  # overlaps the strobes SA896..SA915
    ("timeout_s = -1", "nc.aux.timeout_s"),
])
def test_a_bad_aux_table_is_a_config_error_naming_the_key(tmp_path: Path, table: str,
                                                          key: str) -> None:
    with pytest.raises(ConfigError, match=f": {key}: "):
        load_config(_cell(tmp_path, "N10M30\n", aux=table))


def test_ncgate_map_shows_each_process_s_places(tmp_path: Path) -> None:
    from ncgate.gateway.modbus.map import ModbusMap

    rows = ModbusMap(load_config(_cell(tmp_path, "N10M30\n"))).rows()
    p2 = [(r["table"], r["start"], r["end"]) for r in rows
          if str(r["content"]).startswith("P2 auxiliary functions")]
    # P2's values SYVAR196..199 (holding 1000 + n), strobes SA900..903, acks SA964..967.
    assert sorted(p2) == [("coils", 900, 903), ("coils", 964, 967),
                          ("holding registers", 1196, 1199)]


def test_the_run_log_says_what_the_process_waits_for(tmp_path: Path) -> None:
    from ncgate.gateway.cli.serve import describe
    from ncgate.interpreter.engine import events as ev

    result = _sim(_cell(tmp_path, "N10M08\nN20M30\n"))
    heard = [e for e in result.runtime.trace._all if isinstance(e, ev.Aux | ev.Wait)]
    assert [describe(e) for e in heard] == [
        "P1 outputs M8 (before_motion) at A.nc:1 N10",
        "P1 waits at A.nc:1 N10 for the PLC to acknowledge M08 (SA960)"]


async def test_a_session_acknowledged_over_modbus_replays_as_recorded(tmp_path: Path) -> None:
    config = _cell(tmp_path, "N10G1X10F600M08\nN20G1X0M09\nN30M30\n",
                   aux='codes = { M8 = "before_motion", M9 = "after_motion" }',
                   nc="lookahead = 0\ntime_scale = 20.0")
    record = tmp_path / "session.jsonl"
    overrides = {"modbus.port": 0}
    async with Gateway(ncgate_test_config(config, **overrides), record=record,
                       overrides=overrides) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        await plc.command(1)
        await plc.ack_aux(await plc.expect_aux("M08"))
        await plc.ack_aux(await plc.expect_aux("M09"))
        await gw.wait_idle(timeout_s=30)
    acks = [line for line in record.read_text().splitlines()
            if '"event": "write"' in line and '"var": "SA960"' in line]
    assert len(acks) == 4 and all('"who": "modbus 127.0.0.1:' in line for line in acks)
    replay(record)  # raises with the first divergence


def test_st_cannot_write_a_strobe_and_an_acknowledge_without_aux_is_a_hazard(
        tmp_path: Path) -> None:
    from ncgate.plc.st.compiler import Context, compile_logic
    from ncgate.plc.st.diagnostics import LogicError, StCode
    from ncgate.plc.st.parser import parse_source

    source = "PROGRAM p\nNC.P[1].MSTROBE := TRUE;\nEND_PROGRAM\n"
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "p.st")], Context(1024, 512, 256, 5, frozenset()))
    assert [d.code for d in caught.value.diagnostics] == [StCode.READ_ONLY]
    # Without [nc.aux] the logic's acknowledge has nothing to answer: said, the scan goes on.
    (tmp_path / "p.st").write_text("PROGRAM p\nNC.P[1].MACK := TRUE;\nEND_PROGRAM\n")
    config = _cell(tmp_path, "N10(DLY,0.05)\nN20M30\n", aux=None)
    result = run_sim(load_config(config, overrides={"plc.logic": str(tmp_path / "p.st")}),
                     "A", load_script(None))
    assert result.outcome == "idle"
    (hazard,) = _events(result, "hazard")
    assert "NC.P[1].MACK at p.st:2" in hazard["message"] and "[nc.aux]" in hazard["message"]


def test_32_bit_values_take_two_words_the_high_one_first(tmp_path: Path) -> None:
    """nc.aux.value_bits = 32: S40000 (past an int16) in SYVAR193..194 as 0x0000, 0x9C40 --
    the high word first, as a 32-bit value goes in two Modbus registers -- each letter's place
    two words wide (P1's M 192..193, S 194..195, T 196..197)."""
    result = _sim(_cell(tmp_path, "N10M08S40000T70000\nN20M30\n",
                        aux='handshake = "none"\nvalue_bits = 32'))
    writes = [(e["var"], e["value"]) for e in _events(result, "write")]
    assert writes == [("SYVAR192", 0), ("SYVAR193", 8), ("SYVAR194", 0),
                      ("SYVAR195", 40000 - 0x10000), ("SYVAR196", 1), ("SYVAR197", 70000 - 0x10000)]
    assert [e["code"] for e in _events(result, "aux")] == ["M8", "S40000", "T70000"]


def test_a_16_bit_value_past_its_range_is_an_alarm_and_32_bits_hold_it(tmp_path: Path) -> None:
    result = _sim(_cell(tmp_path, "N10S40000\nN20M30\n", aux='handshake = "none"'))
    assert [e["code"] for e in _events(result, "alarm")] == ["AL103"]


async def test_the_virtual_plc_reads_a_32_bit_value(tmp_path: Path) -> None:
    config = _cell(tmp_path, "N10S40000\nN20M30\n",
                   aux='handshake = "before_motion"\nvalue_bits = 32', nc="lookahead = 0")
    async with Gateway(ncgate_test_config(config, **{"modbus.port": 0})) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        await plc.command(1)
        seen = await plc.expect_aux("S40000")
        assert seen.value == 40000
        await plc.ack_aux(seen)
        await gw.wait_idle(timeout_s=30)


@pytest.mark.parametrize("bits", ["value_bits = 24", "value_bits = true", 'value_bits = "32"'])
def test_value_bits_is_16_or_32(tmp_path: Path, bits: str) -> None:
    with pytest.raises(ConfigError, match=r": nc\.aux\.value_bits: expected 16 or 32"):
        load_config(_cell(tmp_path, "N10M30\n", aux=bits))
