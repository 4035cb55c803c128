"""`ncgate run` as a user runs it: a real process, real TCP, a signal to stop it."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.gateway.cli.main import main

from ..conftest import EXAMPLES, ROOT

PROGRAMS = Path(__file__).resolve().parents[2] / "config" / "programs"


async def start_run(config: Path, *more: str
                    ) -> tuple[asyncio.subprocess.Process, int, list[str]]:
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ncgate", "run", "--config", str(config), *more,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    assert proc.stdout is not None
    lines: list[str] = []
    async with asyncio.timeout(20):
        while True:
            line = (await proc.stdout.readline()).decode()
            assert line, "ncgate run ended early:\n" + "".join(lines)
            lines.append(line)
            found = re.search(r"Modbus TCP on [\d.]+:(\d+)", line)
            if found:
                return proc, int(found.group(1)), lines


async def stop_run(proc: asyncio.subprocess.Process, lines: list[str],
                   sig: int = signal.SIGTERM, timeout_s: float = 20.0) -> tuple[int, str]:
    """Signal ``ncgate run`` and wait for it to end: its exit status, and its whole log."""
    proc.send_signal(sig)
    assert proc.stdout is not None
    async with asyncio.timeout(timeout_s):
        rest = (await proc.stdout.read()).decode()
        code = await proc.wait()
    return code, "".join(lines) + rest


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])  # uvloop: the 'fast' extra, in 'test'
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
async def test_run_serves_and_stops_cleanly_on_a_signal(tmp_path: Path, sig: int,
                                                        loop: str) -> None:
    config = tmp_path / "ncgate.toml"
    folder = EXAMPLES / "scheme3"
    config.write_text(f'[nc]\nautostart = true\ntime_scale = 100.0\n[nc.storage]\n'
                      f'MP0 = "{folder}"\n[modbus]\nport = 0\n')
    proc, port, lines = await start_run(config, "--loop", loop)
    client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0)
    assert await client.connect()
    r = await client.read_input_registers(0, count=2, device_id=1)
    assert r.registers == [1, 5]
    client.close()
    code, log = await stop_run(proc, lines, sig)
    assert code == 0, log
    assert "P1 starts PROG91 (by api nc.autostart)" in log
    assert f"event loop: {loop}" in log
    assert "connected" in log and "stopped" in log
    assert "Traceback" not in log and "Task was destroyed" not in log


def test_map_formats(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["map", "--format", "json"]) == 0
    data = json.loads(capsys.readouterr().out)
    rows = {(r["table"], r["start"]): r for r in data["regions"]}
    assert rows[("holding registers", 0)]["hmi_start"] == "40001"
    assert rows[("holding registers", 1000)]["end"] == 1255
    assert rows[("input registers", 100)]["hmi_start"] == "30101"
    assert rows[("coils", 0)]["hmi_end"] == "01024"
    assert rows[("holding registers", 2000)]["access"] == "write"
    assert main(["map", "--format", "csv"]) == 0
    csv_lines = capsys.readouterr().out.splitlines()
    assert csv_lines[0].startswith("table,start,end,count,hmi_start")
    assert len(csv_lines) == 1 + len(data["regions"])
    assert main(["map"]) == 0
    assert "| holding registers | 1500..1627 | 41501..41628 |" in capsys.readouterr().out


def test_map_follows_the_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "c.toml"
    config.write_text("[nc]\nprocesses = 2\n[plc]\nsa_bits = 64\nsyvars = 10\n"
                      "[modbus]\nread_only = true\n")
    assert main(["map", "--config", str(config), "--format", "json"]) == 0
    rows = {(r["table"], r["start"]): r for r in json.loads(capsys.readouterr().out)["regions"]}
    assert rows[("coils", 0)]["count"] == 64 and rows[("coils", 0)]["access"] == "read"
    assert rows[("holding registers", 1000)]["count"] == 10
    assert rows[("input registers", 100)]["count"] == 40


def test_map_shows_the_canopen_dictionary(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["map", "--format", "json"]) == 0
    data = json.loads(capsys.readouterr().out)
    objects = {(o["index"], o["sub"]): o for o in data["canopen"]["objects"]}
    assert data["canopen"]["node_id"] == 16
    assert objects[("0x2000", "1..128")]["type"] == "ARRAY of UNSIGNED8"
    assert objects[("0x2201", "1..128")]["type"] == "ARRAY of INTEGER16"  # SYVAR 128..255
    assert ("0x2202", "1..128") not in objects  # 256 SYVARs: two objects
    assert objects[("0x2400", "1")]["access"] == "wo"
    assert objects[("0x2504", "1")]["access"] == "ro"  # process 5
    assert objects[("0x1017", "0")]["default"] == 1000
    assert main(["map", "--bus", "canopen", "--format", "csv"]) == 0
    assert capsys.readouterr().out.startswith("index,sub,name,type,access,default\n0x1000,0,")
    assert main(["map"]) == 0
    assert "# CANopen dictionary (node 16)" in capsys.readouterr().out


async def test_a_runaway_program_leaves_modbus_answering_and_sigterm_working(
        tmp_path: Path) -> None:
    """Issue 9.1: a loop with no motion and no runaway limit decodes forever, in slices: the
    event loop still serves Modbus between them and stops on SIGTERM."""
    (tmp_path / "LOOP.nc").write_text('"L"\nN1E1=E1+1\nN2(DIS,"spin",E1)\nN3(BNC,L)\n')
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nmain = "LOOP"\nautostart = true\nrunaway_blocks = 0\n'
                      '[nc.storage]\nMP0 = "."\n[modbus]\nport = 0\n')
    proc, port, lines = await start_run(config)
    client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0, timeout=5)
    assert await client.connect()
    for _ in range(20):  # the loop runs all along; every read is answered
        r = await client.read_input_registers(0, count=2, device_id=1)
        assert r.registers == [1, 5]
    client.close()
    code, log = await stop_run(proc, lines)
    assert code == 0, log[-2000:]
    assert "Traceback" not in log


async def test_the_log_names_a_hazard_once_per_block(tmp_path: Path) -> None:
    """A loop repeats its hazard every turn: the log says it once, the trace every time."""
    (tmp_path / "LOOP.nc").write_text(
        '"L"\nN1G1X10F60000\nN2SYVAR1=E1\nN3G1X0\nN4E1=E1+1\nN5(BLT,E1,20,L)\nN6M30\n')
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nmain = "LOOP"\nautostart = true\ntime_scale = 1000.0\n'
                      '[nc.storage]\nMP0 = "."\n[modbus]\nport = 0\n'
                      f'[trace]\nfile = "{tmp_path / "t.jsonl"}"\n')
    proc, _, lines = await start_run(config)
    assert proc.stdout is not None
    async with asyncio.timeout(20):
        while not any("P1 ends (M30)" in line for line in lines):
            line = (await proc.stdout.readline()).decode()
            assert line, "".join(lines)
            lines.append(line)
    proc.send_signal(signal.SIGTERM)
    async with asyncio.timeout(20):
        lines.append((await proc.stdout.read()).decode())
        assert await proc.wait() == 0
    log = "".join(lines)
    assert log.count("P1 hazard") == 1
    assert "P1 hazard at LOOP.nc:3 N2: SYVAR1=0 acted at decode time" in log
    traced = [json.loads(line) for line in (tmp_path / "t.jsonl").read_text().splitlines()]
    assert sum(e["event"] == "hazard" for e in traced) == 20


def test_run_refuses_a_console_beyond_loopback_without_a_token(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "--no-web", "--web", "0.0.0.0:8080"]) == 2  # one or the other
    capsys.readouterr()
    assert main(["run", "--web", "0.0.0.0:18080"]) == 2
    assert ("web.token: the console listens on 0.0.0.0, beyond this machine"
            in capsys.readouterr().err)


@pytest.mark.parametrize(("args", "said"), [
    (["--set", "nc.bogus=1"], "nc.bogus: unknown key"),
    (["--set", "novalue"], "expected KEY=VALUE"),
    (["--set", "modbus.port=70000"], "modbus.port: expected an integer 1..65535"),
    (["--port", "70000"], "modbus.port: expected an integer 1..65535"),
    (["--web", "8080"], "expected HOST:PORT"),
])
def test_run_names_a_bad_override(capsys: pytest.CaptureFixture[str], args: list[str],
                                  said: str) -> None:
    assert main(["run", *args]) == 2
    assert said in capsys.readouterr().err


async def test_run_logs_every_sync_event_in_a_line(tmp_path: Path) -> None:
    """Start, wait with its condition, resume with who wrote the value, SND, end."""
    config = tmp_path / "ncgate.toml"
    config.write_text("")  # the built-in programs are not here: --set points at them
    proc, port, lines = await start_run(
        config, "--no-web", "--set", "nc.autostart=true", "--set", "nc.time_scale=20",
        "--set", f"nc.storage.MP0={json.dumps(str(PROGRAMS))}")
    assert proc.stdout is not None

    async def line_with(text: str) -> str:
        async with asyncio.timeout(20):
            while not any(text in line for line in lines):
                line = (await proc.stdout.readline()).decode()  # type: ignore[union-attr]
                assert line, "".join(lines)
                lines.append(line)
        return next(line for line in lines if text in line)

    await line_with("P1 starts PROG91 (by api nc.autostart)")
    await line_with("P1 EXE PROG92 in P2 at PROG91.nc:4 N1")
    await line_with("P2 waits at PROG92.nc:8 N40 for SA10=1 (now 0)")
    client = AsyncModbusTcpClient("127.0.0.1", port=port)
    assert await client.connect()
    await client.write_coil(10, True, device_id=1)
    local_port = client.ctx.transport.get_extra_info("sockname")[1]  # type: ignore[union-attr]
    await line_with("P2 resumes at PROG92.nc:8 N40 (by cond, written by modbus 127.0.0.1:"
                    f"{local_port})")
    await line_with("P2 SND to P1 at PROG92.nc:10 N85")
    await line_with("P2 ends (REL) at PROG92.nc:14 N100")
    client.close()
    proc.send_signal(signal.SIGTERM)
    async with asyncio.timeout(20):
        await proc.stdout.read()
        assert await proc.wait() == 0


async def test_run_quiet_says_warnings_only_and_records_the_session(tmp_path: Path) -> None:
    (tmp_path / "ZERO.nc").write_text("N1E1=1\nN2E2=E1/0\nN3M30\n")
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nmain = "ZERO"\n[nc.storage]\nMP0 = "."\n')
    record = tmp_path / "session.jsonl"
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ncgate", "run", "--config", str(config), "-q", "--no-web",
        "--port", "0", "--record", str(record), "--set", "nc.autostart=true",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    assert proc.stdout is not None
    out = []
    async with asyncio.timeout(20):
        while not any("ALARM" in line for line in out):  # the first line -q lets through
            line = (await proc.stdout.readline()).decode()
            assert line, "".join(out)
            out.append(line)
    proc.send_signal(signal.SIGTERM)
    async with asyncio.timeout(20):
        out.append((await proc.stdout.read()).decode())
        assert await proc.wait() == 0
    log = "".join(out)
    assert "WARNING ncgate: P1 ALARM AL101 at ZERO.nc:2 N2: division by zero" in log
    assert " INFO " not in log, log  # -q: warnings and errors only
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    assert lines[0]["ncgate_record"] == 2 and lines[0]["config"] == str(config)
    assert lines[0]["overrides"]["nc.autostart"] is True
    starts = [line for line in lines if line.get("input") == "start"]
    assert starts == [{"input": "start", "t": starts[0]["t"], "who": "api nc.autostart",
                       "peer": None, "prog": "ZERO", "proc": 1}]
    assert any(line.get("event") == "alarm" for line in lines)
    assert "stop" in lines[-1]


async def test_sigterm_stops_run_while_a_big_program_is_read(tmp_path: Path) -> None:
    """A cycle start of an 8 MB main is answered at once (the program is read off the loop);
    a SIGTERM right after stops the gateway cleanly before the program ever starts -- it
    does not wait for the reading, nor for the interpreter to free it."""
    lines = [f"N{n % 9999}G1X{n % 500}Y{(n * 7) % 500}F6000\n" for n in range(400_000)]
    (tmp_path / "BIG.nc").write_text("".join(lines) + "M30\n")
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nmain = "BIG"\n[nc.storage]\nMP0 = "."\n[modbus]\nport = 0\n'
                      '[canopen]\nenabled = false\n')
    # --allow-missing: run does not check the main program at start, so the cycle start is
    # the first to read it (checking it at start takes seconds for 8 MB).
    proc, port, lines_before = await start_run(config, "--no-web", "--allow-missing")
    client = AsyncModbusTcpClient("127.0.0.1", port=port, retries=0)
    assert await client.connect()
    await client.write_register(2000, 1, device_id=1)  # cycle start: answered at once
    client.close()
    code, log = await stop_run(proc, lines_before, timeout_s=30)
    assert code == 0 and "stopped" in log, log
    assert "P1 starts BIG" not in log, log  # stopped while it was still being read


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
async def test_a_signal_during_the_start_up_check_stops_run_at_once_and_says_so(
        tmp_path: Path, sig: int) -> None:
    """Before it serves, run checks its main program: seconds for 3 MB.  A SIGTERM then (a
    service manager's stop) or a SIGINT ends it at once, in the check, not after it: a line
    that says so and exit 0, as a stop once serving.  It was the default action: status -15
    and not a word, or a KeyboardInterrupt's traceback."""
    lines = [f"N{n % 9999}G1X{n % 500}Y{(n * 7) % 500}F6000\n" for n in range(150_000)]
    (tmp_path / "BIG.nc").write_text("".join(lines) + "M30\n")  # 3 MB
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nmain = "BIG"\nautostart = true\n[nc.storage]\nMP0 = "."\n'
                      '[modbus]\nport = 0\n[canopen]\nenabled = false\n')
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ncgate", "run", "--config", str(config), "--no-web",
        stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
    assert proc.stderr is not None
    said: list[str] = []
    async with asyncio.timeout(20):
        while not any("checking BIG.nc" in line for line in said):  # the check begins
            line = (await proc.stderr.readline()).decode()
            assert line and "Modbus TCP on" not in line, "".join([*said, line])
            said.append(line)
    proc.send_signal(sig)
    async with asyncio.timeout(20):
        said.append((await proc.stderr.read()).decode())
        code = await proc.wait()
    log = "".join(said)
    assert code == 0, log
    assert log.endswith(f"ncgate run: stopped before serving ({signal.Signals(sig).name})\n"), log
    assert "checked BIG.nc" not in log, log  # the check was cut short, not waited for
    assert "Traceback" not in log


