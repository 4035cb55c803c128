"""PLC logic in Structured Text, as users run it: the shipped example under ``sim`` and under
``run`` with a Modbus client and a CANopen master watching, a fault raised and cleared over
Modbus, the stall rule with logic, and RETAIN across a real ``kill -9``."""

from __future__ import annotations

import asyncio
import random
from pathlib import Path
from typing import Any

import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.config import load_config
from ncgate.config.script import Script
from ncgate.gateway import Gateway
from ncgate.gateway.door import Door
from ncgate.gateway.sim import run_sim
from ncgate.gateway.testing.canopen_kit import CanopenMaster
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.plc_kit import PlcFaulted, PlcWatch
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.plc.scan import PlcState

from ..conftest import EXAMPLES
from .test_cli_run import start_run

EXAMPLE = EXAMPLES / "plclogic"


def waits_and_resumes(events: list[dict[str, Any]]) -> list[tuple[float, dict[str, Any]]]:
    """Each wait of P2 at N40 with the resume that ended it."""
    out = []
    for i, e in enumerate(events):
        if e["event"] == "wait" and e["proc"] == 2 and e.get("n") == 40:
            resume = next(r for r in events[i:] if r["event"] == "resume" and r["proc"] == 2)
            out.append((e["t"], resume))
    return out


def test_the_example_under_sim_is_played_by_its_logic() -> None:
    result = run_sim(load_config(EXAMPLE / "ncgate.toml"), "PROG91", Script(None, ()))
    assert result.outcome == "idle" and result.exit_status == 0
    events = result.events
    answered = waits_and_resumes(events)
    assert len(answered) == 2  # the logic takes SA10 back, so P2 waits in both cycles
    for waited_at, resume in answered:
        assert resume["by"] == "cond" and resume["writer"] == "plc"
        # TON 500 ms from the first 10 ms scan that saw the wait: 0.5 s .. 0.51 s later
        assert 0.5 <= resume["t"] - waited_at <= 0.51 + 1e-9
    plc_writes = [(e["var"], e["value"]) for e in events if e["event"] == "write"]
    assert [w for w in plc_writes if w[0] == "SYVAR20"] == [("SYVAR20", 1), ("SYVAR20", 2)]
    assert not [w for w in plc_writes if w[0] == "SA11"]  # the timeout bit never rises
    assert {e["who"] for e in events if e["event"] == "write" and e["proc"] == 0} == {"plc"}
    assert result.runtime.plc is not None and result.runtime.plc.read("cell.cycles") == 2


def test_a_simulation_with_logic_is_deterministic() -> None:
    config = load_config(EXAMPLE / "ncgate.toml")
    first = run_sim(config, "PROG91", Script(None, ())).events
    second = run_sim(config, "PROG91", Script(None, ())).events
    assert first == second


async def test_the_example_under_run_with_a_modbus_client_and_a_canopen_master(
        tmp_path: Path) -> None:
    # RETAIN values go to the test's folder, not next to the example.
    config = ncgate_test_config(EXAMPLE / "ncgate.toml", **{
        "nc.time_scale": 30.0, "plc.retain_file": str(tmp_path / "retain.sqlite")})
    async with Gateway(config) as gw:
        watch = PlcWatch(gw)
        master = CanopenMaster(config)
        host, port = gw.modbus_address
        try:
            async with VirtualPLC(host, port, config) as plc:
                assert (await plc.plc_status()).state is PlcState.RUNNING
                await plc.command(1)  # cycle start: PROG91 in process 1
                assert await watch.until("cell.cycles", 2, timeout_s=30) == 2
                assert await plc.get("SYVAR20") == 2
                await gw.wait_idle(timeout_s=30)
                seen = await plc.plc_status()
                assert seen.state is PlcState.RUNNING and seen.scans >= 1
                assert seen.max_scan_us >= seen.last_scan_us > 0 or seen.last_scan_us == 0
                assert seen.fault_line == 0
            state = await master.upload(0x2700, 1)
            scans = int.from_bytes(await master.upload(0x2700, 2), "little")
            assert state == bytes([1]) and scans >= seen.scans
        finally:
            master.close()
        answered = waits_and_resumes(gw.trace)
        assert [r["writer"] for _, r in answered] == ["plc", "plc"]
        assert watch.read("cell.answer.PT") == 500


