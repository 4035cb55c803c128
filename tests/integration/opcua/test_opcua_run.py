"""`ncgate run --opcua` as a user runs it: a real process serving OPC UA, read by node-opcua,
stopped by a signal -- and its server's process gone with it, even after a kill -9."""

from __future__ import annotations

import asyncio
import os
import re
import signal
import sys
from pathlib import Path

from .conftest import DI, MACHINERY, NCGATE, UaClient


async def start_run(tmp_path: Path, new_group: bool = False
                    ) -> tuple[asyncio.subprocess.Process, int, list[str]]:
    (tmp_path / "ncgate").mkdir()  # (an ncgate.toml's machine is named after its folder)
    config = tmp_path / "ncgate" / "ncgate.toml"
    config.write_text("[modbus]\nport = 0\n[canopen]\nenabled = false\n")
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ncgate", "run", "--config", str(config), "--no-web",
        "--opcua", "0", "--allow-missing", stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT, start_new_session=new_group)
    assert proc.stdout is not None
    lines: list[str] = []
    async with asyncio.timeout(60):
        while True:
            line = (await proc.stdout.readline()).decode()
            assert line, "ncgate run ended early:\n" + "".join(lines)
            lines.append(line)
            found = re.search(r"OPC UA on opc\.tcp://127\.0\.0\.1:(\d+)/, security none", line)
            if found:
                return proc, int(found.group(1)), lines


async def port_closed(port: int) -> None:
    """Until nothing listens on ``port`` (another process's port: nothing to wait on)."""
    async with asyncio.timeout(20):
        while True:
            try:
                _, writer = await asyncio.open_connection("127.0.0.1", port)
            except OSError:
                return
            writer.close()
            await asyncio.sleep(0.05)  # another process's socket: nothing to wait on


async def test_run_opcua_serves_the_cell_and_stops_cleanly_on_sigterm(
        tmp_path: Path, ua_client: UaClient) -> None:
    proc, port, lines = await start_run(tmp_path)
    await ua_client.call("connect", url=f"opc.tcp://127.0.0.1:{port}/")
    node = await ua_client.call("translate", path=[
        (MACHINERY, "Machines"), (NCGATE, "ncgate"), (DI, "Identification"),
        (DI, "Manufacturer")])
    assert await ua_client.call("read", node=node) == "ncgate (virtual)"
    await ua_client.call("close")
    proc.send_signal(signal.SIGTERM)
    assert proc.stdout is not None
    async with asyncio.timeout(30):
        log = "".join(lines) + (await proc.stdout.read()).decode()
        code = await proc.wait()
    assert code == 0, log
    assert "Traceback" not in log, log
    await port_closed(port)


async def test_the_server_process_ends_when_run_is_killed(tmp_path: Path) -> None:
    proc, port, _ = await start_run(tmp_path)
    proc.kill()  # no close: the server's process sees its stdin end
    await proc.wait()
    await port_closed(port)


async def test_ctrl_c_to_the_process_group_stops_run_and_its_server_cleanly(
        tmp_path: Path) -> None:
    """A terminal's Ctrl-C reaches every process of its group: the server's process leaves its
    end to the gateway, which stops it once it has shut down itself."""
    proc, port, lines = await start_run(tmp_path, new_group=True)
    os.killpg(proc.pid, signal.SIGINT)
    assert proc.stdout is not None
    async with asyncio.timeout(30):
        log = "".join(lines) + (await proc.stdout.read()).decode()
        code = await proc.wait()
    assert code == 0, log
    assert "Traceback" not in log and "process ended" not in log, log
    await port_closed(port)
