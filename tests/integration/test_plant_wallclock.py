"""The plant on the wall clock: ``ncgate run`` as a process, a real Modbus client as the PLC
(the test process), and ``run --script`` judging a scenario while that client drives it."""

from __future__ import annotations

import asyncio
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.gateway.cli.main import main

from .test_cli_run import start_run, stop_run

CELL = """
[nc]
processes = 1
main = "O1"
autostart = true
[modbus]
port = 0
[canopen]
enabled = false
[web]
enabled = false
[plant]
scan_ms = 10
[[plant.model]]
name = "clamp"
kind = "cylinder"
extend = "SA20"
extended = "SA30"
retracted = "SA31"
travel_ms = 300
"""


def _cell(tmp_path: Path) -> Path:
    (tmp_path / "O1.nc").write_text("N10 (WAI,SA30=1)\nN20 M30\n")
    config = tmp_path / "ncgate.toml"
    config.write_text(CELL)
    return config


async def _until(client: AsyncModbusTcpClient, coil: int, value: bool,
                 timeout_s: float = 10.0) -> None:
    """Poll a discrete state: a Modbus client learns of a change no other way."""
    async with asyncio.timeout(timeout_s):
        while True:
            answer = await client.read_coils(coil, count=1, device_id=1)
            if bool(answer.bits[0]) is value:
                return
            await asyncio.sleep(0.005)  # a Modbus poller learns of a change no other way


async def test_an_external_plc_sets_the_valve_and_sees_the_end_switch_after_the_stroke(
        tmp_path: Path) -> None:
    trace = tmp_path / "trace.jsonl"
    proc, port, lines = await start_run(_cell(tmp_path), "--trace", str(trace))
    client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0)
    try:
        assert await client.connect()
        await _until(client, 31, True)  # at rest: retracted
        assert not (await client.read_coils(30, count=1, device_id=1)).bits[0]
        loop = asyncio.get_running_loop()
        await client.write_coil(20, True, device_id=1)
        sent = loop.time()
        await _until(client, 31, False)  # it leaves its end switch as the valve switches
        await _until(client, 30, True)
        seen = loop.time()
        # Not before the stroke's time on the wall clock (time_scale 1): cause and effect.
        assert seen - sent >= 0.3 - 0.005
    finally:
        client.close()
        code, log = await stop_run(proc, lines)
    assert code == 0, log
    events = [json.loads(line) for line in trace.read_text().splitlines()]
    valve = next(e for e in events if e["event"] == "write" and e["var"] == "SA20")
    arrived = next(e for e in events if e["event"] == "write" and e["var"] == "SA30"
                   and e["value"] == 1)
    # On the engine's clock the stroke is exact: 300 ms after the valve's write.
    assert arrived["t"] - valve["t"] == pytest.approx(0.3, abs=1e-6)
    assert arrived["who"] == "plant clamp"
    assert valve["who"].startswith("modbus 127.0.0.1:")
    resume = next(e for e in events if e["event"] == "resume")
    assert resume["t"] == arrived["t"] and resume["writer"] == "plant clamp"


SCENARIO = """
[[expect]]
name = "clamp closes"
cond = "SA30=1"
by = 3.0
[[expect]]
name = "P1 ends"
cond = "P1 IDLE"
within = [1.0, 3.0]
"""


async def _scenario(tmp_path: Path, script: str, *more: str) -> tuple[int, str]:
    path = tmp_path / "scenario.toml"
    path.write_text(script)
    proc, port, lines = await start_run(_cell(tmp_path), "--script", str(path), *more)
    assert proc.stdout is not None
    async with asyncio.timeout(20):  # the scenario starts O1: its t = 0, its faults in force
        while "the scenario's t = 0" not in lines[-1]:
            line = (await proc.stdout.readline()).decode()
            assert line, "".join(lines)
            lines.append(line)
    client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0)
    try:
        assert await client.connect()
        await client.write_coil(20, True, device_id=1)  # the PLC closes the clamp
    finally:
        client.close()
    assert proc.stdout is not None
    async with asyncio.timeout(30):  # it ends by itself at the last window's end
        rest = (await proc.stdout.read()).decode()
        code = await proc.wait()
    return code, "".join(lines) + rest


async def test_run_script_judges_the_good_case_with_a_real_plc_connected(
        tmp_path: Path) -> None:
    code, log = await _scenario(tmp_path, SCENARIO)
    assert code == 0, log
    assert "PASS clamp closes: SA30=1 at" in log
    assert "PASS P1 ends: P1 IDLE at 1.000 s" in log
    # The scenario starts the main program: the log said it "waits for cycle start".
    assert "main O1 (the scenario starts it)" in log and "waits for cycle start" not in log


