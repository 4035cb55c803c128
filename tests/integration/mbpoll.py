"""mbpoll (Debian, on libmodbus) as the tests run it, once, over Modbus TCP or RTU: the
independent client of tests/integration/modbus/ and tests/integration/rtu/."""

from __future__ import annotations

import asyncio
import re

from ncgate.gateway import Gateway

TABLE = {"coils": "0", "discrete": "1", "input": "3", "holding": "4"}


def tcp(gw: Gateway) -> list[str]:
    host, port = gw.modbus_address
    return ["-m", "tcp", "-p", str(port), host]


def rtu(device: str) -> list[str]:
    return ["-m", "rtu", "-b", "19200", "-P", "even", device]


async def mbpoll(where: list[str], table: str, address: int, count: int = 1,
                 write: list[int] | None = None, unit: int = 1) -> tuple[int, dict[int, int],
                                                                         str]:
    """mbpoll once: ``where`` its mode options and then its device or host."""
    *mode, target = where
    cmd = ["mbpoll", *mode, "-a", str(unit), "-0", "-1", "-t", TABLE[table], "-r", str(address)]
    cmd += [target, *map(str, write)] if write else ["-c", str(count), target]
    proc = await asyncio.create_subprocess_exec(*cmd, stdout=asyncio.subprocess.PIPE,
                                                stderr=asyncio.subprocess.STDOUT)
    out, _ = await proc.communicate()
    text = out.decode()
    values = {int(a): int(v) for a, v in re.findall(r"^\[(\d+)\]:\s+(-?\d+)", text, re.M)}
    return proc.returncode or 0, values, text
