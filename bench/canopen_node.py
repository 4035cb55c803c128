"""CANopen node speed (issue: the gateway over CANopen).  Side by side in one script:

1. expedited SDO round trips/s against the gateway's node vs against a bare canopen
   LocalNode with the same dictionary, each on its own python-can virtual channel, driven
   by the same blocking canopen master (target: >= 0.8x);
2. latency from an SND in a program to the TPDO2 frame at the master, p50 / p99 over
   2,000 samples (target: p99 <= 1 ms);
3. TPDO frames per second with TPDO1..4 on SYNC (type 1) and a master sending SYNC at
   1 kHz for 3 s: every SYNC must bring 4 frames (4,000/s);
4. TPDO frames per second with TPDO1..4 event-driven (type 255) on a write storm (every
   write changes what all four map), beside the python-can virtual bus's own frame rate
   measured in the same run (two bare buses, one sending as fast as it can).

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
from ncgate.inputs import Source, SourceKind, Var, Writes

ROUNDS, TRIPS, SAMPLES = 3, 2000, 2000


def master(channel: str, node_id: int, with_dictionary: bool = False
           ) -> tuple[canopen.Network, canopen.RemoteNode]:
    network = canopen.Network()
    network.NOTIFIER_CYCLE = 0.05
    network.connect(interface="virtual", channel=channel)
    od = build_dictionary(load_config(None)) if with_dictionary else None
    node = canopen.RemoteNode(node_id, od)
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


SYNC_HZ, SYNC_S, STORM_WRITES = 1000, 3.0, 20_000


def map_four_tpdos(node: canopen.RemoteNode, ttype: int) -> None:
    """TPDO1..4 each map two SA bytes of their own (a write storm changes all four)."""
    node.tpdo.read()
    for n in range(1, 5):
        pdo = node.tpdo[n]
        pdo.clear()
        pdo.add_variable(0x2000, 2 * n - 1)
        pdo.add_variable(0x2000, 2 * n)
        pdo.trans_type = ttype
        pdo.inhibit_time = 0
        pdo.enabled = True
        pdo.save()


def counting(net: canopen.Network) -> list[int]:
    count = [0]

    def seen(can_id: int, data: bytearray, ts: float) -> None:
        count[0] += 1
    for n in range(4):
        net.subscribe(0x190 + 0x100 * n, seen)
    return count


def tpdos_on_sync() -> None:
    with GatewayThread(None, **{"canopen.channel": "bench-sync", "canopen.heartbeat_ms": 0}):
        net, node = master("bench-sync", 16, with_dictionary=True)
        map_four_tpdos(node, 1)
        count = counting(net)
        node.nmt.send_command(0x01)
        node.sdo.upload(0x2500, 1)  # OPERATIONAL before the first SYNC
        syncs, period = int(SYNC_HZ * SYNC_S), 1 / SYNC_HZ
        start = time.perf_counter()
        for i in range(syncs):  # on a deadline, not a sleep per frame: no drift
            while time.perf_counter() < start + i * period:
                pass
            net.send_message(0x80, b"")
        elapsed = time.perf_counter() - start
        node.sdo.upload(0x2500, 1)  # the node has handled every SYNC
        deadline = time.perf_counter() + 2
        while count[0] < 4 * syncs and time.perf_counter() < deadline:
            time.sleep(0.001)
        net.disconnect()
    print(f"3. TPDO1..4 on SYNC: {syncs:,} SYNCs at {syncs / elapsed:,.0f}/s -> {count[0]:,} "
          f"TPDO frames ({count[0] / elapsed:,.0f}/s), {4 * syncs - count[0]} missing   "
          f"(target: 4 per SYNC, none missing)")


def bus_frame_rate() -> float:
    import can

    tx = can.Bus(interface="virtual", channel="bench-raw")
    rx = can.Bus(interface="virtual", channel="bench-raw")
    n, got = 100_000, 0
    msg = can.Message(arbitration_id=0x190, data=bytes(8), is_extended_id=False)
    start = time.perf_counter()

    def send() -> None:
        for _ in range(n):
            tx.send(msg)
    sender = threading.Thread(target=send)
    sender.start()
    while got < n and rx.recv(1.0) is not None:
        got += 1
    elapsed = time.perf_counter() - start
    sender.join()
    tx.shutdown()
    rx.shutdown()
    return got / elapsed


def tpdos_on_write_storm() -> None:
    with GatewayThread(None, **{"canopen.channel": "bench-storm",
                                "canopen.heartbeat_ms": 0}) as gateway:
        net, node = master("bench-storm", 16, with_dictionary=True)
        map_four_tpdos(node, 255)
        count = counting(net)
        node.nmt.send_command(0x01)
        node.sdo.upload(0x2500, 1)
        deadline = time.perf_counter() + 2
        while count[0] < 4 and time.perf_counter() < deadline:
            time.sleep(0.001)
        base = count[0]  # the four "where things stand" frames

        BENCH = Source(SourceKind.API, "bench")

        async def storm(gw: Gateway) -> float:
            start = time.perf_counter()
            for i in range(STORM_WRITES):
                v = (i + 1) & 0xFF  # never the value before: every write is a change
                gw.apply(Writes(tuple((Var("SA", b, "BY"), v) for b in range(8)), BENCH))
                if i % 64 == 0:
                    await asyncio.sleep(0)  # let the loop breathe, as a server would
            return time.perf_counter() - start
        assert gateway.loop is not None and gateway.gateway is not None
        elapsed = asyncio.run_coroutine_threadsafe(storm(gateway.gateway),
                                                   gateway.loop).result(120)
        node.sdo.upload(0x2500, 1)
        deadline = time.perf_counter() + 5
        while count[0] - base < 4 * STORM_WRITES and time.perf_counter() < deadline:
            time.sleep(0.001)
        frames = count[0] - base
        net.disconnect()
    bus = bus_frame_rate()
    rate = frames / elapsed
    print(f"4. TPDO1..4 event-driven on a storm of {STORM_WRITES:,} image writes "
          f"({STORM_WRITES / elapsed:,.0f} writes/s): {frames:,} TPDO frames ({rate:,.0f}/s), "
          f"{4 * STORM_WRITES - frames} missing; the virtual bus alone: {bus:,.0f} frames/s; "
          f"ratio {rate / bus:.2f}x")


if __name__ == "__main__":
    sdo_throughput()
    snd_to_tpdo2()
    tpdos_on_sync()
    tpdos_on_write_storm()