async def test_run_script_fails_a_bad_case_and_exits_1(tmp_path: Path) -> None:
    code, log = await _scenario(tmp_path, SCENARIO + '[[fault]]\ntarget = "clamp"\n'
                                'kind = "never"\nat = 0.0\n')
    assert code == 1, log
    assert "FAIL clamp closes: SA30 still 0 at 3.000 s" in log
    assert "clamp retracted (fault: never)" in log
    assert "FAIL P1 ends:" in log


async def test_a_scripts_modbus_fault_is_seen_by_the_client_inside_its_window(
        tmp_path: Path) -> None:
    """run --script with a [[fault]] on the Modbus server: the client's read is answered
    with exception 06 while it is in force, and normally once its for_s has run out."""
    path = tmp_path / "scenario.toml"
    path.write_text('[[fault]]\ntarget = "modbus"\nkind = "exception"\ncode = 6\nat = 0.0\n'
                    'for_s = 1.0\n[[expect]]\nname = "clamp at rest"\ncond = "SA31=1"\n'
                    'by = 5.0\n')  # (it serves until 5 s: the client is done long before)
    trace = tmp_path / "trace.jsonl"
    proc, port, lines = await start_run(_cell(tmp_path), "--script", str(path), "--trace",
                                        str(trace))
    client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0)
    answers = []
    try:
        assert await client.connect()
        async with asyncio.timeout(10):
            # (a read may come before the scenario is armed: the log says where Modbus
            # listens first) -- until it has seen the fault and then its end
            while 6 not in answers or answers[-1] != "ok":
                answer = await client.read_coils(31, count=1, device_id=1)
                answers.append(answer.exception_code if answer.isError() else "ok")
                await asyncio.sleep(0.05)  # a poller polls
    finally:
        client.close()
    assert proc.stdout is not None
    async with asyncio.timeout(30):
        rest = (await proc.stdout.read()).decode()
        code = await proc.wait()
    assert code == 0, "".join(lines) + rest
    first = answers.index(6)
    assert set(answers[:first]) <= {"ok"} and answers[-1] == "ok"
    assert set(answers[first:-1]) == {6}  # inside the window, every read: exception 06
    events = [json.loads(line) for line in trace.read_text().splitlines()]
    fault = next(e for e in events if e["event"] == "fault")
    clear = next(e for e in events if e["event"] == "fault_clear")
    assert (fault["target"], fault["who"]) == ("modbus", "script fault[0]")
    assert clear["t"] - fault["t"] == pytest.approx(1.0, abs=1e-6)


def _junit(path: Path) -> dict[str, str | None]:
    """Each testcase's name, and its failure's text (None: it passed)."""
    assert not list(path.parent.glob(f".{path.name}.*"))  # written whole, nothing beside it
    suites = ET.parse(path).getroot()
    assert suites.tag == "testsuites"
    (suite,) = suites  # one scenario
    assert suite.get("name") == str(path.parent / "scenario.toml")
    cases = {}
    for case in suite.iter("testcase"):
        failure = case.find("failure")
        cases[case.get("name") or ""] = None if failure is None else failure.text
    assert suites.get("tests") == str(len(cases))
    assert suites.get("failures") == str(sum(v is not None for v in cases.values()))
    return cases


async def test_run_script_writes_its_verdicts_as_junit_for_ci(tmp_path: Path) -> None:
    junit = tmp_path / "verdicts.xml"
    code, log = await _scenario(tmp_path, SCENARIO, "--junit", str(junit))
    assert code == 0, log
    assert _junit(junit) == {"clamp closes": None, "P1 ends": None}


async def test_run_script_junit_holds_the_failures_a_bad_case_prints(tmp_path: Path) -> None:
    junit = tmp_path / "verdicts.xml"
    code, log = await _scenario(tmp_path, SCENARIO + '[[fault]]\ntarget = "clamp"\n'
                                'kind = "never"\nat = 0.0\n', "--junit", str(junit))
    assert code == 1, log
    cases = _junit(junit)
    assert set(cases) == {"clamp closes", "P1 ends"}
    failed = cases["clamp closes"]
    assert failed is not None and failed.startswith("FAIL clamp closes: SA30 still 0 at 3.000 s")
    assert failed in log  # the line the run printed, word for word
    assert cases["P1 ends"] is not None


def test_run_junit_is_refused_before_anything_serves(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    config = _cell(tmp_path)
    script = tmp_path / "scenario.toml"
    script.write_text(SCENARIO)
    assert main(["run", "--config", str(config), "--junit", str(tmp_path / "v.xml")]) == 2
    assert "--junit goes with --script" in capsys.readouterr().err
    assert main(["run", "--config", str(config), "--script", str(script), "--junit",
                 str(tmp_path / "missing" / "v.xml")]) == 2
    assert "no folder" in capsys.readouterr().err
