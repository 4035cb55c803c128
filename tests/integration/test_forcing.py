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
from ncgate.inputs import Command, CommandKind, Force, Var

LOGIC = """PROGRAM main
VAR n : INT; END_VAR
n := n + 1;
SA[20] := TRUE;          (* every scan *)
SYVAR[5] := n;
END_PROGRAM
"""


def cell(tmp_path: Path, logic: str | None = None, more: str = "") -> None:
    """A cell whose main waits on SA21 (so it stays up), with ``logic`` as its PLC logic."""
    (tmp_path / "A.nc").write_text("N1(WAI,SA21=1)\nN2M30\n")
    plc = '[plc]\nlogic = "logic.st"\n' if logic is not None else ""
    if logic is not None:
        (tmp_path / "logic.st").write_text(logic)
    (tmp_path / "ncgate.toml").write_text(
        f'[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n{plc}[canopen]\nenabled = false\n{more}')


async def test_a_forced_bit_holds_against_plc_logic_and_a_modbus_writer(tmp_path: Path) -> None:
    cell(tmp_path, LOGIC)
    record = tmp_path / "session.jsonl"
    async with Gateway(ncgate_test_config(tmp_path / "ncgate.toml"), record=record) as gw:
        watch = PlcWatch(gw)
        await watch.until("main.n", test=lambda v: v >= 3)
        assert gw.read("SA20") == 1  # the logic wrote it
        gw.apply(Force(Var.parse("SA20"), 0))
        n = watch.read("main.n")
        # five scans more, each writing SA20 := TRUE
        await watch.until("main.n", test=lambda v: v >= n + 5)
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
        await watch.until("main.n", test=lambda v: v >= n + 2)
        assert gw.read("SA20") == 1
        trace = gw.trace
    forces = [(e["var"], e["value"]) for e in trace if e["event"] == "force"]
    assert forces == [("SA20", 0), ("SA20", None)]
    overridden = [e["who"].split()[0] for e in trace if e["event"] == "forced"]
    assert overridden[0] == "plc" and "modbus" in overridden  # the logic's and Modbus's tries
    lines = [line for line in record.read_text().splitlines() if '"input": "force"' in line]
    assert len(lines) == 2
    assert replay(record).divergence is None


# The force table (docs/decisions.md): holding 2100..2103 a request (action, kind, index,
# value), 2104 the count, 2105.. the list, 3 registers a force (kind, index, value).
FORCE, FORCE_SA_BIT, FORCE_SYVAR = 2100, 1, 6