FAULTY = """PROGRAM main
VAR q : INT; END_VAR
q := 100 / SYVAR[1];
SYVAR[2] := q;
END_PROGRAM
"""


@pytest.mark.parametrize("section", ["plc", "plant"])
async def test_logic_that_does_not_compile_stops_the_gateway_before_anything_serves(
        tmp_path: Path, section: str, caplog: pytest.LogCaptureFixture) -> None:
    """A PLC connected saw the CANopen node boot (and the Modbus server answer), then go,
    for a typo in the ST: the logic is compiled before the first adapter starts."""
    (tmp_path / "logic.st").write_text("PROGRAM main\nVAR x : INT; END_VAR\nx := x + ;\n"
                                       "END_PROGRAM\n")
    (tmp_path / "ncgate.toml").write_text(f'[{section}]\nlogic = "logic.st"\n')
    from ncgate.plc.st.diagnostics import LogicError

    with caplog.at_level("INFO"), pytest.raises(LogicError, match=r"logic\.st:3:10"):
        async with Gateway(ncgate_test_config(tmp_path / "ncgate.toml")):
            pass
    assert "CANopen node" not in caplog.text and "Modbus" not in caplog.text, caplog.text


async def test_a_fault_is_raised_and_cleared_over_modbus(tmp_path: Path) -> None:
    (tmp_path / "logic.st").write_text(FAULTY)
    (tmp_path / "ncgate.toml").write_text('[plc]\nlogic = "logic.st"\n[canopen]\n'
                                          'enabled = false\n')
    config = ncgate_test_config(tmp_path / "ncgate.toml")
    async with Gateway(config) as gw:
        watch = PlcWatch(gw)
        host, port = gw.modbus_address
        async with VirtualPLC(host, port, config) as plc:
            # SYVAR1 = 0 at start: the first scan faults at once.
            with pytest.raises(PlcFaulted, match=r"logic.st:3:1: division by zero"):
                await watch.until("main.q", 25)
            seen = await plc.plc_status()
            assert (seen.state, seen.fault_line) == (PlcState.FAULT, 3)
            alarms = [e for e in gw.trace if e["event"] == "alarm" and e["proc"] == 0]
            assert alarms[-1]["code"] == "AL160"
            assert "logic.st:3:1: division by zero" in alarms[-1]["message"]
            await plc.set("SYVAR1", 4)
            assert gw.plc.status.state is PlcState.FAULT  # no scan runs until a reset
            await plc.command(3)  # reset: the PLC starts again
            assert await watch.until("main.q", 25) == 25
            assert await plc.get("SYVAR2") == 25
            seen = await plc.plc_status()
            assert (seen.state, seen.fault_line) == (PlcState.RUNNING, 0)
            # The lateness pair is the block's last four registers, as the PLC reports it.
            status = gw.plc_status  # read after: its largest lateness is no smaller
            assert status is not None and seen.late_us <= seen.max_late_us
            assert seen.max_late_us <= status.max_lateness_us
            await plc.set("SYVAR1", 0)  # again: outputs hold at the last good scan's
            with pytest.raises(PlcFaulted):
                await watch.until("main.q", -1)
            assert await plc.get("SYVAR2") == 25


STALL_PROGRAM = "N10(WAI,SA12=1)\nN20G4\nN30M30\n"


