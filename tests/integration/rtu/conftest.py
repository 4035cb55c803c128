"""Modbus RTU over pseudo-terminals: a cell like the Modbus tests', its serial server on one
end of a ``socat`` pty pair and the independent masters (mbpoll, a libmodbus client in C) on
the other, or the raw bytes of a test on the master side of a pty (no relay between).

socat, mbpoll, a C compiler and libmodbus-dev are Debian's; CI installs them (.ci/run): a
missing one fails there and skips here, with the reason.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import subprocess
import tty
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest
import pytest_asyncio

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.modbus.framer import crc16
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from ...helpers import write_cell
from ..modbus.conftest import CELL, PROGRAMS


def need(tool: str, package: str) -> None:
    """Skip (fail under CI) without ``tool``."""
    if shutil.which(tool) is None:
        if os.environ.get("CI"):
            pytest.fail(f"{tool} is not installed: .ci/run must install {package}",
                        pytrace=False)
        pytest.skip(f"{tool} not installed (apt-get install {package}); CI runs this")


def frame(hex_text: str) -> bytes:
    """An RTU frame: the bytes given, then their CRC (low byte first)."""
    body = bytes.fromhex(hex_text)
    crc = crc16(body)
    return body + bytes((crc & 0xFF, crc >> 8))


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    return write_cell(tmp_path, CELL, PROGRAMS)


def socat(*addresses: str) -> subprocess.Popen[str]:
    """socat relaying ``addresses``, once it says both exist and it relays."""
    proc = subprocess.Popen(["socat", "-d", "-d", *addresses], stderr=subprocess.PIPE,
                            text=True)
    assert proc.stderr is not None
    for line in proc.stderr:
        if "starting data transfer loop" in line:
            return proc
    pytest.fail(f"socat ended: {proc.wait()}")


@pytest.fixture
def socat_pair(tmp_path: Path) -> Iterator[tuple[str, str]]:
    """Two linked pseudo-terminals (``socat``): (the gateway's end, the master's end)."""
    need("socat", "socat")
    ends = str(tmp_path / "ttyGW"), str(tmp_path / "ttyPLC")
    proc = socat(*(f"pty,raw,echo=0,link={e}" for e in ends))
    yield ends
    proc.terminate()
    proc.wait()


@pytest.fixture
def ncgate_config(cell: Path, socat_pair: tuple[str, str]) -> Config:
    return ncgate_test_config(cell / "ncgate.toml", **{"modbus.rtu.port": socat_pair[0],
                                                      "modbus.rtu_tcp.port": 0})


class RawLine:
    """The master side of a pty whose other side the gateway serves: bytes as they are."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        os.set_blocking(self.master, False)
        self.device = os.ttyname(self.slave)
        self.received = bytearray()
        self.arrived = asyncio.Event()
        asyncio.get_running_loop().add_reader(self.master, self._readable)

    def _readable(self) -> None:
        try:
            self.received += os.read(self.master, 4096)
        except BlockingIOError:
            return
        self.arrived.set()

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    async def silence(self, seconds: float = 0.02) -> None:
        """Send nothing for ``seconds`` (ten times the 3.5 characters of 19,200 bit/s): the
        line's silence is itself the input here."""
        await asyncio.sleep(seconds)

    async def answer(self, length: int, timeout_s: float = 5.0) -> bytes:
        """The next ``length`` bytes the gateway sends."""
        async with asyncio.timeout(timeout_s):
            while len(self.received) < length:
                self.arrived.clear()
                await self.arrived.wait()
        out = bytes(self.received[:length])
        del self.received[:length]
        return out

    def close(self) -> None:
        asyncio.get_running_loop().remove_reader(self.master)
        os.close(self.master)
        os.close(self.slave)


@pytest_asyncio.fixture
async def raw_line() -> AsyncIterator[RawLine]:
    line = RawLine()
    yield line
    line.close()


@pytest_asyncio.fixture
async def raw_gateway(cell: Path, raw_line: RawLine) -> AsyncIterator[Gateway]:
    """A gateway whose RTU server is on ``raw_line``'s pty (unit ids 1 and 7)."""
    config = ncgate_test_config(cell / "ncgate.toml", **{"modbus.rtu.port": raw_line.device})
    async with Gateway(config) as gw:
        yield gw