async def test_a_modbus_client_forces_through_the_force_table(tmp_path: Path) -> None:
    cell(tmp_path, LOGIC)
    record = tmp_path / "session.jsonl"
    async with Gateway(ncgate_test_config(tmp_path / "ncgate.toml"), record=record) as gw:
        watch = PlcWatch(gw)
        await watch.until("main.n", test=lambda v: v >= 3)
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            async def table() -> list[int]:
                answer = await client.read_holding_registers(FORCE, count=11, device_id=1)
                assert not answer.isError()
                return list(answer.registers)

            # Force SA20 off and SYVAR5 to -2 (int16 in a register: 0xFFFE).
            for request in ([1, FORCE_SA_BIT, 20, 0], [1, FORCE_SYVAR, 5, 0xFFFE]):
                answer = await client.write_registers(FORCE, request, device_id=1)
                assert not answer.isError()
            n = watch.read("main.n")
            # the logic writes both every scan
            await watch.until("main.n", test=lambda v: v >= n + 5)
            assert gw.read("SA20") == 0 and gw.read("SYVAR5") == -2
            assert not (await client.write_coil(20, True, device_id=1)).isError()
            assert gw.read("SA20") == 0  # a Modbus writer is overridden too
            # The list: the request reads 0; 2 forced; SA bit 20 = 0, SYVAR 5 = 0xFFFE.
            assert await table() == [0, 0, 0, 0, 2, FORCE_SA_BIT, 20, 0, FORCE_SYVAR, 5,
                                     0xFFFE]
            assert sorted(gw.image.forced) == [("SA", 20, "bit"), ("SYVAR", 5, "IN")]

            # Bad requests are refused with their code, and nothing of them is forced.
            for request, code in (([9, FORCE_SA_BIT, 21, 1], 3),   # no such action
                                  ([1, 9, 21, 1], 3),              # no such kind
                                  ([1, FORCE_SA_BIT, 21, 2], 3),   # a bit is 0 or 1
                                  ([1, FORCE_SA_BIT, 60000, 1], 2)):  # outside the image
                answer = await client.write_registers(FORCE, request, device_id=1)
                assert answer.isError() and answer.exception_code == code, request
            answer = await client.write_register(FORCE, 1, device_id=1)  # not one FC16 of 4
            assert answer.isError() and answer.exception_code == 2
            answer = await client.write_registers(FORCE + 4, [0], device_id=1)  # the list
            assert answer.isError() and answer.exception_code == 2
            assert len(gw.image.forced) == 2

            # Release SA20: the logic writes it again; then release every one.
            assert not (await client.write_registers(FORCE, [2, FORCE_SA_BIT, 20, 0],
                                                     device_id=1)).isError()
            n = watch.read("main.n")
            await watch.until("main.n", test=lambda v: v >= n + 2)
            assert gw.read("SA20") == 1
            assert (await table())[4:8] == [1, FORCE_SYVAR, 5, 0xFFFE]
            assert not (await client.write_registers(FORCE, [3, 0, 0, 0],
                                                     device_id=1)).isError()
            assert await table() == [0] * 11
            n = watch.read("main.n")
            await watch.until("main.n", test=lambda v: v >= n + 2)
            assert gw.read("SYVAR5") > 0  # SYVAR[5] := n again
        finally:
            client.close()
        trace = gw.trace
    forces = [(e["var"], e["value"], e["who"].split()[0]) for e in trace
              if e["event"] == "force"]
    assert forces == [("SA20", 0, "modbus"), ("SYVAR5", -2, "modbus"),
                      ("SA20", None, "modbus"), (None, None, "modbus")]
    assert replay(record).divergence is None


def test_the_force_table_is_named_force_for_roles_and_read_only() -> None:
    from ncgate.config import load_config
    from ncgate.gateway.modbus.map import ModbusMap, Table

    served = ModbusMap(load_config(None))
    assert {served.region(Table.HOLDING, a, 1).name for a in (FORCE, FORCE + 4)} == {"force"}
    assert served.region(Table.HOLDING, FORCE, 4).access == "w"
    locked = ModbusMap(load_config(None, overrides={"modbus.map.read_only": ["force"]}))
    assert locked.region(Table.HOLDING, FORCE, 4).access == "r"


async def test_the_run_log_says_what_was_forced_and_released(tmp_path: Path) -> None:
    from ncgate.gateway.cli.serve import describe
    from ncgate.interpreter.engine import events as ev

    cell(tmp_path)
    heard: list[ev.Event] = []
    async with Gateway(ncgate_test_config(tmp_path / "ncgate.toml"),
                       listeners=[heard.append]) as gw:
        gw.apply(Force(Var.parse("SA20"), 1))
        gw.write("SA20", 0)  # overridden
        gw.apply(Force(Var.parse("SA20"), None))
        gw.apply(Force(None, None))
    lines = [describe(e) for e in heard if isinstance(e, ev.Force | ev.Forced)]
    assert lines == ["SA20 forced to 1 (by api)", "SA20 = 0 by api overridden by force",
                     "SA20 released (by api)", "every force released (by api)"]


PLC_LOGIC = """PROGRAM main
VAR n : INT; on : BOOL; speed : REAL; t : TON; zero : INT; END_VAR
IF SA[30] THEN n := n / zero; END_IF;   (* a FAULT on demand *)
n := n + 1;
SYVAR[5] := n;           (* what the logic made of n inside the scan *)
on := NOT on;
SA[20] := on;
speed := 1.5;
END_PROGRAM
"""