@pytest.mark.parametrize(("answer_ms", "outcome"), [(3000, "idle"), (None, "stall")])
def test_a_wait_the_logic_may_release_is_a_stall_only_after_stall_s(
        tmp_path: Path, answer_ms: int | None, outcome: str) -> None:
    (tmp_path / "MAIN.nc").write_text(STALL_PROGRAM)
    answer = (f"t(IN := TRUE, PT := T#{answer_ms}ms); SA[12] := t.Q;" if answer_ms
              else "SA[13] := NOT SA[13] AND FALSE;")
    (tmp_path / "plc.st").write_text(f"PROGRAM p VAR t : TON; END_VAR {answer} END_PROGRAM")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "MAIN"\nstall_s = 5\n'
                                          '[plc]\nlogic = "plc.st"\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "MAIN", Script(None, ()))
    assert result.outcome == outcome
    if outcome == "stall":
        stall = next(e for e in result.events if e["event"] == "stall")
        assert 5.0 <= stall["t"] <= 5.0 + 0.01 + 1e-9  # stall_s after the last change (t=0)
    else:
        resume = next(e for e in result.events if e["event"] == "resume")
        assert resume["writer"] == "plc" and 3.0 <= resume["t"] <= 3.01 + 1e-9



def test_a_process_the_logic_holds_for_ever_is_a_stall_after_stall_s(tmp_path: Path) -> None:
    """The PLC's NC.HOLD_LEVEL holds P1 in a move and never lets go: `sim` ran for ever (the
    scan never stood still long enough for a stall, since a hold did not count as one), its
    summary counting the hold as running.  Now it is a stall stall_s after the last change,
    naming who holds P1 and since when.  (--until far away: the old code ran up to it.)"""
    (tmp_path / "MAIN.nc").write_text("N10G1X100F600\nN20M30\n")  # a 10 s move
    (tmp_path / "plc.st").write_text("PROGRAM p VAR t : TON; END_VAR\n"
                                     "t(IN := TRUE, PT := T#500ms);\n"
                                     "NC.HOLD_LEVEL := t.Q;\nEND_PROGRAM\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "MAIN"\nstall_s = 5\n'
                                          '[plc]\nlogic = "plc.st"\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "MAIN", Script(None, ()),
                     until=100_000.0)
    assert result.outcome == "stall" and result.exit_status == 1
    hold = next(e for e in result.events if e["event"] == "hold")
    assert hold["on"] and 0.5 <= hold["t"] <= 0.51 + 1e-9
    stall = next(e for e in result.events if e["event"] == "stall")
    assert stall["t"] == pytest.approx(hold["t"] + 5.0, abs=0.01 + 1e-9)
    [blocked] = stall["blocked"]
    assert (blocked["proc"], blocked["n"]) == (1, hold["n"])  # where its decoder stands
    assert blocked["reason"] == (f"held since {hold['t']:.3f} s (feed hold by plc plc.st:3): "
                                 "a cycle start goes on")
    stats = result.runtime.engine.processes[1].stats
    assert stats.running_s == pytest.approx(hold["t"])  # the move, until the hold
    assert stats.waiting_s == pytest.approx(stall["t"] - hold["t"])  # held: not running


RETAINED = """PROGRAM keep
VAR edge : R_TRIG; END_VAR
VAR RETAIN count : INT; spin : DINT; END_VAR
edge(CLK := SA[0]);
IF edge.Q THEN count := count + 1; END_IF
spin := spin + 1;                       (* a RETAIN value that changes every scan *)
SYVAR[0] := count;
SYVAR[1] := DINT_TO_INT(spin MOD 30000);
END_PROGRAM
"""


async def holding(client: AsyncModbusTcpClient, address: int, count: int = 1) -> list[int]:
    r = await client.read_holding_registers(address, count=count, device_id=1)
    assert not r.isError()
    return list(r.registers)


async def until_scanned(client: AsyncModbusTcpClient) -> None:
    """Until the PLC status shows a scan (a Modbus client can only poll)."""
    async with asyncio.timeout(10):
        while True:
            r = await client.read_input_registers(300, count=3, device_id=1)
            if r.registers[0] == 1 and (r.registers[1] << 16 | r.registers[2]) > 0:
                return
            await asyncio.sleep(0.01)


async def scans(client: AsyncModbusTcpClient) -> int:
    r = await client.read_input_registers(301, count=2, device_id=1)
    return int(r.registers[0] << 16 | r.registers[1])


async def after_a_scan(client: AsyncModbusTcpClient) -> None:
    """Until a whole scan has run since now: the PLC has read what was just written (an
    input shorter than a scan is not seen, as on any PLC)."""
    first = await scans(client)
    async with asyncio.timeout(10):
        while await scans(client) < first + 2:  # noqa: ASYNC110 - Modbus: read to learn
            await asyncio.sleep(0.005)


