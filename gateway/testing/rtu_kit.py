"""A serial line for tests without a cable or socat: two pseudo-terminals whose master sides
this process relays to each other on the event loop, as a null-modem cable joins two ports.

    async with PtyPair() as line:
        config = ncgate_test_config(..., **{"modbus.rtu.port": line.gateway_end})
        ...  # a master (VirtualPLC.rtu(line.plc_end, config), mbpoll) opens line.plc_end

Bytes go through as they are, and a silence on one side is a silence on the other (the
relay adds one loop turn), so RTU's framing -- the 3.5-character gaps included -- is what a
master on ``plc_end`` makes of it.  The ``ncgate_rtu_line`` fixture is one of these.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import tty


class PtyPair:
    """Two ptys joined: ``gateway_end`` and ``plc_end`` are device paths (``/dev/pts/N``)."""

    def __init__(self) -> None:
        self._fds: list[int] = []
        self._masters: list[int] = []
        self.gateway_end = self.plc_end = ""
        self._pending: dict[int, bytearray] = {}

    async def __aenter__(self) -> PtyPair:
        self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        loop = asyncio.get_running_loop()
        ends = []
        for _ in range(2):
            master, slave = os.openpty()
            self._fds += [master, slave]
            tty.setraw(master)
            os.set_blocking(master, False)
            self._masters.append(master)
            ends.append(os.ttyname(slave))
        self.gateway_end, self.plc_end = ends
        a, b = self._masters
        for src, dst in ((a, b), (b, a)):
            self._pending[dst] = bytearray()
            loop.add_reader(src, self._relay, src, dst)

    def _relay(self, src: int, dst: int) -> None:
        try:
            data = os.read(src, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:  # EIO: nobody has the slave side open (between two clients)
            return
        pending = self._pending[dst]
        pending += data
        with contextlib.suppress(BlockingIOError, InterruptedError):
            sent = os.write(dst, pending)
            del pending[:sent]
        if pending:
            asyncio.get_running_loop().add_writer(dst, self._flush, dst)

    def _flush(self, dst: int) -> None:
        pending = self._pending[dst]
        with contextlib.suppress(BlockingIOError, InterruptedError):
            sent = os.write(dst, pending)
            del pending[:sent]
        if not pending:
            asyncio.get_running_loop().remove_writer(dst)

    def close(self) -> None:
        loop = asyncio.get_running_loop()
        for master in self._masters:
            loop.remove_reader(master)
            loop.remove_writer(master)
        for fd in self._fds:
            with contextlib.suppress(OSError):
                os.close(fd)
        self._fds, self._masters = [], []
