"""Commands of one process (issue 27, item 1): cycle start, feed hold and reset of process k,
over the Modbus command register (high byte: the process) and the Python API, beside the
cell's 1/2/3, which keep their meaning."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.gateway import Gateway, load_config
from ncgate.inputs import CommandKind
from ncgate.interpreter.engine import ProcessState

COMMAND = 2000  # holding register 2000: the command word (modbus.map.command)

CELL = """[nc]
main = "A"
[nc.storage]
MP0 = "."
[[nc.process]]
number = 2
main = "B"
[[nc.process]]
number = 4
external = true
"""


def _cell(tmp_path: Path) -> Path:
    (tmp_path / "ncgate.toml").write_text(CELL)
    (tmp_path / "A.nc").write_text("N1(WAI,SA1=1)\nN2M30\n")
    # A 10 s move, then the interpolator's wait (#: in motion order): RUNNING while it moves.
    (tmp_path / "B.nc").write_text("N1G1X100F600\nN2#(WAI,SA2=1)\nN3M30\n")
    return tmp_path / "ncgate.toml"


async def test_modbus_commands_one_process_by_the_high_byte(tmp_path: Path) -> None:
    cfg = load_config(_cell(tmp_path), overrides={"modbus.port": 0, "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            async def word(value: int) -> int:
                """The exception code (0: written)."""
                answer = await client.write_register(COMMAND, value, device_id=1)
                return answer.exception_code if answer.isError() else 0

            assert await word(0x0201) == 0  # cycle start of process 2: its own main, B
            await gw.wait_state(2, "RUNNING", timeout_s=10)
            assert gw.status(1).state is ProcessState.IDLE  # the cell's main did not start
            assert await word(0x0202) == 0  # feed hold of process 2 only
            await gw.wait_state(2, "HOLD", timeout_s=10)
            assert await word(1) == 0  # the cell's cycle start: resumes the held process 2
            await gw.wait_state(2, "RUNNING", timeout_s=10)
            assert gw.status(1).state is ProcessState.IDLE
            assert await word(1) == 0  # nothing held: starts nc.main in process 1
            await gw.wait_state(1, "WAIT_COND", timeout_s=10)
            assert await word(0x0203) == 0  # reset of process 2 only
            await gw.wait_state(2, "IDLE", timeout_s=10)
            assert gw.status(1).state is ProcessState.WAIT_COND  # P1 goes on waiting
            # Not a process, or an external one: refused (ILLEGAL DATA VALUE), nothing done.
            assert await word(0x0901) == 3
            assert await word(0x0401) == 3
            assert await word(0x0204) == 3  # not a command
        finally:
            client.close()
        ends = [(e["proc"], e["how"]) for e in gw.trace if e["event"] == "end"]
        starts = [(e["proc"], e["prog"]) for e in gw.trace if e["event"] == "start"]
    assert starts == [(2, "B"), (1, "A")]
    assert ends == [(2, "reset")]


async def test_the_api_commands_one_process(tmp_path: Path) -> None:
    cfg = load_config(_cell(tmp_path), overrides={"modbus.enabled": False,
                                                  "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        gw.command(CommandKind.CYCLE_START)  # the cell: P1's A
        await gw.wait_state(1, "WAIT_COND", timeout_s=10)
        gw.command(CommandKind.CYCLE_START, process=2)
        await gw.wait_state(2, "RUNNING", timeout_s=10)
        gw.command(CommandKind.FEED_HOLD, process=1)  # P1 holds; P2 keeps moving
        await gw.wait_state(1, "HOLD", timeout_s=10)
        assert gw.status(2).state is ProcessState.RUNNING
        gw.command(CommandKind.RESET, process=1)
        await gw.wait_state(1, "IDLE", timeout_s=10)
        assert gw.status(2).state is ProcessState.RUNNING  # untouched by P1's reset
        gw.command(CommandKind.RESET)  # the cell
        await gw.wait_state(2, "IDLE", timeout_s=10)
        ends = [(e["proc"], e["how"]) for e in gw.trace if e["event"] == "end"]
    assert ends == [(1, "reset"), (2, "reset")]


async def test_a_session_with_commands_of_one_process_replays(tmp_path: Path) -> None:
    """The record keeps the process of a command; the replay gives it to the same process and
    matches (before, a command for one process was a malformed record)."""
    from ncgate.gateway.record import replay

    cfg = load_config(_cell(tmp_path), overrides={"modbus.enabled": False,
                                                  "canopen.enabled": False})
    record = tmp_path / "session.jsonl"
    async with Gateway(cfg, cold=True, record=record) as gw:
        gw.command(CommandKind.CYCLE_START, process=2)
        await gw.wait_state(2, "RUNNING", timeout_s=10)
        gw.command(CommandKind.FEED_HOLD, process=2)
        await gw.wait_state(2, "HOLD", timeout_s=10)
        gw.command(CommandKind.RESET, process=2)
        await gw.wait_state(2, "IDLE", timeout_s=10)
    lines = record.read_text().splitlines()
    assert sum('"process": 2' in line for line in lines if '"input"' in line) == 3
    result = replay(record)
    assert result.divergence is None and result.compared > 0, result.divergence


async def test_single_block_and_step_over_modbus(tmp_path: Path) -> None:
    """Command words 6/7 switch single block (of one process with its high byte), 5 steps;
    the status register shows STEP (9) between blocks."""
    (tmp_path / "ncgate.toml").write_text(CELL)
    (tmp_path / "A.nc").write_text("N1E1=1\nN2E1=2\nN3E1=3\nN4M30\n")
    (tmp_path / "B.nc").write_text("N1M30\n")
    cfg = load_config(tmp_path / "ncgate.toml", overrides={"modbus.port": 0,
                                                           "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            async def word(value: int) -> None:
                assert not (await client.write_register(COMMAND, value, device_id=1)).isError()

            async def state() -> int:
                return (await client.read_input_registers(100, count=1,
                                                          device_id=1)).registers[0]

            await word(0x0106)  # single block on, process 1
            await word(1)  # cycle start: A runs N1 and stops
            await gw.wait_state(1, "STEP", timeout_s=10)
            assert await state() == int(ProcessState.STEP) == 9
            assert gw.engine.processes[1].E[1] == 1.0
            await word(5)  # step: N2 (the write's answer comes after the step has run)
            await gw.wait_state(1, "STEP", timeout_s=10)
            assert gw.engine.processes[1].E[1] == 2.0
            await word(0x0107)  # single block off: A runs to its end
            await gw.wait_idle(timeout_s=10)
        finally:
            client.close()
        assert gw.engine.processes[1].E[1] == 3.0


def test_sim_single_block_goes_on_with_the_scripts_steps(tmp_path: Path) -> None:
    """`ncgate sim --single-block`: each block waits for the script's next command; the
    run is deterministic (the writes land at the commands' times), and a stop with no
    command left is a stall that names the stopped block."""
    import json
    import subprocess
    import sys

    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n')
    (tmp_path / "A.nc").write_text("N1SYVAR1=1\nN2SYVAR1=2\nN3SYVAR1=3\nN4M30\n")
    (tmp_path / "script.toml").write_text(
        '[[command]]\nat = 1.0\ncommand = "step"\n'
        '[[command]]\nat = 2.5\ncommand = "cycle_start"\nprocess = 1\n'
        '[[command]]\nat = 4.0\ncommand = "single_block_off"\n')

    def sim(*extra: str) -> tuple[int, list[dict[str, object]], str]:
        trace = tmp_path / "trace.jsonl"
        done = subprocess.run(
            [sys.executable, "-m", "ncgate", "sim", "--config", str(tmp_path / "ncgate.toml"),
             "--trace", str(trace), "--single-block", *extra], capture_output=True, text=True,
            timeout=60)
        events = [json.loads(line) for line in trace.read_text().splitlines()]
        return done.returncode, events, done.stdout

    code, events, _ = sim("--script", str(tmp_path / "script.toml"))
    writes = [(e["t"], e["value"]) for e in events if e["event"] == "write"]
    assert code == 0, events
    assert writes == [(0.0, 1), (1.0, 2), (2.5, 3)]
    assert [e["t"] for e in events if e["event"] == "end"] == [4.0]
    code, events, out = sim()  # no script: it stops after N1 for good
    assert code == 1 and "A.nc:1 N1" in out and "single block" in out  # stopped after N1


def test_a_script_command_that_does_not_exist_names_its_entry(tmp_path: Path) -> None:
    from ncgate.config import ConfigError
    from ncgate.config.script import load_script
    from ncgate.gateway.sim import run_sim

    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n')
    (tmp_path / "A.nc").write_text("N1M30\n")
    (tmp_path / "s.toml").write_text('[[command]]\nat = 1\ncommand = "jump"\n')
    config = load_config(tmp_path / "ncgate.toml")
    with pytest.raises(ConfigError, match=r"s\.toml: command\[0\]\.command: unknown command "
                       r"'jump' \(cycle_start, feed_hold, reset, restart_plc, step"):
        run_sim(config, "A", load_script(tmp_path / "s.toml"))
    (tmp_path / "s.toml").write_text('[[command]]\nat = 1\ncommand = "step"\nprocess = 0\n')
    with pytest.raises(ConfigError, match=r"command\[0\]\.process: expected a process number"):
        load_script(tmp_path / "s.toml")


async def test_overrides_over_modbus_scale_the_move_under_way(tmp_path: Path) -> None:
    """Holding 2010+2(k-1): feed and rapid override of process k.  50 % makes P2's move run
    at half speed from where it is; 0 % stands with P2 RUNNING (not HOLD); a value past the
    range, or a write over the external process's registers, is refused whole (03)."""
    (tmp_path / "ncgate.toml").write_text(CELL)
    (tmp_path / "A.nc").write_text("N1M30\n")
    (tmp_path / "B.nc").write_text("N1G1X1000F600\nN2M30\n")  # 100 s
    cfg = load_config(tmp_path / "ncgate.toml", overrides={"modbus.port": 0,
                                                           "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        p2 = gw.engine.processes[2]
        try:
            gw.command(CommandKind.CYCLE_START, process=2)
            await gw.wait_state(2, "RUNNING", timeout_s=10)
            assert not (await client.write_registers(2012, [50, 80], device_id=1)).isError()
            regs = (await client.read_holding_registers(2010, count=6,
                                                        device_id=1)).registers
            assert regs == [100, 100, 50, 80, 100, 100]
            assert p2.int_rate == 0.5 and p2.int_timer is not None
            assert not (await client.write_register(2012, 0, device_id=1)).isError()
            x = (await client.read_input_registers(132, count=2, device_id=1)).registers
            await client.read_holding_registers(2010, count=2, device_id=1)  # a round trip
            assert (await client.read_input_registers(132, count=2,
                                                      device_id=1)).registers == x  # stands
            assert gw.status(2).state is ProcessState.RUNNING  # not held
            assert p2.int_timer is None and p2.int_remaining is not None
            bad = await client.write_registers(2012, [100, 101], device_id=1)  # rapid > 100
            assert bad.isError() and bad.exception_code == 3
            bad = await client.write_registers(2014, [120, 90, 100, 100], device_id=1)  # P4
            assert bad.isError() and bad.exception_code == 3
            assert gw.engine.processes[3].feed_override == 100  # nothing of it stored
        finally:
            client.close()
        overrides = [(e["proc"], e["feed"], e["rapid"]) for e in gw.trace
                     if e["event"] == "override"]
    assert overrides == [(2, 50, 80), (2, 0, 80)]


async def test_optional_stop_and_block_skip_switches_over_modbus(tmp_path: Path) -> None:
    """Command words 8 (optional stop on) and 10 (block skip on): M01 stops, a "/" block is
    skipped; 0x0108 (a switch of one process) is refused -- they are the cell's."""
    (tmp_path / "ncgate.toml").write_text(CELL)
    (tmp_path / "A.nc").write_text("N1SYVAR1=1\nN2M01\n/N3SYVAR1=3\nN4SYVAR2=4\nN5M30\n")
    (tmp_path / "B.nc").write_text("N1M30\n")
    cfg = load_config(tmp_path / "ncgate.toml", overrides={"modbus.port": 0,
                                                           "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            async def word(value: int) -> int:
                answer = await client.write_register(COMMAND, value, device_id=1)
                return answer.exception_code if answer.isError() else 0

            assert await word(0x0108) == 3
            assert await word(8) == 0 and await word(10) == 0
            assert await word(1) == 0
            await gw.wait_state(1, "STEP", timeout_s=10)  # at M01
            assert await word(1) == 0
            await gw.wait_idle(timeout_s=10)
        finally:
            client.close()
        assert (gw.read("SYVAR1"), gw.read("SYVAR2")) == (1, 4)  # N3 was skipped


def test_sim_breakpoints_from_the_command_line_and_the_script(tmp_path: Path) -> None:
    """`sim --break PROG:LINE` stops the cell before that block; the script's cycle_start
    goes on, `--continue` goes on at once; a bad breakpoint is a usage error (exit 2)."""
    import json
    import subprocess
    import sys

    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n')
    (tmp_path / "A.nc").write_text("N1SYVAR1=1\nN2G1X10F600\nN3SYVAR1=3\nN4M30\n")
    (tmp_path / "script.toml").write_text('[[command]]\nat = 5.0\ncommand = "cycle_start"\n')

    def sim(*extra: str) -> tuple[int, list[dict[str, object]], str]:
        trace = tmp_path / "trace.jsonl"
        trace.unlink(missing_ok=True)
        done = subprocess.run(
            [sys.executable, "-m", "ncgate", "sim", "--config", str(tmp_path / "ncgate.toml"),
             "--trace", str(trace), *extra], capture_output=True, text=True, timeout=60)
        events = ([json.loads(line) for line in trace.read_text().splitlines()]
                  if trace.exists() else [])
        return done.returncode, events, done.stdout + done.stderr

    code, events, _ = sim("--break", "A:3", "--script", str(tmp_path / "script.toml"))
    hits = [(e["t"], e["line"], e["breakpoint"]) for e in events if e["event"] == "break"]
    assert code == 0 and hits == [(0.0, 3, "A:3")]
    # N2's move (1 s) was held from t = 0 until the script's cycle start at 5 s.
    assert [e["t"] for e in events if e["event"] == "end"] == [6.0]
    code, events, _ = sim("--break", "N3", "--continue")
    assert code == 0 and [e["breakpoint"] for e in events if e["event"] == "break"] == ["N3"]
    assert [e["t"] for e in events if e["event"] == "end"] == [1.0]
    code, _, out = sim("--break", "A:3")  # nobody goes on: a stall naming the stop
    assert code == 1 and "held" in out
    code, _, out = sim("--break", "P9 N3")
    assert code == 2 and "--break P9 N3" in out


async def test_breakpoints_and_run_to_sync_through_the_api_and_modbus(
        tmp_path: Path) -> None:
    from ncgate.errors import InputRefused, Reason
    from ncgate.gateway.record import replay
    from ncgate.inputs import Break

    (tmp_path / "ncgate.toml").write_text(CELL)
    (tmp_path / "A.nc").write_text("N1(EXE,2,B)\nN2(WAI,2)\nN3M30\n")
    (tmp_path / "B.nc").write_text("N1G1X5F600\nN2(SND,1)\nN3M30\n")
    cfg = load_config(tmp_path / "ncgate.toml", overrides={"modbus.port": 0,
                                                           "canopen.enabled": False})
    record = tmp_path / "session.jsonl"
    async with Gateway(cfg, cold=True, record=record) as gw:
        with pytest.raises(InputRefused) as caught:
            gw.apply(Break("somewhere"))
        assert caught.value.reason is Reason.BAD_VALUE
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            assert not (await client.write_register(COMMAND, 12, device_id=1)).isError()
        finally:
            client.close()
        gw.command(CommandKind.CYCLE_START)  # A's EXE is the next sync event: the cell stops
        await gw.wait_state(1, "HOLD", timeout_s=10)
        hits = [e for e in gw.trace if e["event"] == "break"]
        assert [(e["proc"], e["breakpoint"]) for e in hits] == [(1, "sync")]
        gw.command(CommandKind.CYCLE_START)  # goes on: run to sync was one-shot
        await gw.wait_idle(timeout_s=10)
    result = replay(record)
    assert result.divergence is None, result.divergence


def test_the_commissioning_walkthrough_runs_as_its_readme_says() -> None:
    """examples/commissioning: the break at P2's N16 at 10.399 s, P2's feed at 50 % a second
    later, the cycle start at 42 s refused while the door (SA100) is open, the end at
    101.930 s (90.798 s without the walkthrough), exit 0 -- each figure as its README says."""
    from ncgate.config.script import load_script
    from ncgate.gateway.examples import find_example
    from ncgate.gateway.sim import run_sim

    example = find_example("commissioning")
    assert example.script is not None
    result = run_sim(load_config(example.config), "PROG91", load_script(example.script))
    events = result.events
    (hit,) = [e for e in events if e["event"] == "break"]
    assert (hit["proc"], hit["prog"], hit["n"], round(hit["t"], 3)) == (2, "PROG92.nc", 16,
                                                                        10.399)
    (override,) = [e for e in events if e["event"] == "override"]
    assert (override["proc"], override["feed"], round(override["t"], 3)) == (2, 50, 11.399)
    refused = [e for e in events if e["event"] == "hazard" and "SA100 is set" in e["message"]]
    assert [e["t"] for e in refused] == [42.0]
    assert result.outcome == "idle" and result.exit_status == 0
    assert round(result.runtime.engine.now, 3) == 104.506
    # Without step 4 (single block for P1) the cell ends 2.576 s sooner: P1 did stop.
    script = load_script(example.script)
    without = run_sim(load_config(example.config), "PROG91",
                      type(script)(script.file, tuple(e for e in script.entries
                                                      if e.process != 1)))
    assert round(without.runtime.engine.now, 3) == 101.930
    readme = (example.folder / "README.md").read_text()
    for figure in ("10.399", "104.506", "101.930", "90.798", "SA100"):
        assert figure in readme


async def test_a_block_search_through_the_api_is_refused_or_recorded(tmp_path: Path) -> None:
    from ncgate.errors import InputRefused, Reason
    from ncgate.gateway.record import replay

    # The rule by skipped blocks, by its option: the seed's default refuses any search in A
    # (its WAI).  In the file: the replay reads the config again.
    (tmp_path / "ncgate.toml").write_text(CELL.replace(
        "[nc]\n", '[nc]\nblock_search_sync = "skipped"\n', 1))
    (tmp_path / "A.nc").write_text("N1G1F600\nN2(WAI,SA1=1)\nN3X10\nN4M30\n")
    (tmp_path / "B.nc").write_text("N1M30\n")
    cfg = load_config(tmp_path / "ncgate.toml", overrides={"modbus.enabled": False,
                                                           "canopen.enabled": False})
    record = tmp_path / "session.jsonl"
    async with Gateway(cfg, cold=True, record=record) as gw:
        with pytest.raises(InputRefused, match=r"block search: .*A.nc:2: \(WAI,SA1=1\)") as c:
            await gw.start("A", at="N3")
        assert c.value.reason is Reason.BAD_VALUE
        await gw.start("A", at="N2")  # N1 only is skipped: its G1 F600 are in force
        await gw.wait_state(1, "WAIT_COND", timeout_s=10)
        gw.write("SA1", 1)
        await gw.wait_idle(timeout_s=10)
    lines = [line for line in record.read_text().splitlines() if '"input": "start"' in line]
    assert len(lines) == 1 and '"at": "N2"' in lines[0]
    assert replay(record).divergence is None


def test_sim_set_nc_feed_override(tmp_path: Path) -> None:
    import json
    import subprocess
    import sys

    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n')
    (tmp_path / "A.nc").write_text("N1G1X10F600\nN2M30\n")
    trace = tmp_path / "t.jsonl"
    done = subprocess.run([sys.executable, "-m", "ncgate", "sim", "--config",
                           str(tmp_path / "ncgate.toml"), "--set", "nc.feed_override=50",
                           "--trace", str(trace)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    ends = [json.loads(line)["t"] for line in trace.read_text().splitlines()
            if '"event": "end"' in line or '"event":"end"' in line]
    assert ends == [2.0]


def test_sim_at_starts_the_main_program_by_block_search(tmp_path: Path) -> None:
    import json
    import subprocess
    import sys

    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\nlookahead = 0\n[nc.storage]\nMP0 = "."\n')
    (tmp_path / "A.nc").write_text("N10G1F600\nN20E1=5\nN30G91X10\nN40XE1\nN50SYVAR1=E1\n"
                                   "N60M30\n")
    trace = tmp_path / "t.jsonl"

    def sim(*extra: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "ncgate", "sim", "--config",
                               str(tmp_path / "ncgate.toml"), "--trace", str(trace), *extra],
                              capture_output=True, text=True, timeout=60)

    assert sim("--at", "N40", "--with-calc").returncode == 0
    writes = [json.loads(line) for line in trace.read_text().splitlines()
              if '"write"' in line]
    assert [(e["var"], e["value"], e["t"]) for e in writes] == [("SYVAR1", 5, 0.5)]
    refused = sim("--at", "N99")
    assert refused.returncode == 2 and "no block N99" in refused.stderr


async def test_block_search_and_breakpoints_by_n_from_the_fieldbus(tmp_path: Path) -> None:
    """Holding 2003 holds an N number; command word 13 starts the process's main by block
    search there, 14 sets a breakpoint at it, 15 clears every breakpoint (issue 27)."""
    (tmp_path / "ncgate.toml").write_text(CELL)
    (tmp_path / "A.nc").write_text("N10G1X1F600\nN20X2\nN30SYVAR1=3\nN40M30\n")
    (tmp_path / "B.nc").write_text("N1G1X10F600\nN2SYVAR2=2\nN3M30\n")
    cfg = load_config(tmp_path / "ncgate.toml", overrides={"modbus.port": 0,
                                                           "canopen.enabled": False})
    async with Gateway(cfg, cold=True) as gw:
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            async def word(value: int) -> None:
                assert not (await client.write_register(COMMAND, value, device_id=1)).isError()

            assert not (await client.write_register(2003, 2, device_id=1)).isError()
            assert (await client.read_holding_registers(2003, count=1,
                                                        device_id=1)).registers == [2]
            await word(0x020E)  # breakpoint at N2 of process 2
            assert [b.text for b in gw.engine.breakpoints] == ["P2 N2"]
            await word(0x0201)  # P2 starts B: the breakpoint stops the cell before N2
            await gw.wait_state(2, "HOLD", timeout_s=10)
            bad = await client.write_register(COMMAND, 0x060F, device_id=1)  # no process 6
            assert bad.isError() and bad.exception_code == 3
            assert gw.engine.breakpoints != []
            await word(15)  # clear every breakpoint
            assert gw.engine.breakpoints == []
            await word(1)  # go on
            assert not (await client.write_register(2003, 30, device_id=1)).isError()
            gw.runtime.store.preload("A", 1)  # read already: the start acts with the write
            await word(13)  # P1's main by block search at N30: N10 and N20 skipped
            await gw.wait_state(1, "IDLE", timeout_s=10)
            assert gw.engine.processes[1].actual[0] == 2.0  # where N20 would have left it
            await gw.wait_idle(timeout_s=10)
        finally:
            client.close()
        writes = [(e["var"], e["value"]) for e in gw.trace if e["event"] == "write"
                  and e["var"].startswith("SYVAR")]
    assert writes == [("SYVAR2", 2), ("SYVAR1", 3)]


async def test_a_session_using_every_control_replays_as_recorded(tmp_path: Path) -> None:
    """Single block, a step, an override, the switches, a breakpoint and its clearing, a
    command of one process: the record keeps each, and the replay matches."""
    from ncgate.gateway.record import replay
    from ncgate.inputs import Break, Command, Override

    (tmp_path / "ncgate.toml").write_text(CELL)
    (tmp_path / "A.nc").write_text("N1G1X10F600\nN2M01\nN3X20\nN4M30\n")
    (tmp_path / "B.nc").write_text("N1G1X5F600\nN2M30\n")
    cfg = load_config(tmp_path / "ncgate.toml", overrides={"modbus.enabled": False,
                                                           "canopen.enabled": False})
    record = tmp_path / "session.jsonl"
    async with Gateway(cfg, cold=True, record=record) as gw:
        gw.apply(Command(CommandKind.OPTIONAL_STOP_ON))
        gw.apply(Override(feed=200, process=1))
        gw.apply(Break("P2 N2"))
        gw.apply(Command(CommandKind.SINGLE_BLOCK_ON, 1))
        gw.command(CommandKind.CYCLE_START)
        await gw.wait_state(1, "STEP", timeout_s=10)  # after N1 (single block)
        gw.apply(Command(CommandKind.SINGLE_BLOCK_OFF, 1))
        await gw.wait_state(1, "STEP", timeout_s=10)  # at M01 (optional stop on)
        gw.apply(Command(CommandKind.STEP, 1))
        await gw.wait_state(1, "STEP", timeout_s=10)  # one block: N3
        gw.apply(Break("P2 N2", on=False))
        gw.command(CommandKind.CYCLE_START, process=2)  # B starts: no breakpoint any more
        gw.command(CommandKind.CYCLE_START, process=1)
        await gw.wait_idle(timeout_s=10)
    kinds = {json.loads(line).get("input") for line in record.read_text().splitlines()}
    assert {"command", "override", "break"} <= kinds
    result = replay(record)
    # Two starts and two ends compared, at their times: the stops and the 200 % move shaped
    # them; and the stops themselves (single block, M01, the step's) and the step.
    assert result.divergence is None and result.compared == 8, result.divergence
