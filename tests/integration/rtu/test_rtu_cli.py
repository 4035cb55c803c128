"""`ncgate run --rtu DEVICE --rtu-tcp PORT` as a user runs it: a real process, mbpoll on the
other end of a socat pty pair, the log saying where it serves; a device that cannot be
opened stops the start with the key to change."""

from __future__ import annotations

import asyncio
import re
import signal
import sys
from pathlib import Path

from ..mbpoll import mbpoll, rtu
from ..test_cli_run import start_run, stop_run
from .conftest import need


async def test_run_serves_rtu_on_the_serial_port_and_over_tcp(
        tmp_path: Path, cell: Path, socat_pair: tuple[str, str]) -> None:
    need("mbpoll", "mbpoll")
    proc, _, lines = await start_run(cell / "ncgate.toml", "--rtu", socat_pair[0],
                                     "--rtu-tcp", "0", "--no-web", "--port", "0")
    try:
        assert proc.stdout is not None
        async with asyncio.timeout(20):  # the adapters' lines follow Modbus TCP's
            while "Modbus RTU over TCP" not in lines[-1]:
                line = (await proc.stdout.readline()).decode()
                assert line, "".join(lines)
                lines.append(line)
        log = "".join(lines)
        assert f"Modbus RTU on {socat_pair[0]} (19200 bit/s, 8E1), unit ids 1,7" in log
        rc, values, text = await mbpoll(rtu(socat_pair[1]), "input", 0, 2)
        assert rc == 0 and (values[0], values[1]) == (1, 4), text
    finally:
        code, log = await stop_run(proc, lines, signal.SIGINT)
    assert code == 0, log
    assert re.search(r"Modbus RTU over TCP on 127\.0\.0\.1:\d+, unit ids 1,7", log), log
    assert "Traceback" not in log


async def test_a_serial_port_that_cannot_be_opened_stops_the_start(cell: Path,
                                                                   tmp_path: Path) -> None:
    missing = tmp_path / "ttyNONE"
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ncgate", "run", "--config", str(cell / "ncgate.toml"),
        "--rtu", str(missing), "--no-web", "--port", "0",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    out, _ = await proc.communicate()
    text = out.decode()
    assert proc.returncode != 0, text
    assert f"modbus.rtu.port: cannot open {missing}" in text, text
    assert "Traceback" not in text
