"""The OPC UA server's cost to the cell and its latency (docs/opcua.md; docs/decisions.md,
"OPC UA: a thread of its own fed snapshots").

1. **Start-up: what asyncua's init holds the loop for.**  A 1 ms ticker runs on the loop
   while an asyncua server starts and builds ncgate's address space (about 2,000 nodes for
   the built-in cell) on that same loop -- the "same loop" design -- and then while a
   ``Gateway`` with ``[opcua]`` starts its server on a thread of its own, the design ncgate
   uses.  Printed: the ticker's longest gap in each case (target for the thread: <= 20 ms,
   the loop stays free while the server's thread builds).
2. **Write -> data-change notification**, beside **Modbus write -> read** in the same run
   (the baseline): `ncgate run` in a process of its own with Modbus and OPC UA on loopback
   (``opcua.writable = ["sa_bits"]``); in alternating rounds an asyncua client writes SA20
   and times the data-change notification of SA20 on its subscription (publishing interval
   10 ms), and a pymodbus client writes coil 21 (SA21) and reads it back.  Printed: p50/p99
   of each and the ratio (UA to Modbus).  A notification leaves at the next publishing
   interval, so the UA figure includes up to 10 ms of waiting by design.
3. **What feeding the server costs the gateway's loop**: the time of each hand-over (one
   loop turn's changes to the server's thread) and of each 0.1 s sample, measured inside a
   gateway in this process while it is written to.
4. **The storm rule** (``--storm``): bench/storm.py's cell (PLC logic scanning every 10 ms,
   an SND/WAI loop, a 200 Hz Modbus poller sampling the last scan's lateness) with
   ``[opcua]`` on, in two phases of ``--seconds`` each.  In both, a process of its own
   writes SYVAR0..63 by Modbus at 20 Hz, so the image changes as a busy cell's does.  In the
   quiet phase no OPC UA client connects; in the storm phase 10 asyncua clients in that
   process (at nice 10: they stand for dashboards on other machines) each monitor 2,000 items
   (publishing interval 50 ms).  Printed: the poller's p99
   and the PLC's largest lateness in each phase and their ratio to quiet (target <= 1.5x),
   the gateway process's CPU share, and the p99 of bench/storm.py's control (a bare asyncio
   server in a process of its own, polled alike): the clients and the server run on this
   machine too, so what the machine's load does to any server shows there.

5. **How long a start takes** (``--starts N``, alone): N ``Gateway`` starts with ``[opcua]``
   (Modbus on a free port, no CANopen, no console), each timed from ``__aenter__`` to
   serving, on whatever the machine is doing -- run it beside a load (a suite, CPU hogs) to
   see a start on a busy machine (docs/decisions.md: the server starts at nice 0).

    .venv/bin/python bench/opcua.py                  # 300 rounds of each
    .venv/bin/python bench/opcua.py --rounds 1000 --storm --seconds 10
    .venv/bin/python bench/opcua.py --starts 3
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = str(Path(__file__).resolve().parent)  # bench/storm.py's cell and poller are reused


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


async def ticker_gap(work: Any) -> tuple[float, float]:
    """The longest gap (ms) of a 1 ms ticker on this loop while ``work`` runs, and its time."""
    gaps: list[float] = []
    stop = False

    async def tick() -> None:
        last = time.perf_counter()
        while not stop:
            await asyncio.sleep(0.001)
            now = time.perf_counter()
            gaps.append(now - last)
            last = now
    task = asyncio.create_task(tick())
    await asyncio.sleep(0.01)
    t0 = time.perf_counter()
    result = await work()
    took = time.perf_counter() - t0
    stop = True
    await task
    del result
    return max(gaps) * 1000, took


async def same_loop_start() -> None:
    """asyncua started on this loop with an address space of ncgate's size."""
    from asyncua import Server, ua

    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{free_port()}/")
    ns = await server.register_namespace("urn:bench")
    folder = await server.nodes.objects.add_folder(ua.NodeId("Image", ns), "Image")
    for i in range(2000):
        await folder.add_variable(ua.NodeId(f"V{i}", ns), f"V{i}", 0)
    await server.start()
    await server.stop()