def web_stack_mapped(pid: int) -> bool:
    """Whether aiohttp's compiled parts are in the process (its memory map: the one way to
    see from outside what a process has imported)."""
    return "/aiohttp/" in Path(f"/proc/{pid}/maps").read_text()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/PID/maps")
async def test_the_console_loads_at_its_first_connection_and_misses_nothing(
        tmp_path: Path) -> None:
    """The console's port listens from the start but aiohttp is loaded only when a client
    connects (docs/decisions.md, "The console loads at its first connection"): connections
    made at once all get their answer, and the events of before are in the page's feed."""
    import aiohttp

    config = tmp_path / "ncgate.toml"
    config.write_text(f'[nc]\nautostart = true\ntime_scale = 100.0\n[nc.storage]\n'
                      f'MP0 = "{EXAMPLES / "scheme3"}"\n[modbus]\nport = 0\n[web]\nport = 0\n'
                      '[canopen]\nenabled = false\n')
    proc, _port, lines = await start_run(config)
    assert proc.stdout is not None
    async with asyncio.timeout(20):
        while not (found := re.search(r"web console on (http://[\d.]+:\d+/)", "".join(lines))):
            line = (await proc.stdout.readline()).decode()
            assert line, "".join(lines)
            lines.append(line)
    url = found.group(1)
    try:
        assert not web_stack_mapped(proc.pid)
        async with aiohttp.ClientSession(url) as http:
            pages = await asyncio.gather(*(http.get("/") for _ in range(8)),
                                         http.get("/api/events?since=0"))
            for page in pages[:-1]:
                assert page.status == 200 and "<html" in (await page.text()).lower()
            events = (await pages[-1].json())["events"]
            assert any(e["event"] == "start" and e["proc"] == 1 for e in events), events
        assert web_stack_mapped(proc.pid)  # (so the first check could have failed)
    finally:
        code, log = await stop_run(proc, lines)
    assert code == 0, log
    assert "Traceback" not in log, log


