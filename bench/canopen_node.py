"""CANopen node speed (issue: the gateway over CANopen).  Side by side in one script:

1. expedited SDO round trips/s against the gateway's node vs against a bare canopen
   LocalNode with the same dictionary, each on its own python-can virtual channel, driven
   by the same blocking canopen master (target: >= 0.8x);
2. latency from an SND in a program to the TPDO2 frame at the master, p50 / p99 over
   2,000 samples (target: p99 <= 1 ms).

The gateway's asyncio loop runs in a background thread (its node answers from there); the
master runs in the main thread, as a test or a tool would.

    python3 dev.py bench         # or: .venv/bin/python bench/canopen_node.py
"""

from __future__ import annotations

import asyncio
import queue
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import canopen

from ncgate.config import load_config
from ncgate.gateway import Gateway
from ncgate.gateway.canopen.dictionary import build_dictionary

ROUNDS, TRIPS, SAMPLES = 3, 2000, 2000


def master(channel: str, node_id: int) -> tuple[canopen.Network, canopen.RemoteNode]:
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface="virtual", channel=channel)
    node = canopen.RemoteNode(node_id, None)
    network.add_node(node)
    return network, node


def round_trips(node: canopen.RemoteNode, index: int, sub: int) -> float:
    upload = node.sdo.upload
    start = time.perf_counter()
    for _ in range(TRIPS):
        upload(index, sub)
    return TRIPS / (time.perf_counter() - start)


class GatewayThread:
    """A gateway running on its own asyncio loop in a background thread."""

    def __init__(self, config_path: Path | None, **overrides: object) -> None:
        self.config = load_config(config_path, overrides={"modbus.enabled": False,
                                                          **overrides})
        self.ready = threading.Event()
        self.stop: asyncio.Event | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.gateway: Gateway | None = None
        self.thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)

    async def _main(self) -> None:
        self.loop = asyncio.get_running_loop()
        self.stop = asyncio.Event()
        async with Gateway(self.config) as gw:
            self.gateway = gw
            self.ready.set()
            await self.stop.wait()

    def __enter__(self) -> GatewayThread:
        self.thread.start()
        self.ready.wait(10)
        return self

    def __exit__(self, *exc: object) -> None:
        assert self.loop is not None and self.stop is not None
        self.loop.call_soon_threadsafe(self.stop.set)
        self.thread.join(10)

    def call(self, fn: Callable[[Gateway], object]) -> None:
        assert self.loop is not None and self.gateway is not None
        gw = self.gateway
        asyncio.run_coroutine_threadsafe(_call(fn, gw), self.loop).result(10)


async def _call(fn: Callable[[Gateway], object], gw: Gateway) -> None:
    result = fn(gw)
    if asyncio.iscoroutine(result):
        await result


def sdo_throughput() -> None:
    config = load_config(None)
    bare_net = canopen.Network()
    bare_net.NOTIFIER_CYCLE = 0.05
    bare_net.connect(interface="virtual", channel="bench-bare")
    bare = canopen.LocalNode(20, build_dictionary(config))
    bare_net.add_node(bare)
    bare_master_net, bare_master = master("bench-bare", 20)
    with GatewayThread(None, **{"canopen.channel": "bench-ours"}):
        ours_master_net, ours_master = master("bench-ours", 16)
        rates: dict[str, list[float]] = {"ours": [], "ours_1000": [], "bare": []}
        for _ in range(ROUNDS):  # alternate, so both see the same machine
            rates["ours"].append(round_trips(ours_master, 0x2000, 1))  # the live image
            rates["ours_1000"].append(round_trips(ours_master, 0x1000, 0))
            rates["bare"].append(round_trips(bare_master, 0x2000, 1))
        ours_master_net.disconnect()
    bare_master_net.disconnect()
    bare_net.disconnect()
    o, o2, b = max(rates["ours"]), max(rates["ours_1000"]), max(rates["bare"])
    print(f"1. expedited SDO upload of 0x2000:1 (an SA byte): gateway node {o:,.0f}/s, bare "
          f"LocalNode {b:,.0f}/s; ratio {o / b:.2f}x   (target >= 0.8x); gateway 0x1000: "
          f"{o2:,.0f}/s")


PING = '"L"\nN1(SND,4)\nN2(WAI,4)\nN3(BNC,L)\n'


def snd_to_tpdo2() -> None:
    folder = Path(tempfile.mkdtemp())
    (folder / "PING.nc").write_text(PING)
    (folder / "ncgate.toml").write_text(
        '[nc]\nmain = "PING"\n[[nc.process]]\nnumber = 4\nexternal = true\n'
        '[canopen]\nchannel = "bench-tpdo"\nnmt_autostart = true\nheartbeat_ms = 0\n')
    sent: list[float] = []
    received: queue.Queue[float] = queue.Queue()
    with GatewayThread(folder / "ncgate.toml") as gateway:
        net, node = master("bench-tpdo", 16)
        net.subscribe(0x290, lambda can_id, data, ts: received.put(time.perf_counter()))

        def hook(gw: Gateway) -> None:
            gw.runtime.trace.subscribe(
                lambda e: sent.append(time.perf_counter()) if e.kind == "snd" else None)
        gateway.call(hook)
        node.sdo.download(0x2400, 2, bytes([4]))  # the mailbox's sender: P4
        gateway.call(lambda gw: gw.start())
        latencies = []
        for i in range(SAMPLES):
            arrived = received.get(timeout=5)
            latencies.append(arrived - sent[i])
            node.sdo.download(0x2400, 3, bytes([1]))  # P4 sends to P1: the next round
        net.disconnect()
    q = statistics.quantiles(latencies, n=100)
    print(f"2. SND in a program -> TPDO2 at the master, {SAMPLES} samples: p50 {q[49] * 1e6:.0f}"
          f" us, p99 {q[98] * 1e6:.0f} us   (target p99 <= 1000 us)")


if __name__ == "__main__":
    sdo_throughput()
    snd_to_tpdo2()