async def startup() -> None:
    from ncgate.gateway import Gateway, load_config

    gap, took = await ticker_gap(same_loop_start)
    print(f"start-up, asyncua on the gateway's loop: the loop held up to {gap:.0f} ms "
          f"(start {took:.2f} s)")
    for opcua in (False, True):
        config = load_config(None, overrides={"opcua.enabled": opcua, "opcua.port": 0,
                                              "modbus.port": 0, "canopen.enabled": False})
        gateway = Gateway(config)

        async def start(gateway: Gateway = gateway) -> None:
            await gateway.__aenter__()
        gap, took = await ticker_gap(start)
        await gateway.__aexit__(None, None, None)
        what = ("ncgate's server in a process of its own" if opcua
                else "the baseline, a gateway without [opcua]")
        print(f"start-up, {what}: the loop held up to {gap:.0f} ms (the gateway's start "
              f"{took:.2f} s)")


async def latency(rounds: int) -> None:
    from asyncua import Client, ua
    from pymodbus.client import AsyncModbusTcpClient

    with tempfile.TemporaryDirectory() as tmp:
        mb, uap = free_port(), free_port()
        gateway = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "ncgate", "run", "-q", "--no-web", "--port", str(mb),
            "--opcua", str(uap), "--set", 'opcua.writable=["sa_bits"]',
            "--set", "canopen.enabled=false", stdout=asyncio.subprocess.DEVNULL, cwd=tmp)
        try:
            async with asyncio.timeout(60):
                while True:
                    with contextlib.suppress(OSError):
                        _, w = await asyncio.open_connection("127.0.0.1", uap)
                        w.close()
                        break
                    await asyncio.sleep(0.05)  # another process's port: nothing to wait on
            client = Client(f"opc.tcp://127.0.0.1:{uap}/")
            await client.connect()
            modbus = AsyncModbusTcpClient("127.0.0.1", port=mb)
            await modbus.connect()
            ns = await client.get_namespace_index("urn:ncgate:image")
            node = client.get_node(ua.NodeId("SA20", ns))
            seen: asyncio.Queue[tuple[float, Any]] = asyncio.Queue()

            class Handler:
                def datachange_notification(self, node: Any, value: Any, data: Any) -> None:
                    seen.put_nowait((time.perf_counter(), value))
            sub = await client.create_subscription(10, Handler())
            await sub.subscribe_data_change(node)
            await seen.get()  # the initial value
            ua_ms: list[float] = []
            mb_ms: list[float] = []
            for i in range(rounds):
                value = bool((i + 1) % 2)
                t0 = time.perf_counter()
                await node.write_value(ua.Variant(value, ua.VariantType.Boolean))
                while True:
                    t1, got = await seen.get()
                    if got == value:
                        break
                ua_ms.append((t1 - t0) * 1000)
                t0 = time.perf_counter()
                await modbus.write_coil(21, value)
                read = await modbus.read_coils(21, count=1)
                assert read.bits[0] == value
                mb_ms.append((time.perf_counter() - t0) * 1000)
            await client.disconnect()
            modbus.close()
        finally:
            gateway.terminate()
            await gateway.wait()
    print(f"write -> notification (OPC UA, publishing 10 ms): p50 {pct(ua_ms, .5):.2f} ms, "
          f"p99 {pct(ua_ms, .99):.2f} ms over {rounds} rounds")
    print(f"write -> read (Modbus, the baseline):          p50 {pct(mb_ms, .5):.2f} ms, "
          f"p99 {pct(mb_ms, .99):.2f} ms")
    print(f"ratio OPC UA / Modbus: p50 {pct(ua_ms, .5) / pct(mb_ms, .5):.1f}x, "
          f"p99 {pct(ua_ms, .99) / pct(mb_ms, .99):.1f}x")


