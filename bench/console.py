"""The web console under load (issue: the commissioning console).  Side by side, in this script:

A cell makes about 1,500 events a second (P1 and P2 in an SND/WAI loop with an 8 ms
dwell) while P3 waits alternately for SA10 and SK3 and a Modbus client on loopback releases
each wait 200 times a second (as bench/modbus.py measures it).  Two variants, alternated for
``--rounds``:

- *without* the console;
- *with* the console and ``--clients`` browser-like stream clients (another process: aiohttp
  clients reading /api/stream and parsing every event, as the page does).

Printed: the event rate; for the streams, the delay from an event's recording in the gateway to
its arrival in each client, p50 / p99 over every event and client (target p99 <= 100 ms); the
Modbus write -> resume time inside the gateway, p50 / p99, with and without the console and
their ratio (target <= 1.2x); and the gateway's resident memory at the end of the warm-up and
at the end of the console run (target: flat, <= 1.10x).

    .venv/bin/python bench/console.py                 # 3 rounds of 10 s
    .venv/bin/python bench/console.py --seconds 120 --rounds 1

Measured on the 2-core CI machine: at this load the write -> resume p99 ratio is about 1.1x;
at 2,500 events/s (500 writes/s, a 5 ms dwell) it was 1.27x -- the stream clients' process
then takes a core's worth of the two.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MAIN = ('(EXE,2,PEER)\n(EXE,3,LOOP)\n"L"\nN1(SND,2)\nN2(WAI,2)\nN3(DLY,0.008)\n'
        'N4(BNC,L)\n')
PEER = '"L"\nN1(WAI,1)\nN2(SND,1)\nN3(BNC,L)\n'
LOOP = '"L"\nN1(WAI,SA10=1)\nN2(WAI,SK3=0)\nN3(WAI,SA10=0)\nN4(WAI,SK3=1)\nN5(BNC,L)\n'
WRITES = [struct.pack(">HHHBBHH", 0, 0, 6, 1, 5, 10, 0xFF00),
          struct.pack(">HHHBBHH", 0, 0, 6, 1, 6, 3, 0),
          struct.pack(">HHHBBHH", 0, 0, 6, 1, 5, 10, 0),
          struct.pack(">HHHBBHH", 0, 0, 6, 1, 6, 3, 1)]
WRITE_EVERY_S = 0.005  # one Modbus write every 5 ms (200/s)


def rss_kib() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def p(values: list[float], q: int) -> float:
    return statistics.quantiles(values, n=100)[q - 1] * 1000.0  # ms


# -- the stream clients (a child process) ---------------------------------------------------

async def clients(url: str, count: int) -> None:
    """``count`` streams; on stdin's end, print every (seq, arrival) as JSON and stop."""
    import aiohttp

    arrivals: list[list[tuple[int, float]]] = [[] for _ in range(count)]

    async def one(i: int, session: aiohttp.ClientSession) -> None:
        async with session.get(url + "api/stream") as r:
            event, data = "", ""
            async for raw in r.content:
                line = raw.decode()
                if line.startswith("event: "):
                    event = line[7:].strip()
                elif line.startswith("data: "):
                    data = line[6:]
                elif line == "\n" and event == "events":
                    now = time.time()
                    for e in json.loads(data)["events"]:  # parsed, as the page does
                        arrivals[i].append((e["seq"], now))

    async with aiohttp.ClientSession() as session:
        tasks = [asyncio.create_task(one(i, session)) for i in range(count)]
        print("connected", flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    print(json.dumps(arrivals), flush=True)


# -- the gateway and the load (this process) ------------------------------------------------

async def variant(folder: Path, seconds: float, console: bool, streams: int
                  ) -> dict[str, object]:
    from ncgate.gateway import Gateway, load_config
    from ncgate.gateway.modbus.server import _Connection

    recorded: dict[int, float] = {}
    arrivals: list[float] = []
    resumes: list[float] = []
    original = _Connection.data_received

    def timed(self: _Connection, data: bytes) -> None:
        arrivals.append(time.perf_counter())
        original(self, data)

    def listen(e: object) -> None:
        recorded[e.seq] = time.time()  # type: ignore[attr-defined]
        if e.kind == "resume" and e.proc == 3:  # type: ignore[attr-defined]
            resumes.append(time.perf_counter())

    config = load_config(folder / "ncgate.toml", overrides={"web.port": 0})
    _Connection.data_received = timed  # type: ignore[method-assign]
    child = None
    try:
        async with Gateway(config, listeners=[listen], console=console) as gw:
            if console:
                child = await asyncio.create_subprocess_exec(
                    sys.executable, __file__, "--stream-clients", str(streams), "--url",
                    gw.web_console.url if gw.web_console else "",
                    stdin=subprocess.PIPE, stdout=subprocess.PIPE)
                assert child.stdout is not None
                assert (await child.stdout.readline()).strip() == b"connected"
            gw.write("SK3", 1)
            await gw.start()
            reader, writer = await asyncio.open_connection(*gw.modbus_address)
            warm = time.perf_counter() + min(2.0, seconds / 4)
            end = time.perf_counter() + seconds
            rss_warm = 0
            seq_warm = 0
            arrivals.clear()
            resumes.clear()
            i = 0
            loop = asyncio.get_running_loop()
            while time.perf_counter() < end:
                if not rss_warm and time.perf_counter() >= warm:
                    rss_warm, seq_warm, t_warm = rss_kib(), gw.runtime.trace.seq, loop.time()
                    arrivals.clear()
                    resumes.clear()
                writer.write(WRITES[i % 4])
                await reader.readexactly(12)
                i += 1
                await asyncio.sleep(WRITE_EVERY_S)  # the load's pace, not a wait for a result
            rate = (gw.runtime.trace.seq - seq_warm) / (loop.time() - t_warm)
            rss_end = rss_kib()
            writer.close()
            await writer.wait_closed()
            inside = [r - a for a, r in zip(arrivals, resumes, strict=False)]
            out: dict[str, object] = {"rate": rate, "inside": inside, "rss": (rss_warm, rss_end)}
            if child is not None:
                assert child.stdin is not None and child.stdout is not None
                child.stdin.close()
                data = json.loads(await child.stdout.read())
                await child.wait()
                delays = [at - recorded[seq] for stream in data for seq, at in stream
                          if seq in recorded]
                out["delays"] = delays
                out["received"] = sum(len(s) for s in data)
            return out
    finally:
        _Connection.data_received = original  # type: ignore[method-assign]


async def bench(seconds: float, rounds: int, streams: int) -> None:
    folder = Path(tempfile.mkdtemp())
    for name, text in (("MAIN", MAIN), ("PEER", PEER), ("LOOP", LOOP)):
        (folder / f"{name}.nc").write_text(text)
    (folder / "ncgate.toml").write_text(
        '[nc]\nmain = "MAIN"\n[nc.storage]\nMP0 = "."\n[modbus]\nport = 0\n'
        '[canopen]\nenabled = false\n[trace]\nring = 10000\n')
    without: list[float] = []
    with_console: list[float] = []
    delays: list[float] = []
    rates = []
    rss = (0, 0)
    for r in range(rounds):
        a = await variant(folder, seconds, False, streams)
        b = await variant(folder, seconds, True, streams)
        without += a["inside"]  # type: ignore[arg-type]
        with_console += b["inside"]  # type: ignore[arg-type]
        delays += b["delays"]  # type: ignore[arg-type]
        rates.append((a["rate"], b["rate"]))
        rss = b["rss"]  # type: ignore[assignment]
        print(f"round {r + 1}: {a['rate']:.0f} / {b['rate']:.0f} sync events/s without / with "
              f"the console; {b['received']} events received by {streams} streams", flush=True)
    print(f"streams: {streams} clients, event -> client delay over {len(delays)} deliveries: "
          f"p50 {p(delays, 50):.1f} ms, p99 {p(delays, 99):.1f} ms   (target p99 <= 100 ms)")
    p99a, p99b = p(without, 99), p(with_console, 99)
    print(f"Modbus write -> resume inside the gateway: without the console p50 "
          f"{p(without, 50) * 1000:.0f} us, p99 {p99a * 1000:.0f} us; with it p50 "
          f"{p(with_console, 50) * 1000:.0f} us, p99 {p99b * 1000:.0f} us; ratio "
          f"{p99b / p99a:.2f}x   (target <= 1.2x)")
    print(f"memory (VmRSS) with the console: {rss[0]} KiB after the warm-up, {rss[1]} KiB at "
          f"the end: {rss[1] / max(rss[0], 1):.3f}x   (target <= 1.10x)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--clients", type=int, default=10)
    parser.add_argument("--stream-clients", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.stream_clients:
        asyncio.run(clients(args.url, args.stream_clients))
        return
    print(f"bench/console.py: pid {os.getpid()}, {args.rounds} rounds of {args.seconds:g} s")
    asyncio.run(bench(args.seconds, args.rounds, args.clients))


if __name__ == "__main__":
    main()
