"""Online change of the PLC logic while the gateway runs (issue 29, item 5): the command
``reload_plc`` through every door -- the API, the console's HTTP API, Modbus command word 16,
CANopen 0x2400:1 = 16 -- and ``run --watch``; values and FB state kept, a load error leaving
the old logic running with its diagnostics in the answer, the log and the trace; recorded and
replayed."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from ncgate.config import load_config
from ncgate.errors import InputRefused, Reason
from ncgate.gateway import Gateway
from ncgate.gateway.record import replay
from ncgate.gateway.testing.canopen_kit import CanopenMaster
from ncgate.gateway.testing.modbus_kit import VirtualPLC, VirtualPLCError
from ncgate.gateway.testing.plc_kit import PlcWatch
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.inputs import Command, CommandKind, Source, SourceKind
from ncgate.interpreter.engine.events import Event, PlcReload
from ncgate.plc.scan import PlcState

from .test_cli_run import start_run, stop_run

V1 = """PROGRAM main
VAR
  scans : DINT;
  t : TON;
  step : INT := 1;
END_VAR
scans := scans + 1;
t(IN := TRUE, PT := T#2s);
SYVAR[0] := step;
END_PROGRAM
"""
V2 = V1.replace("step : INT := 1;", "step : INT := 1;\n  added : INT := 7;").replace(
    "SYVAR[0] := step;", "SYVAR[0] := step + 10 * added;")
BROKEN = V1.replace("SYVAR[0] := step;", "SYVAR[0] := step +;")


def cell(tmp_path: Path, **overrides: Any) -> Gateway:
    (tmp_path / "logic.st").write_text(V1)
    (tmp_path / "ncgate.toml").write_text('[plc]\nlogic = "logic.st"\n')
    return Gateway(ncgate_test_config(tmp_path / "ncgate.toml", **overrides), console=True)


class Reloads:
    """The trace's plc_reload events, waited on as they come."""

    def __init__(self, gw: Gateway) -> None:
        self.seen: list[PlcReload] = []
        self._came = asyncio.Event()
        self.stop: Callable[[], None] = gw.runtime.trace.subscribe(self._hear)

    def _hear(self, event: Event) -> None:
        if isinstance(event, PlcReload):
            self.seen.append(event)
            self._came.set()

    async def nth(self, k: int = 0, timeout_s: float = 20.0) -> PlcReload:
        """The k-th plc_reload since this began to listen (0: the first)."""
        async with asyncio.timeout(timeout_s):
            while len(self.seen) <= k:
                self._came.clear()
                await self._came.wait()
        return self.seen[k]


@pytest.fixture
async def gw(tmp_path: Path) -> AsyncIterator[Gateway]:
    async with cell(tmp_path) as gateway:
        yield gateway


async def test_a_reload_keeps_values_and_timers_and_runs_the_new_logic(
        gw: Gateway, tmp_path: Path) -> None:
    watch = PlcWatch(gw)
    await watch.until("main.scans", test=lambda n: n >= 5)
    (tmp_path / "logic.st").write_text(V2)
    reloads = Reloads(gw)
    before = watch.read("main.t.ET")
    outcome = await gw.reload_plc()
    assert outcome.ok and outcome.initial == ("main.added",) and outcome.dropped == ()
    assert outcome.kept == 3  # scans, t, step
    event = await reloads.nth()
    assert (event.ok, event.initial, event.by) == (True, ["main.added"], "api")
    assert watch.read("main.scans") >= 5  # kept, not restarted from 0
    assert watch.read("main.t.ET") >= before  # the timer runs on from where it was
    assert await watch.until("main.added", 7) == 7
    assert gw.read("SYVAR0") == 1 + 10 * 7 or await _until(gw, "SYVAR0", 71)


async def _until(gw: Gateway, var: str, value: int) -> bool:
    watch = PlcWatch(gw)
    await watch.until("main.scans", test=lambda _: gw.read(var) == value)
    return True


async def test_a_load_error_leaves_the_old_logic_running_and_says_where(
        gw: Gateway, tmp_path: Path) -> None:
    watch = PlcWatch(gw)
    await watch.until("main.scans", test=lambda n: n >= 3)
    logic = tmp_path / "logic.st"
    logic.write_text(BROKEN)
    reloads = Reloads(gw)
    outcome = await gw.reload_plc()
    assert not outcome.ok
    assert any(f"{logic}:9:19: error ST002" in d for d in outcome.diagnostics)
    event = await reloads.nth()
    assert not event.ok and event.diagnostics == list(outcome.diagnostics)
    scans = watch.read("main.scans")
    assert await watch.until("main.scans", test=lambda n: n > scans + 2)  # the old logic
    assert gw.plc.status.state is PlcState.RUNNING and gw.read("SYVAR0") == 1


async def test_reloads_asked_for_while_one_waits_join_it_not_a_queue(
        gw: Gateway, tmp_path: Path) -> None:
    """Twenty asks at once: the first reloads, the second waits for it, and the other
    eighteen join the second (it has not read the files yet), so two reloads, each traced,
    and every ask answered with what loaded -- not twenty reloads queued one after another
    (100 a second on Modbus word 16 piled up without end)."""
    (tmp_path / "logic.st").write_text(V2)
    reloads = Reloads(gw)
    outcomes = await asyncio.gather(*(gw.reload_plc() for _ in range(20)))
    assert all(o.ok for o in outcomes)
    assert outcomes[0].initial == ("main.added",)  # V1 -> V2
    assert all(o.initial == () for o in outcomes[1:])  # V2 -> V2
    await reloads.nth(1)
    assert len(reloads.seen) == 2
    assert await PlcWatch(gw).until("main.added", 7) == 7


async def test_without_logic_reload_plc_is_refused_as_not_configured() -> None:
    async with Gateway(ncgate_test_config()) as gw:
        with pytest.raises(InputRefused) as caught:
            await gw.reload_plc()
        assert caught.value.reason is Reason.NOT_CONFIGURED
        with pytest.raises(InputRefused):
            gw.apply(Command(CommandKind.RELOAD_PLC))


async def test_the_console_answers_with_the_outcome(gw: Gateway, tmp_path: Path) -> None:
    host, port = gw.web_address
    async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
        (tmp_path / "logic.st").write_text(V2)
        async with http.post("/api/command", json={"command": "reload_plc"}) as r:
            assert r.status == 200
            body = await r.json()
        assert body["ok"] and body["initial"] == ["main.added"]
        (tmp_path / "logic.st").write_text(BROKEN)
        async with http.post("/api/command", json={"command": "reload_plc"}) as r:
            assert r.status == 422
            body = await r.json()
        assert not body["ok"] and "ST002" in body["diagnostics"][0]
        async with http.post("/api/command", json={"command": "reload_plc",
                                                    "process": 1}) as r:
            assert r.status == 400


async def test_modbus_command_word_16_reloads(gw: Gateway, tmp_path: Path) -> None:
    (tmp_path / "logic.st").write_text(V2)
    reloads = Reloads(gw)
    async with VirtualPLC(*gw.modbus_address, gw.config) as plc:
        await plc.command(16)
        event = await reloads.nth()
        assert event.ok and event.by.startswith("modbus 127.0.0.1:")
        await PlcWatch(gw).until("main.added", 7)
        with pytest.raises(VirtualPLCError, match="exception_code=3"):
            await plc.command(0x0116)  # of one process: the cell's command only
        assert len(reloads.seen) == 1


async def test_canopen_command_value_16_reloads(gw: Gateway, tmp_path: Path) -> None:
    (tmp_path / "logic.st").write_text(V2)
    reloads = Reloads(gw)
    master = CanopenMaster(gw.config)
    try:
        await master.download(0x2400, 1, (16).to_bytes(2, "little"))
        event = await reloads.nth()
        assert event.ok and event.by.startswith("canopen")
    finally:
        master.close()
    await PlcWatch(gw).until("main.added", 7)


async def test_a_recorded_reload_replays_the_logic_the_session_ran(tmp_path: Path) -> None:
    """The record carries the logic's sources (at its start, and each reload's): the replay
    runs V1, then V2 from the reload's time, whatever the file holds when it replays."""
    record = tmp_path / "session.jsonl"
    gw = Gateway(cell(tmp_path).config, record=record)
    async with gw:
        watch = PlcWatch(gw)
        await watch.until("main.scans", test=lambda n: n >= 3)
        (tmp_path / "logic.st").write_text(V2)
        assert (await gw.reload_plc(Source(SourceKind.API, "test"))).ok
        await watch.until("main.added", 7)
    (tmp_path / "logic.st").write_text(V2.replace("added : INT := 7", "added : INT := 9"))
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    command = next(x for x in lines if x.get("input") == "command")
    assert (command["command"], command["who"]) == ("reload_plc", "api test")
    logic = [x for x in lines if "plc_logic" in x]
    assert [x["plc_logic"] for x in logic] == [{str(tmp_path / "logic.st"): V1},
                                               {str(tmp_path / "logic.st"): V2}]
    assert lines.index(logic[1]) == lines.index(command) + 1
    recorded = next(x for x in lines if x.get("event") == "plc_reload")
    assert recorded["ok"] and recorded["initial"] == ["main.added"]
    assert command["t"] <= recorded["t"]
    result = replay(record)
    assert result.divergence is None
    assert not [w for w in result.warnings if "logic.st" in w]  # the record's logic ran
    replayed = [e for e in result.runtime.trace.events if e["event"] == "plc_reload"]
    assert len(replayed) == 1 and replayed[0]["ok"] and replayed[0]["by"] == "api test"
    assert abs(replayed[0]["t"] - command["t"]) < 1e-6
    # V1 ran before the reload (V2's 'added' was new to it), then V2 as recorded (7, not
    # the file's 9 now).
    assert replayed[0]["initial"] == ["main.added"]
    assert result.runtime.plc is not None and result.runtime.plc.read("main.added") == 7


async def test_run_watch_reloads_when_a_logic_file_changes(tmp_path: Path) -> None:
    logic = tmp_path / "logic.st"
    logic.write_text(V1)
    config = tmp_path / "ncgate.toml"
    config.write_text('[plc]\nlogic = "logic.st"\n[modbus]\nport = 0\n[canopen]\n'
                      "enabled = false\n")
    proc, port, lines = await start_run(config, "--watch", "--no-web", "--allow-missing")
    assert proc.stdout is not None

    async def line_with(text: str) -> str:
        async with asyncio.timeout(20):
            while not any(text in line for line in lines):
                line = (await proc.stdout.readline()).decode()  # type: ignore[union-attr]
                assert line, "".join(lines)
                lines.append(line)
        return next(line for line in lines if text in line)

    try:
        await line_with("watching logic.st")
        async with VirtualPLC("127.0.0.1", port, load_config(config)) as plc:
            assert await _poll(plc, "SYVAR0", 1)
            logic.write_text(V2)
            said = await line_with("PLC logic reloaded (api run --watch)")
            assert "3 variable(s) kept, 1 from their initial value (main.added)" in said
            assert await _poll(plc, "SYVAR0", 71)  # step kept, added 7
            logic.write_text(BROKEN)
            await line_with("PLC logic not reloaded (api run --watch)")
            await line_with(f"{logic}:9:19: error ST002")
            assert await plc.get("SYVAR0") == 71  # the old logic runs on
    finally:
        code, log = await stop_run(proc, lines)
    assert code == 0, log
    assert "Traceback" not in log


async def _poll(plc: VirtualPLC, var: str, value: int) -> bool:
    async with asyncio.timeout(20):
        # Another process's PLC: a Modbus client learns its value only by asking.
        while await plc.get(var) != value:  # noqa: ASYNC110
            await asyncio.sleep(0.05)
    return True


async def test_a_reload_that_could_not_read_its_file_replays_with_the_same_error(
        tmp_path: Path) -> None:
    """A logic file deleted, then a directory in its place (run --watch sees both): the
    session's reloads fail with the OS's error, and so do the replay's -- it said "the files
    hold no PROGRAM to run" for both, from an empty record of the files."""
    record = tmp_path / "session.jsonl"
    gw = Gateway(cell(tmp_path).config, record=record)
    logic = tmp_path / "logic.st"
    said = []
    async with gw:
        await PlcWatch(gw).until("main.scans", test=lambda n: n >= 3)
        logic.unlink()
        said.append(await gw.reload_plc(Source(SourceKind.API, "test")))
        logic.mkdir()
        said.append(await gw.reload_plc(Source(SourceKind.API, "test")))
    assert [(o.ok, o.diagnostics[0].split("]")[0]) for o in said] == [
        (False, "[Errno 2"), (False, "[Errno 21")]  # ENOENT, EISDIR
    logic.rmdir()
    logic.write_text(V2)
    replayed = [e for e in replay(record).runtime.trace.events if e["event"] == "plc_reload"]
    assert [(e["ok"], e["diagnostics"]) for e in replayed] == [
        (False, list(o.diagnostics)) for o in said]