async def loop_cost(rounds: int) -> None:
    """The gateway's loop's share: each hand-over to the server's thread, timed in-process."""
    from ncgate.gateway import Gateway, load_config
    from ncgate.gateway.opcua import server as module

    config = load_config(None, overrides={"opcua.enabled": True, "opcua.port": 0,
                                          "modbus.port": 0, "canopen.enabled": False})
    costs: list[float] = []
    flush = module.OpcuaServer._flush
    sample = module.OpcuaServer._sample

    def timed_flush(self: Any) -> None:
        t0 = time.perf_counter()
        flush(self)
        costs.append((time.perf_counter() - t0) * 1e6)

    samples: list[float] = []

    def timed_sample(self: Any) -> None:
        t0 = time.perf_counter()
        sample(self)
        samples.append((time.perf_counter() - t0) * 1e6)
    module.OpcuaServer._flush = timed_flush  # type: ignore[method-assign]
    module.OpcuaServer._sample = timed_sample  # type: ignore[method-assign]
    async with Gateway(config) as gw:
        await gw.start()
        for i in range(rounds):
            gw.write("SA30", i % 2)
            gw.write("SYVAR5", i)
            await asyncio.sleep(0.001)
    print(f"hand-over on the gateway's loop (image + states, one per turn): p50 "
          f"{statistics.median(costs):.1f} us, p99 {pct(costs, .99):.1f} us, max "
          f"{max(costs):.1f} us over {len(costs)}")
    print(f"sampling every {module.SAMPLE_S * 1000:.0f} ms (5 processes, PLC): p50 "
          f"{statistics.median(samples):.1f} us, max {max(samples):.1f} us over {len(samples)}")


def abuse(uap: int, mb: int, clients: int, items: int, ready: Any, stop: Any) -> None:
    """The storm's load, in a process of its own: the image churned by Modbus, and
    ``clients`` OPC UA clients monitoring ``items`` nodes each."""
    import logging
    import struct

    from asyncua import Client, ua

    logging.getLogger("asyncua").setLevel(logging.CRITICAL)  # its disconnects at the end
    # The clients stand for dashboards on other machines: below everything else here, so that
    # the CPU they need on this one is not what the figures measure.
    os.nice(10)

    class Quiet:
        def datachange_notification(self, node: Any, value: Any, data: Any) -> None:
            pass

    async def main() -> None:
        sessions = []
        for _ in range(clients):
            client = Client(f"opc.tcp://127.0.0.1:{uap}/", timeout=60)
            await client.connect()
            ns = await client.get_namespace_index("urn:ncgate:image")
            names = ([f"SA{i}" for i in range(1024)] + [f"SK{i}" for i in range(512)]
                     + [f"SYVAR{i}" for i in range(256)])
            names = (names * 2)[:items]
            sub = await client.create_subscription(50, Quiet())
            await sub.subscribe_data_change([client.get_node(ua.NodeId(n, ns)) for n in names])
            sessions.append(client)
        reader, writer = await asyncio.open_connection("127.0.0.1", mb)
        ready.set()
        tid = 0
        while not stop.is_set():
            tid += 1
            values = [(tid + i) % 1000 for i in range(64)]
            pdu = struct.pack(">BHHB64H", 16, 1000, 64, 128, *values)  # SYVAR0..63 (map base)
            writer.write(struct.pack(">HHHB", tid & 0xFFFF, 0, len(pdu) + 1, 1) + pdu)
            await reader.readexactly(12)
            await asyncio.sleep(0.05)
        for client in sessions:
            with contextlib.suppress(Exception):
                await client.disconnect()
    asyncio.run(main())


