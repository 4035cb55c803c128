"""A serial port that goes away while served (a USB adapter pulled: here the socat relay
killed) is logged, shown closed, and taken again when it comes back; the rest of the cell
serves on meanwhile."""

from __future__ import annotations

import asyncio
import os
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


def port_status(gw: Gateway) -> dict[str, object]:
    """The serial port's status (fieldbus.modbus_rtu's only port)."""
    port: dict[str, object] = fieldbus(gw)["modbus_rtu"]["ports"][0]
    return port


def served(tmp_path: Path, cell: Path) -> Gateway:
    """A gateway serving the relay's ttyGW."""
    return Gateway(ncgate_test_config(cell / "ncgate.toml",
                                      **{"modbus.rtu.port": str(tmp_path / "ttyGW")}))


async def test_a_port_that_goes_away_is_taken_again_when_it_comes_back(
        tmp_path: Path, cell: Path, caplog: pytest.LogCaptureFixture) -> None:
    need("socat", "socat")
    need("mbpoll", "mbpoll")
    first = relay(tmp_path)
    async with served(tmp_path, cell) as gw:
        plc = str(tmp_path / "ttyPLC")
        assert (await mbpoll(rtu(plc), "input", 1))[1] == {1: 4}
        first.kill()
        first.wait()
        await until(gw, lambda: port_status(gw)["open"] is False)
        assert "the port went away" in caplog.text
        assert (await mbpoll(tcp(gw), "input", 1))[1] == {1: 4}  # TCP serves on
        second = relay(tmp_path)
        try:
            await until(gw, lambda: port_status(gw)["open"] is True)
            rc, values, text = await mbpoll(rtu(plc), "input", 1)
            assert rc == 0 and values == {1: 4}, text
            assert port_status(gw)["answered"] == 2  # counted across the two openings
        finally:
            second.terminate()
            second.wait()


def used_with_parity(device: str) -> None:
    """Open ``device`` with even parity and close it, as a gateway that served it before
    did: Linux 6.x then refuses even parity on that pseudo-terminal (tcsetattr: EINVAL)."""
    import serial

    serial.Serial(device, 19200, parity=serial.PARITY_EVEN, timeout=0).close()


async def test_a_pty_served_before_is_served_again(tmp_path: Path, cell: Path) -> None:
    """The README's socat pair, served by one `ncgate run` and then the next: the second
    crashed at the start with termios.error (exit 70, "a bug in ncgate"), the pty refusing
    the parity it had been given once."""
    need("socat", "socat")
    need("mbpoll", "mbpoll")
    pair = relay(tmp_path)
    try:
        used_with_parity(str(tmp_path / "ttyGW"))  # the gateway before
        async with served(tmp_path, cell) as gw:
            rc, values, text = await mbpoll(rtu(str(tmp_path / "ttyPLC")), "input", 1)
            assert rc == 0 and values == {1: 4}, text
            assert port_status(gw)["settings"] == "19200 8E1 (a pty: opened without parity)"
    finally:
        pair.terminate()
        pair.wait()


async def test_a_port_that_comes_back_refusing_its_settings_is_still_looked_for(
        tmp_path: Path, cell: Path) -> None:
    """A port that went away came back as a pty served before: its reopening raised
    termios.error, which ended the looking for it for good (the line stayed closed, the
    status said "end of file")."""
    need("socat", "socat")
    need("mbpoll", "mbpoll")
    first = relay(tmp_path)
    async with served(tmp_path, cell) as gw:
        first.kill()
        first.wait()
        await until(gw, lambda: port_status(gw)["open"] is False)
        # The new pair is used before the gateway may find it: made under other names,
        # then put where the port was.
        second = socat(*(f"pty,raw,echo=0,link={tmp_path / end}"
                         for end in ("ttyGW2", "ttyPLC2")))
        try:
            used_with_parity(str(tmp_path / "ttyGW2"))
            os.replace(tmp_path / "ttyGW2", tmp_path / "ttyGW")
            await until(gw, lambda: port_status(gw)["open"] is True)
            rc, values, text = await mbpoll(rtu(str(tmp_path / "ttyPLC2")), "input", 1)
            assert rc == 0 and values == {1: 4}, text
        finally:
            second.terminate()
            second.wait()