def _children(pid: int) -> list[str]:
    return Path(f"/proc/{pid}/task/{pid}/children").read_text().split()


def _alive(pid: int) -> bool:
    try:
        return "zombie" not in Path(f"/proc/{pid}/status").read_text().lower()
    except FileNotFoundError:
        return False


async def test_sigterm_to_dev_py_run_stops_the_gateway_it_started(tmp_path: Path) -> None:
    """The README's `python3 dev.py run` under a service manager or `kill`: SIGTERM reaches
    dev.py alone, which passes it on; the gateway stopped and its port is free (a new user
    found it orphaned, still listening)."""
    config = tmp_path / "ncgate.toml"
    config.write_text('[modbus]\nport = 0\n[web]\nenabled = false\n')
    proc = await asyncio.create_subprocess_exec(
        sys.executable, str(ROOT / "dev.py"), "run", "--config", str(config), "--allow-missing",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    assert proc.stdout is not None
    lines: list[str] = []
    async with asyncio.timeout(60):  # (dev.py checks the venv first)
        while not re.search(r"Modbus TCP on [\d.]+:(\d+)", lines[-1] if lines else ""):
            line = (await proc.stdout.readline()).decode()
            assert line, "dev.py run ended early:\n" + "".join(lines)
            lines.append(line)
    children = _children(proc.pid)
    assert len(children) == 1, children
    gateway = int(children[0])
    proc.send_signal(signal.SIGTERM)
    try:
        async with asyncio.timeout(20):
            rest = (await proc.stdout.read()).decode()
            code = await proc.wait()
    finally:  # (an orphan holds the pipe open: the read above never ends)
        with contextlib.suppress(ProcessLookupError):
            os.kill(gateway, signal.SIGKILL)
    log = "".join(lines) + rest
    assert code == 0, log  # the gateway's own clean exit, passed on
    assert "stopped" in log
    assert not _alive(gateway), "the gateway outlived dev.py"


async def test_run_logs_a_scripts_fault_and_its_end_by_for_s(tmp_path: Path) -> None:
    """A fault is an input like any: the log says which, on what and from whom -- a script's
    too, and its clear by for_s (a new user found only the console's, as a Python repr)."""
    (tmp_path / "O1.nc").write_text("N1 (DLY,0.3)\nN2 M30\n")
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nmain = "O1"\nautostart = true\n[nc.storage]\nMP0 = "."\n'
                      '[modbus]\nport = 0\n[web]\nenabled = false\n'
                      '[[plant.model]]\nname = "clamp"\nkind = "cylinder"\nextend = "SA20"\n'
                      'extended = "SA30"\ntravel_ms = 100\n')
    script = tmp_path / "s.toml"
    script.write_text('[[fault]]\ntarget = "modbus"\nkind = "exception"\ncode = 6\nat = 0.0\n'
                      'for_s = 0.2\n[[fault]]\ntarget = "clamp"\nkind = "never"\nat = 0.1\n'
                      '[[expect]]\nname = "ends"\ncond = "P1 IDLE"\nby = 1.0\n')
    proc, _port, lines = await start_run(config, "--script", str(script))
    assert proc.stdout is not None
    async with asyncio.timeout(30):  # it ends by itself at the window's end
        log = "".join(lines) + (await proc.stdout.read()).decode()
        assert await proc.wait() == 0, log
    assert "fault exception on modbus (code 6) (by script fault[0])" in log, log
    assert "fault exception on modbus cleared (for_s 0.2)" in log, log
    assert "fault never on clamp (by script fault[1])" in log, log
    assert "Fault(" not in log