async def test_a_forced_plc_variable_is_kept_at_the_start_and_end_of_every_scan(
        tmp_path: Path) -> None:
    """As CODESYS forces (docs/decisions.md): the forced value is set before the logic runs
    and again after it, so the logic sees it each scan and what it leaves is overridden."""
    cell(tmp_path, PLC_LOGIC)
    record = tmp_path / "session.jsonl"
    async with Gateway(ncgate_test_config(tmp_path / "ncgate.toml"), record=record) as gw:
        watch = PlcWatch(gw)
        await watch.until("main.n", test=lambda v: v >= 3)
        gw.apply(Force("main.n", 100))
        gw.apply(Force("main.on", True))
        gw.apply(Force("MAIN.SPEED", -2))
        for _ in range(5):  # five scans more: each starts and ends with the forced values
            await watch.next_scan()
            assert watch.read("main.n") == 100 and watch.read("main.on") is True
            assert watch.read("main.speed") == -2.0
            assert gw.read("SYVAR5") == 101  # the logic ran on 100 and stored 101
            assert gw.read("SA20") == 0      # NOT TRUE, inside the scan
        # A restart makes the programs anew (n := 0): the first scan starts from the force.
        gw.write("SA30", 1)
        await watch.until("main.n", test=lambda _: gw.plc.status.state.name == "FAULT")
        gw.write("SA30", 0)
        gw.apply(Command(CommandKind.RESTART_PLC))
        await watch.next_scan()
        assert gw.read("SYVAR5") == 101 and watch.read("main.n") == 100
        # Refused, with nothing forced: no such variable, a value it cannot hold, an FB's
        # member, a value of another type.
        for var, value, reason in (("main.nope", 1, Reason.UNKNOWN_VARIABLE),
                                   ("other.n", 1, Reason.UNKNOWN_VARIABLE),
                                   ("main.n", 40000, Reason.BAD_VALUE),
                                   ("main.on", 2, Reason.BAD_VALUE),
                                   ("main.t.Q", 1, Reason.UNKNOWN_VARIABLE),
                                   ("main.t", 1, Reason.BAD_VALUE),
                                   ("main.n", 1.5, Reason.BAD_VALUE)):
            with pytest.raises(InputRefused) as caught:
                gw.apply(Force(var, value))
            assert caught.value.reason is reason, (var, value)
        assert sorted(gw.runtime.plc.forced) == ["MAIN.N", "MAIN.ON", "MAIN.SPEED"]
        gw.apply(Force("main.n", None))  # released: counting goes on from 100
        await watch.until("main.n", test=lambda v: v >= 103)
        gw.apply(Force(None, None))
        await watch.next_scan()
        assert not gw.runtime.plc.forced
        trace = gw.trace
    forces = [(e["var"], e["value"]) for e in trace if e["event"] == "force"]
    assert forces == [("main.n", 100), ("main.on", True), ("MAIN.SPEED", -2),
                      ("main.n", None), (None, None)]
    overridden = {(e["var"], e["value"]) for e in trace
                  if e["event"] == "forced" and e["who"] == "plc"}
    assert ("main.n", 101) in overridden and ("main.on", False) in overridden
    assert ("MAIN.SPEED", 1.5) in overridden
    assert replay(record).divergence is None


async def test_the_api_forces_a_plc_variable_and_lists_it(tmp_path: Path) -> None:
    import aiohttp

    cell(tmp_path, PLC_LOGIC, "[web]\nport = 0\n")
    async with Gateway(ncgate_test_config(tmp_path / "ncgate.toml"), console=True) as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            for body, status in (({"var": "main.on", "value": True}, 200),
                                 ({"var": "main.speed", "value": 2.5}, 200),
                                 ({"var": "SA10", "value": 1}, 200),
                                 ({"var": "main.nope", "value": 1}, 422),
                                 ({"var": "main.speed", "value": "fast"}, 400),
                                 ({"var": "main.n", "value": 1e9}, 422)):
                async with http.post("/api/force", json=body) as r:
                    assert r.status == status, (body, r.status, await r.text())
            async with http.get("/api/force") as r:
                assert (await r.json())["forced"] == [
                    {"var": "SA10", "value": 1}, {"var": "main.on", "value": True},
                    {"var": "main.speed", "value": 2.5}]
            await PlcWatch(gw).next_scan()
            assert PlcWatch(gw).read("main.on") is True
            async with http.delete("/api/force") as r:
                assert r.status == 200
        assert not gw.runtime.plc.forced and not gw.image.forced
