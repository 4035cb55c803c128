"""Modbus RTU through a second independent master: a libmodbus RTU client in C, built here
(as bench/c's programs are), on the other end of a socat pty pair.  Its reads of every table
must be the values mbpoll reads over Modbus TCP, its writes must land."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
from pathlib import Path

import pytest

from ncgate.gateway import Gateway

from ..mbpoll import mbpoll, tcp
from .conftest import need
from .test_rtu_mbpoll import RANGES

SOURCE = Path(__file__).with_name("libmodbus_rtu_client.c")
LETTER = {"coils": "c", "discrete": "d", "input": "i", "holding": "h"}


@pytest.fixture(scope="module")
def client_binary(tmp_path_factory: pytest.TempPathFactory) -> Path:
    need("cc", "gcc")
    need("pkg-config", "pkg-config")
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "libmodbus"],
                           capture_output=True, text=True)
    if flags.returncode != 0:
        need("libmodbus-dev is missing", "libmodbus-dev")  # skips here, fails under CI
    out = tmp_path_factory.mktemp("c") / "libmodbus_rtu_client"
    subprocess.run(["cc", "-O1", "-o", str(out), str(SOURCE), *flags.stdout.split()],
                   check=True)
    assert shutil.which(str(out))
    return out


class Client:
    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc

    async def ask(self, line: str) -> list[int]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(line.encode() + b"\n")
        await self.proc.stdin.drain()
        async with asyncio.timeout(10):
            answer = (await self.proc.stdout.readline()).decode().split()
        assert answer and answer[0] == "ok", f"{line}: {' '.join(answer)}"
        return [int(v) for v in answer[1:]]


async def test_libmodbus_rtu_reads_every_table_as_tcp_does_and_writes(
        ncgate_gateway: Gateway, socat_pair: tuple[str, str], client_binary: Path) -> None:
    need("mbpoll", "mbpoll")
    gw = ncgate_gateway
    proc = await asyncio.create_subprocess_exec(
        str(client_binary), socat_pair[1], "7", stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE)
    client = Client(proc)
    try:
        await client.ask("w h 2000 1")  # cycle start, as unit 7 (the cell's second id)
        await gw.wait_state(1, "WAIT_COND", timeout_s=10)
        await gw.wait_state(2, "WAIT_COND", timeout_s=10)
        await client.ask("w h 1002 54321")
        await client.ask("w c 20 1")
        assert gw.image.syvar[2] == 54321 - 0x10000  # a SYVAR register is signed 16-bit
        assert (gw.image.sa[2] >> 4) & 1
        for table, address, count in RANGES:
            over_rtu = await client.ask(f"r {LETTER[table]} {address} {count}")
            rc, over_tcp, text = await mbpoll(tcp(gw), table, address, count)
            assert rc == 0, text
            assert over_rtu == [over_tcp[address + i] for i in range(count)], (table, address)
    finally:
        assert proc.stdin is not None
        proc.stdin.close()
        await proc.wait()
    writers = {e["who"] for e in gw.trace if e["event"] == "write"}
    assert f"modbus-rtu {socat_pair[0]}" in writers