async def until_value(client: AsyncModbusTcpClient, address: int, wanted: int) -> None:
    try:
        async with asyncio.timeout(10):
            while (await holding(client, address))[0] != wanted:  # noqa: ASYNC110 - as above
                await asyncio.sleep(0.005)
    except TimeoutError:
        now = await holding(client, address)
        raise AssertionError(f"holding {address} is {now}, not {wanted}") from None


async def test_retain_survives_kill_9_between_two_writes(tmp_path: Path) -> None:
    (tmp_path / "keep.st").write_text(RETAINED)
    config = tmp_path / "ncgate.toml"
    config.write_text('[plc]\nlogic = "keep.st"\n[modbus]\nport = 0\n[canopen]\n'
                      'enabled = false\n')
    rng = random.Random(12)
    count = 0
    spin_seen = 0
    for _ in range(4):
        # --allow-missing: the cell is its PLC logic alone; its folder holds no main program.
        proc, port, _ = await start_run(config, "--allow-missing")
        client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0)
        assert await client.connect()
        try:
            await until_scanned(client)
            # what the last process committed is what this one starts from
            assert (await holding(client, 1000))[0] == count
            assert (await holding(client, 1001))[0] >= spin_seen
            for _ in range(2):  # two more rising edges of SA0, each seen committed
                await client.write_coil(0, True, device_id=1)
                count += 1
                await until_value(client, 1000, count)
                await client.write_coil(0, False, device_id=1)
                await after_a_scan(client)
            spin_seen = (await holding(client, 1001))[0]
            await client.write_coil(0, True, device_id=1)  # a third edge, and kill at once:
            await asyncio.sleep(rng.uniform(0, 0.02))      # a random moment around its save
        finally:
            client.close()
            proc.kill()
            await proc.wait()
        assert proc.returncode == -9
        probe_proc, probe_port, _ = await start_run(config, "--allow-missing")
        probe = AsyncModbusTcpClient("127.0.0.1", port=probe_port, retries=0)
        assert await probe.connect()
        try:
            await until_scanned(probe)
            after = (await holding(probe, 1000))[0]
            assert after in (count, count + 1)  # the third edge: saved whole, or not at all
            count = after
        finally:
            probe.close()
            probe_proc.kill()
            await probe_proc.wait()
    # --cold: the stored values are dropped
    proc, port, _ = await start_run(config, "--cold", "--allow-missing")
    client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0)
    assert await client.connect()
    try:
        await until_scanned(client)
        assert (await holding(client, 1000))[0] == 0
    finally:
        client.close()
        proc.kill()
        await proc.wait()


def test_scans_keep_their_grid_and_count_the_ones_the_loop_missed(tmp_path: Path) -> None:
    """On the wall clock: scan k is due at k * scan_ms.  The scan due at 20 ms runs with the
    wall clock at 55 ms: the scans due at 30 and 40 ms are a whole period late or more and
    are skipped (two overruns); the one due at 50 ms, half a period late, runs; then the grid
    goes on."""
    from ncgate.gateway.plc import start_plc
    from ncgate.gateway.wiring import build_runtime

    (tmp_path / "p.st").write_text("PROGRAM p VAR n : DINT; END_VAR n := n + 1; END_PROGRAM")
    (tmp_path / "ncgate.toml").write_text('[plc]\nlogic = "p.st"\nscan_ms = 10\n')
    config = load_config(tmp_path / "ncgate.toml")
    runtime = build_runtime(config, closed=False)
    engine = runtime.engine
    lateness = {0.02: 0.035}  # the scan due at 20 ms runs with the wall clock at 55 ms
    scanned: list[float] = []
    started = start_plc(config, runtime, Door(runtime), closed=False,
                        wall=lambda: engine.now + lateness.get(round(engine.now, 3), 0.0))
    assert started is not None
    plc, _ = started
    plc.scan_listeners.append(lambda: scanned.append(round(engine.now, 3)))
    engine.advance_to(0.1)
    assert scanned == [0.0, 0.01, 0.02, 0.05, 0.06, 0.07, 0.08, 0.09, 0.1]
    assert plc.status.overruns == 2 and plc.read("p.n") == 9


