"""A canopen master on the gateway's virtual CAN bus, and a cell to talk to.

The master's SDO calls block, and the node answers from the asyncio loop that runs the test:
so the tests call them through ``asyncio.to_thread``.  Frames the master hears are put in
thread-safe queues and awaited with a timeout, never slept for.
"""

from __future__ import annotations

import asyncio
import queue
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import canopen
import pytest
import pytest_asyncio
from canopen.sdo.exceptions import SdoAbortedError

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.canopen.clock import ManualClock
from ncgate.gateway.canopen.dictionary import build_dictionary
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from ...helpers import write_cell

CELL = """
[nc]
processes = 4
main = "MAIN"
time_scale = 50.0
[nc.storage]
MP0 = "."
[[nc.process]]
number = 4
external = true
[canopen]
heartbeat_ms = 0
"""
PROGRAMS = {
    "MAIN": "N1(EXE,2,SIDE)\nN2(WAI,SA10=1)\nN3(SND,4)\nN4(WAI,4)\nN5SYVAR3=-7\nN6M30\n",
    "SIDE": "N1(WAI,SK5=200)\nN2(REL)\n",
    "BAD": "N1E1=1/0\n",
}


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    return write_cell(tmp_path, CELL, PROGRAMS)


@pytest.fixture
def ncgate_config(cell: Path, request: pytest.FixtureRequest) -> Config:
    return ncgate_test_config(cell / "ncgate.toml", **getattr(request, "param", {}))


@dataclass
class Master:
    network: canopen.Network
    node: canopen.RemoteNode
    node_id: int
    frames: dict[int, queue.Queue[bytes]] = field(default_factory=dict)

    def listen(self, cob_id: int) -> queue.Queue[bytes]:
        """Every frame on this COB-ID from now on, in order."""
        q: queue.Queue[bytes] = queue.Queue()
        self.network.subscribe(cob_id, lambda can_id, data, ts: q.put(bytes(data)))
        self.frames[cob_id] = q
        return q

    async def next(self, cob_id: int, timeout_s: float = 5.0) -> bytes:
        return await asyncio.to_thread(self.frames[cob_id].get, True, timeout_s)

    async def until(self, cob_id: int, wanted: bytes, timeout_s: float = 5.0) -> list[bytes]:
        """Frames on the COB-ID up to and including the first equal to ``wanted``."""
        seen = []
        async with asyncio.timeout(timeout_s):
            while not seen or seen[-1] != wanted:
                seen.append(await self.next(cob_id, timeout_s))
        return seen

    async def upload(self, index: int, sub: int) -> bytes:
        return await asyncio.to_thread(self.node.sdo.upload, index, sub)

    async def download(self, index: int, sub: int, data: bytes, force_segment: bool = False
                       ) -> None:
        await asyncio.to_thread(self.node.sdo.download, index, sub, data, force_segment)

    async def while_disabled(self, comm: int, sub: int, data: bytes) -> None:
        """Write a PDO parameter CiA 301 lets change only while the PDO does not exist
        (inhibit time, SYNC start value): disable, write, enable again."""
        cob = await self.upload(comm, 1)
        await self.download(comm, 1, (int.from_bytes(cob, "little") | 0x80000000)
                            .to_bytes(4, "little"))
        await self.download(comm, sub, data)
        await self.download(comm, 1, cob)

    async def raw_sdo(self, payload: bytes, timeout_s: float = 5.0) -> bytes:
        """Send a raw SDO request frame; the node's answer frame."""
        answers = self.frames.get(0x580 + self.node_id) or self.listen(0x580 + self.node_id)
        while not answers.empty():
            answers.get_nowait()
        self.network.send_message(0x600 + self.node_id, payload)
        return await asyncio.to_thread(answers.get, True, timeout_s)

    def nmt(self, command: int) -> None:
        self.network.send_message(0, bytes((command, self.node_id)))

    async def barrier(self) -> None:
        """Until the node has handled every frame sent before, and its loop has run what
        they handed it: a status read goes through the node's receive thread, then its loop,
        and its answer follows on the bus whatever the node sent meanwhile."""
        await self.upload(0x2500, 1)

    def sync(self, counter: int | None = None, cob: int = 0x80) -> None:
        self.network.send_message(cob, b"" if counter is None else bytes((counter,)))


def connect_master(config: Config) -> Master:
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface="virtual", channel=config.canopen.channel)
    node = canopen.RemoteNode(config.canopen.node_id, build_dictionary(config))
    network.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 2.0
    return Master(network, node, config.canopen.node_id)


@pytest.fixture
def master(ncgate_config: Config) -> Iterator[Master]:
    """Connected before the gateway starts, so it hears the boot-up."""
    m = connect_master(ncgate_config)
    for cob in (0x700, 0x180, 0x280, 0x80):
        m.listen(cob + m.node_id)
    yield m
    m.network.disconnect()


@pytest_asyncio.fixture
async def gw(master: Master, ncgate_config: Config) -> AsyncIterator[Gateway]:
    async with Gateway(ncgate_config) as gateway:
        yield gateway


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


@pytest_asyncio.fixture
async def clocked(master: Master, ncgate_config: Config, clock: ManualClock
                  ) -> AsyncIterator[Gateway]:
    """A gateway whose CANopen timers (inhibit, event timer, heartbeat consumer, SDO
    timeout) run on ``clock``: the test moves time with ``clock.advance``."""
    async with Gateway(ncgate_config, canopen_clock=clock) as gateway:
        yield gateway


def u8(v: int) -> bytes:
    return v.to_bytes(1, "little")


def u16(v: int) -> bytes:
    return v.to_bytes(2, "little")


def i16(v: int) -> bytes:
    return v.to_bytes(2, "little", signed=True)


def u32(v: int) -> bytes:
    return v.to_bytes(4, "little")


async def sdo_error(call: object) -> int:
    """The abort code of an SDO call that must be refused."""
    with pytest.raises(SdoAbortedError) as caught:
        await call  # type: ignore[misc]
    return caught.value.code


def abort_code(answer: bytes) -> int:
    assert answer[0] == 0x80, answer.hex()
    return int.from_bytes(answer[4:8], "little")

