"""I/O names (issue 28, item 3): [symbols] names image variables; the API and the sim script
take a name wherever they take a variable, and a wait's why-record shows it beside."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import ConfigError, load_config
from ncgate.config.script import load_script
from ncgate.gateway import Gateway
from ncgate.gateway.sim import run_sim

CELL = """[nc]
main = "A"
[nc.storage]
MP0 = "."
[canopen]
enabled = false
[symbols]
door_closed = "SA10"
spindle_speed = { var = "SYVAR3", comment = "rpm / 10" }
"""


def _cell(tmp_path: Path) -> Path:
    (tmp_path / "ncgate.toml").write_text(CELL)
    (tmp_path / "A.nc").write_text("N1(WAI,SA10=1)\nN2SYVAR4=SYVAR3\nN3M30\n")
    return tmp_path / "ncgate.toml"


async def test_the_api_writes_and_reads_by_name_and_the_why_record_shows_it(
        tmp_path: Path) -> None:
    async with Gateway(load_config(_cell(tmp_path), overrides={"modbus.port": 0})) as gw:
        await gw.start()
        await gw.wait_state(1, "WAIT_COND", timeout_s=10)
        assert "waits for door_closed (SA10=1) (now 0" in gw.describe_blocked()
        gw.write("spindle_speed", 120)
        gw.write("DOOR_CLOSED", 1)  # names are not case-sensitive
        await gw.wait_idle(timeout_s=10)
        assert gw.read("SYVAR4") == 120 and gw.read("door_closed") == 1


async def test_the_run_log_and_the_trace_name_the_variable_a_wait_is_on(
        tmp_path: Path) -> None:
    from ncgate.gateway.cli.serve import describe
    from ncgate.interpreter.engine import events as ev

    heard: list[ev.Event] = []
    async with Gateway(load_config(_cell(tmp_path), overrides={"modbus.port": 0}),
                       listeners=[heard.append]) as gw:
        await gw.start()
        await gw.wait_state(1, "WAIT_COND", timeout_s=10)
        waits = [e for e in gw.trace if e["event"] == "wait"]
    assert waits[0]["on"] == {"cond": "SA10=1", "value": 0, "name": "door_closed"}
    lines = [describe(e) for e in heard if isinstance(e, ev.Wait)]
    assert lines == ["P1 waits at A.nc:1 N1 for door_closed (SA10=1) (now 0)"]


def test_a_stall_report_names_the_variable(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    from ncgate.gateway.cli.main import main

    assert main(["sim", "--config", str(_cell(tmp_path))]) == 1
    out = capsys.readouterr().out
    assert "P1 A.nc:1 N1 (WAI,SA10=1) waits for door_closed (SA10=1) (now 0)" in out


def test_the_sim_script_takes_names(tmp_path: Path) -> None:
    (tmp_path / "s.toml").write_text('[[write]]\nwhen = "P1 WAIT_COND"\nafter = 1.0\n'
                                     'set = "door_closed=1"\n[[write]]\nat = 0.5\n'
                                     'set = "spindle_speed=7"\n')
    result = run_sim(load_config(_cell(tmp_path)), "A", load_script(tmp_path / "s.toml"))
    assert result.exit_status == 0
    writes = [(e["var"], e["value"], e["t"]) for e in result.events if e["event"] == "write"]
    assert writes == [("SYVAR3", 7, 0.5), ("SA10", 1, 1.0), ("SYVAR4", 7, 1.0)]


def test_a_state_entry_that_holds_as_it_is_armed_fires_once(tmp_path: Path) -> None:
    """`when = "P1 RUNNING"` holds as the scenario starts: it fires then, and not again as P1
    runs on after its first dwell ("fires once, the first time it holds": docs/script.md;
    it wrote SYVAR1=1 again at 0.1 s)."""
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "D"\n[nc.storage]\nMP0 = "."\n')
    (tmp_path / "D.nc").write_text("N1 (DLY,0.1)\nN2 G4 X0.1\nN3 (DLY,0.1)\nN4 M30\n")  # dwells
    (tmp_path / "s.toml").write_text('[[write]]\nwhen = "P1 RUNNING"\nset = "SYVAR1=1"\n'
                                     '[[write]]\nat = 0.05\nset = "SYVAR1=0"\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "D",
                     load_script(tmp_path / "s.toml"))
    writes = [(e["value"], e["t"]) for e in result.events
              if e["event"] == "write" and e["var"] == "SYVAR1"]
    assert writes == [(1, 0.0), (0, 0.05)]


@pytest.mark.parametrize(("table", "message"), [
    ('door = "SA99999"', "symbols.door: SA99999 is outside the image"),
    ('door = "X10"', "symbols.door: expected an image variable"),
    ('SA12 = "SA10"', "symbols.SA12: a name is letters"),
    ('door = "SA10"\nDOOR = "SA11"', "symbols.DOOR: 'DOOR' is 'door' already"),
])
def test_a_bad_name_is_a_config_error_naming_the_key(tmp_path: Path, table: str,
                                                     message: str) -> None:
    (tmp_path / "ncgate.toml").write_text(f"[symbols]\n{table}\n")
    with pytest.raises(ConfigError, match=message):
        load_config(tmp_path / "ncgate.toml")


@pytest.mark.parametrize("io_list", [
    "name,var,comment\nspindle_on,SA11,M03 issued\nfeed_rate,SYVAR7,\n",
    # as a PLC tool exports it: semicolons, a BOM, a blank line, a header in capitals
    "\ufeffName;Var;Comment\nspindle_on;SA11;M03 issued\n\nfeed_rate;SYVAR7;mm/min\n",
])
async def test_a_csv_io_list_adds_names(tmp_path: Path, io_list: str) -> None:
    (tmp_path / "io.csv").write_text(io_list, encoding="utf-8")
    config = _cell(tmp_path)
    config.write_text('symbols_file = "io.csv"\n' + CELL)
    loaded = load_config(config, overrides={"modbus.port": 0})
    assert loaded.symbols == {"spindle_on": "SA11", "feed_rate": "SYVAR7",
                              "door_closed": "SA10", "spindle_speed": "SYVAR3"}
    async with Gateway(loaded) as gw:
        gw.write("spindle_on", 1)
        gw.write("FEED_RATE", -5)
        assert gw.read("SA11") == 1 and gw.read("SYVAR7") == -5


@pytest.mark.parametrize(("io_list", "message"), [
    ("name,address\ndoor,SA1\n", r"symbols_file: .*io.csv:1: expected a header"),
    ("name,var\nok,SA1\ndoor,X10\n",
     r"symbols_file \(io.csv:3\) door: expected an image variable"),
    ("name,var\ndoor,SA1,extra\n", r"symbols_file: .*io.csv:2: expected 2 columns"),
    ("name,var\ndoor,SA99999\n", r"symbols_file \(io.csv:2\) door: SA99999 is outside"),
    # a name the CSV and [symbols] both give: the second place is named
    ("name,var\nDoor_Closed,SA1\n", r"symbols.door_closed: 'door_closed' is 'Door_Closed'"),
])
def test_a_bad_io_list_is_a_config_error_naming_the_row(tmp_path: Path, io_list: str,
                                                        message: str) -> None:
    (tmp_path / "io.csv").write_text(io_list)
    (tmp_path / "ncgate.toml").write_text('symbols_file = "io.csv"\n' + CELL)
    with pytest.raises(ConfigError, match=message):
        load_config(tmp_path / "ncgate.toml")


def test_ncgate_map_lists_the_names_at_their_addresses(tmp_path: Path) -> None:
    """`ncgate map --format csv` has a row per I/O name, with a names column and its comment:
    SA10 is coil 10, SYVAR3 is holding 1003 (the default map)."""
    import csv
    import io
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "ncgate", "map", "--config",
                           str(_cell(tmp_path)), "--format", "csv"], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    rows = {row["name"]: row for row in csv.DictReader(io.StringIO(done.stdout))
            if row["name"]}
    assert set(rows) == {"door_closed", "spindle_speed"}
    assert rows["door_closed"]["table"].startswith("coil")
    assert rows["door_closed"]["start"] == "10"
    assert rows["spindle_speed"]["table"].startswith("holding")
    assert rows["spindle_speed"]["start"] == "1003"
    assert rows["spindle_speed"]["comment"] == "rpm / 10"  # as [symbols] gives it
    assert rows["door_closed"]["comment"] == ""


def test_an_io_list_s_comments_reach_the_map(tmp_path: Path) -> None:
    (tmp_path / "io.csv").write_text("name;var;comment\nspindle_on;SA11;M03 issued\n")
    config = _cell(tmp_path)
    config.write_text('symbols_file = "io.csv"\n' + CELL)
    from ncgate.gateway.modbus.map import ModbusMap

    text = ModbusMap(load_config(config)).render("md")
    assert "| spindle_on (M03 issued) |" in text and "| spindle_speed (rpm / 10) |" in text


async def test_the_python_api_forces_by_name(tmp_path: Path) -> None:
    async with Gateway(load_config(_cell(tmp_path), overrides={"modbus.port": 0})) as gw:
        gw.force("door_closed", 1)
        gw.write("SA10", 0)  # overridden
        assert gw.read("door_closed") == 1 and gw.image.forced == {("SA", 10, "bit"): 1}
        gw.force("DOOR_CLOSED", None)
        assert gw.image.forced == {}


def test_a_role_may_write_the_overrides_region_by_its_name() -> None:
    from ncgate.gateway.modbus.map import ModbusMap, Table

    region = ModbusMap(load_config(None)).region(Table.HOLDING, 2010, 2)
    assert region.name == "overrides"  # (it was "": no role could write it)