async def storm_phase(clients: int, seconds: float) -> tuple[float, float, float, float]:
    """(poller p99 ms, PLC max lateness ms, the gateway's CPU share, the control's poller p99
    ms) with ``clients`` OPC UA clients of 2,000 items each.  The control is bench/storm.py's
    bare asyncio server in a process of its own, polled alike: what the machine's load does
    to any Python server."""
    import multiprocessing

    sys.path.insert(0, HERE)
    from storm import control_server, cpu_s, poller, wait_listening, write_cell

    spawn = multiprocessing.get_context("spawn")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        port, hub, web, uap = free_port(), free_port(), free_port(), free_port()
        config = write_cell(folder, port, hub, web)
        with config.open("a") as out:
            out.write(f"[opcua]\nenabled = true\nport = {uap}\n")
        gateway = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "ncgate", "run", "--config", str(config), "-q",
            stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL, cwd=tmp)
        control_port, control_ready = free_port(), spawn.Event()
        control = spawn.Process(target=control_server, args=(control_port, control_ready),
                                daemon=True)
        control.start()
        ready, stop_abuse = spawn.Event(), spawn.Event()
        load = spawn.Process(target=abuse, args=(uap, port, clients, 2000, ready, stop_abuse),
                             daemon=True)
        try:
            await wait_listening(port)
            await wait_listening(uap)
            load.start()
            await asyncio.to_thread(ready.wait, 300)
            stop = asyncio.Event()
            rtts: list[float] = []
            late: list[int] = []
            await asyncio.to_thread(control_ready.wait, 30)
            control_rtts: list[float] = []
            polling = asyncio.create_task(poller(port, stop, rtts, late))
            control_polling = asyncio.create_task(poller(control_port, stop, control_rtts, []))
            await asyncio.sleep(1.0)  # warm-up
            rtts.clear()
            late.clear()
            control_rtts.clear()
            cpu0, t0 = cpu_s(gateway.pid), time.perf_counter()
            await asyncio.sleep(seconds)
            cpu = (cpu_s(gateway.pid) - cpu0) / (time.perf_counter() - t0)
            stop.set()
            await polling
            await control_polling
        finally:
            control.terminate()
            stop_abuse.set()
            await asyncio.to_thread(load.join, 30)
            gateway.terminate()
            await gateway.wait()
    return pct(rtts, .99) * 1000, max(late, default=0) / 1000, cpu, pct(control_rtts, .99) * 1000


async def storm(seconds: float, rounds: int) -> None:
    """Quiet and storm phases in alternating rounds (a shared machine's load drifts); the
    median of each figure over the rounds."""
    runs: dict[str, list[tuple[float, float, float, float]]] = {"quiet": [], "storm": []}
    for _ in range(rounds):
        runs["quiet"].append(await storm_phase(0, seconds))
        runs["storm"].append(await storm_phase(10, seconds))
    quiet = [statistics.median(f[i] for f in runs["quiet"]) for i in range(4)]
    for name, label in (("quiet", "quiet"), ("storm", "10 clients x 2,000 items")):
        p99, late, cpu, control = (statistics.median(f[i] for f in runs[name])
                                   for i in range(4))
        print(f"storm, {label} (median of {rounds}): poller p99 {p99:.2f} ms "
              f"({p99 / quiet[0]:.2f}x quiet), PLC lateness max {late:.2f} ms "
              f"({late / max(quiet[1], 1e-3):.2f}x quiet), gateway CPU {100 * cpu:.0f} %; "
              f"the control's poller p99 {control:.2f} ms ({control / quiet[3]:.2f}x quiet)")


async def starts(n: int) -> None:
    from ncgate.gateway import Gateway
    from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

    times = []
    for _ in range(n):
        gw = Gateway(ncgate_test_config(**{
            "opcua.enabled": True, "opcua.port": 0, "canopen.enabled": False,
            "modbus.port": 0, "web.enabled": False}))
        t0 = time.perf_counter()
        try:
            await gw.__aenter__()
        except TimeoutError:
            times.append(float("inf"))  # (START_TIMEOUT_S)
            continue
        times.append(time.perf_counter() - t0)
        await gw.__aexit__(None, None, None)
    print(f"5. a start with [opcua], s: {' '.join(f'{t:.2f}' for t in times)} "
          f"(inf: START_TIMEOUT_S passed); load {os.getloadavg()[0]:.1f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=300)
    parser.add_argument("--storm", action="store_true", help="also the storm phases")
    parser.add_argument("--seconds", type=float, default=6.0, help="each storm phase")
    parser.add_argument("--storm-rounds", type=int, default=2, help="quiet/storm pairs")
    parser.add_argument("--starts", type=int, metavar="N", help="only: time N starts")
    args = parser.parse_args()
    sys.setswitchinterval(0.0002)  # as `ncgate run` has it (gateway/cli/main.py)
    if args.starts:
        asyncio.run(starts(args.starts))
        return 0
    asyncio.run(startup())
    asyncio.run(loop_cost(args.rounds))
    asyncio.run(latency(args.rounds))
    if args.storm:
        asyncio.run(storm(args.seconds, args.storm_rounds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