def test_programs_run_in_the_configured_order(tmp_path: Path) -> None:
    from ncgate.config import ConfigError

    (tmp_path / "MAIN.nc").write_text("N10(DLY,0.1)\nN20M30\n")  # a few scans long
    (tmp_path / "two.st").write_text(
        "PROGRAM first SYVAR[3] := 1; SYVAR[4] := SYVAR[3]; END_PROGRAM\n"
        "PROGRAM second SYVAR[3] := 2; END_PROGRAM\n")
    config_file = tmp_path / "ncgate.toml"
    for order, last, copied in ((["first", "second"], 2, 1), (["second", "first"], 1, 1)):
        config_file.write_text(f'[nc]\nmain = "MAIN"\n[plc]\nlogic = "two.st"\n'
                               f"programs = {order!r}\n".replace("'", '"'))
        result = run_sim(load_config(config_file), "MAIN", Script(None, ()))
        assert result.runtime.image.read("SYVAR", 3, "IN") == last
        assert result.runtime.image.read("SYVAR", 4, "IN") == copied
    config_file.write_text('[plc]\nlogic = "two.st"\nprograms = ["first", "thrid"]\n')
    with pytest.raises(ConfigError, match=r"plc\.programs\[1\]: no PROGRAM thrid"):
        run_sim(load_config(config_file), "MAIN", Script(None, ()))


def test_the_first_scan_is_on_time_however_late_the_gateway_got_to_it(tmp_path: Path) -> None:
    from ncgate.gateway.plc import start_plc
    from ncgate.gateway.wiring import build_runtime

    """Starting the fieldbus took 200 ms: the scans count from the first one, none is skipped
    as an overrun and the PLC's timers do not start behind the NC."""
    (tmp_path / "p.st").write_text("PROGRAM p VAR n : DINT; END_VAR n := n + 1; END_PROGRAM")
    (tmp_path / "ncgate.toml").write_text('[plc]\nlogic = "p.st"\nscan_ms = 10\n')
    config = load_config(tmp_path / "ncgate.toml")
    runtime = build_runtime(config, closed=False)
    engine = runtime.engine
    started = start_plc(config, runtime, Door(runtime), closed=False,
                        wall=lambda: engine.now + (0.2 if engine.now == 0.0 else 0.0))
    assert started is not None
    plc, _ = started
    scanned: list[float] = []
    plc.scan_listeners.append(lambda: scanned.append(round(engine.now, 3)))
    engine.advance_to(0.25)
    assert scanned == [0.0, 0.21, 0.22, 0.23, 0.24, 0.25]
    assert plc.status.overruns == 0 and plc.status.max_lateness_us == 0


async def test_a_scan_past_the_watchdog_faults_at_its_line(tmp_path: Path) -> None:
    (tmp_path / "p.st").write_text(
        "PROGRAM p\nVAR i : DINT; n : DINT; END_VAR\n"
        "FOR i := 1 TO 50000000 DO\n  n := n + 1;\nEND_FOR;\nEND_PROGRAM\n")
    (tmp_path / "ncgate.toml").write_text(
        '[plc]\nlogic = "p.st"\nscan_ms = 10\nwatchdog_ms = 20\nloop_limit = 100000000\n')
    cfg = load_config(tmp_path / "ncgate.toml",
                      overrides={"modbus.port": 0, "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        with pytest.raises(PlcFaulted):  # the fault wakes the watch (no polling)
            await PlcWatch(gw).until("p.n", test=lambda _: False, timeout_s=10)
        fault = gw.plc.status.fault
        scans = gw.plc.status.scans
        alarms = [e for e in gw.trace if e["event"] == "alarm"]
    assert fault is not None and fault.span is not None and fault.span.line in (3, 4)
    assert "watchdog's 20 ms (plc.watchdog_ms)" in str(fault)
    assert alarms and alarms[0]["code"] == "AL160" and "watchdog" in alarms[0]["message"]
    assert scans == 0  # the scan that ran over never completed