def test_run_script_into_a_reader_gone_early_exits_with_its_verdicts_status(
        tmp_path: Path) -> None:
    """`ncgate run --script S | head -1` exited 0 with every expectation failed: the verdict
    lines after the first were a BrokenPipeError, answered by main as map's.  Here the reader
    is gone before the first line."""
    (tmp_path / "O1.nc").write_text("N10 G1X10F6000\nN20 M30\n")
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nprocesses = 1\nmain = "O1"\n[nc.storage]\nMP0 = "."\n'
                      '[modbus]\nport = 0\n[canopen]\nenabled = false\n[web]\n'
                      'enabled = false\n')
    script = tmp_path / "s.toml"
    script.write_text("".join(f'[[expect]]\nname = "SA10 set {i}"\ncond = "SA10=1"\n'
                              'within = [0.0, 0.3]\n' for i in range(3)))
    read_end, write_end = os.pipe()
    os.close(read_end)
    done = subprocess.run([sys.executable, "-m", "ncgate", "run", "--config", str(config),
                           "--script", str(script), "-q"], stdout=write_end,
                          stderr=subprocess.PIPE, text=True, timeout=60)
    os.close(write_end)
    assert done.returncode == 1 and done.stderr == "", done.stderr


def test_the_log_says_a_fault_was_replaced_in_words() -> None:
    from ncgate.gateway.cli.serve import describe
    from ncgate.interpreter.engine import events as ev

    replaced = ev.FaultClear(1, 0.5, 0, None, "canopen", "emcy", "replaced by web 127.0.0.1")
    assert describe(replaced) == "fault emcy on canopen cleared (replaced by web 127.0.0.1)"
    cleared = ev.FaultClear(2, 0.6, 0, None, "canopen", "emcy", "web 127.0.0.1")
    assert describe(cleared) == "fault emcy on canopen cleared (by web 127.0.0.1)"
