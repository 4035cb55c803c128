"""A serial port that goes away while served (a USB adapter pulled: here the socat relay
killed) is logged, shown closed, and taken again when it comes back; the rest of the cell
serves on meanwhile."""

from __future__ import annotations

import asyncio
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.gateway.web.status import fieldbus

from ..mbpoll import mbpoll, rtu, tcp
from .conftest import need, socat


def relay(tmp_path: Path) -> subprocess.Popen[str]:
    return socat(*(f"pty,raw,echo=0,link={tmp_path / end}" for end in ("ttyGW", "ttyPLC")))


async def until(gw: Gateway, what: Callable[[], bool], timeout_s: float = 10.0) -> None:
    """Until ``what`` holds, woken each time the serial port opens or goes away."""
    line = gw.adapters["modbus_rtu"].serial
    async with asyncio.timeout(timeout_s):
        while not what():
            line.changed.clear()
            await line.changed.wait()


async def test_a_port_that_goes_away_is_taken_again_when_it_comes_back(
        tmp_path: Path, cell: Path, caplog: pytest.LogCaptureFixture) -> None:
    need("socat", "socat")
    need("mbpoll", "mbpoll")
    first = relay(tmp_path)
    async with Gateway(ncgate_test_config(
            cell / "ncgate.toml", **{"modbus.rtu.port": str(tmp_path / "ttyGW")})) as gw:
        def serial() -> dict[str, object]:
            port: dict[str, object] = fieldbus(gw)["modbus_rtu"]["ports"][0]
            return port

        plc = str(tmp_path / "ttyPLC")
        assert (await mbpoll(rtu(plc), "input", 1))[1] == {1: 4}
        first.kill()
        first.wait()
        await until(gw, lambda: serial()["open"] is False)
        assert "the port went away" in caplog.text
        assert (await mbpoll(tcp(gw), "input", 1))[1] == {1: 4}  # TCP serves on
        second = relay(tmp_path)
        try:
            await until(gw, lambda: serial()["open"] is True)
            rc, values, text = await mbpoll(rtu(plc), "input", 1)
            assert rc == 0 and values == {1: 4}, text
            assert serial()["answered"] == 2  # counted across the two openings
        finally:
            second.terminate()
            second.wait()
