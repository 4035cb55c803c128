"""Memory of `ncgate run` under load (issue: the house -- bounded memory, whatever the load).

Runs `ncgate run` as its own process with a cell whose two processes run an SND/WAI loop with a
10 ms dwell (autostarted; ``--time-scale`` makes it faster), and drives its Modbus server with
clients on loopback for ``--seconds``: FC16 (8 registers) and FC5 writes, half of them
changing values and half writing what is already there, pipelined, every client reconnecting
every ``--reconnect-s`` seconds.  It samples the server's resident memory (VmRSS) every
``--sample-s`` seconds and prints the curve, the write rate, and the ratio of the last sample to
the sample at the end of the warm-up (target: within 10 %, i.e. <= 1.10x).

    python3 dev.py bench                     # every benchmark, this one for 180 s
    .venv/bin/python bench/memory.py --seconds 600
    .venv/bin/python bench/memory.py --plc   # the same with PLC logic scanning (a RETAIN
                                             # save and image writes every scan)
    .venv/bin/python bench/memory.py --isg   # the ISG dialect: a channel signalling itself,
                                             # broadcasting and removing, 10 ms of motion
    # the same load against another checkout (e.g. the code before the ring):
    PYTHONPATH=/path/to/old .venv/bin/python bench/memory.py --module gateway
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import struct
import sys
import tempfile
import time
from pathlib import Path

# P1 starts P2, then both loop: P1 sends, waits for the answer, dwells 10 ms.
MAIN = '(EXE,2,PEER)\n"L"\nN1(SND,2)\nN2(WAI,2)\nN3(DLY,0.01)\nN4(BNC,L)\n'
PEER = '"L"\nN1(WAI,1)\nN2(SND,1)\nN3(BNC,L)\n'


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# --plc: ST logic that writes the image and a RETAIN value on every scan (a save per scan).
LOGIC = """PROGRAM load
VAR t : ARRAY[0..9] OF TON; i : INT; END_VAR
VAR RETAIN scans : DINT; END_VAR
scans := scans + 1;
FOR i := 0 TO 9 DO t[i](IN := NOT t[i].Q, PT := T#50ms); SA[900 + i] := t[i].Q; END_FOR
SK[400] := DINT_TO_BYTE(scans);
SYVAR[200] := DINT_TO_INT(scans MOD 30000);
END_PROGRAM
"""


# --isg: one channel (cycle start starts channel 1 only) stores and consumes a directed signal,
# a broadcast and a SYN signal every 10 ms of motion, and removes the broadcasts.
ISG = """%channel1
$WHILE 1
#SIGNAL [ID1 P[0]=7 CH1]
#SIGNAL [ID9]
#SIGNAL SYN [ID2 CH1]
G91 G01 X1 F6000
#WAIT [ID1 P[0]=P1 CH1]
#FLUSH
#WAIT [ID2 CH1]
#SIGNAL REMOVE [ID9]
$ENDWHILE
"""


def write_cell(folder: Path, port: int, time_scale: float, plc: bool = False,
               isg: bool = False) -> Path:
    (folder / "LOOP.nc").write_text(ISG if isg else MAIN)
    (folder / "PEER.nc").write_text(PEER)
    config = folder / "ncgate.toml"
    dialect = 'dialect = "isg"\n' if isg else ""
    logic = ""
    if plc:
        (folder / "load.st").write_text(LOGIC)
        logic = '[plc]\nlogic = "load.st"\n'
    config.write_text(f'[nc]\n{dialect}main = "LOOP"\nautostart = true\n'
                      f'time_scale = {time_scale}\n'
                      f'[nc.storage]\nMP0 = "."\n[modbus]\nport = {port}\nmax_clients = 64\n'
                      f'[canopen]\nchannel = "bench-memory-{os.getpid()}"\n{logic}')
    return config


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("no VmRSS")


def frames(client: int) -> list[bytes]:
    """A cycle of requests: FC16 changing, FC16 unchanging, FC5 changing, FC5 unchanging."""
    out = []
    for i in range(64):
        changing = struct.pack(">8H", *((i * 7 + k + client) % 256 for k in range(8)))
        same = struct.pack(">8H", *range(8))
        base = 8 * (client % 8)
        out.append(bytes([0x10]) + struct.pack(">HHB", 100 + base, 8, 16) + changing)
        out.append(bytes([0x10]) + struct.pack(">HHB", 200 + base, 8, 16) + same)
        out.append(bytes([0x05]) + struct.pack(">HH", 100 + client, 0xFF00 if i % 2 else 0))
        out.append(bytes([0x05]) + struct.pack(">HH", 200 + client, 0xFF00))
    return out


async def client_loop(port: int, client: int, until: float, reconnect_s: float,
                      counts: list[int], window: int = 32) -> None:
    pdus = frames(client)
    tid = 0
    while time.perf_counter() < until:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        session_end = min(until, time.perf_counter() + reconnect_s)
        try:
            while time.perf_counter() < session_end:
                batch = []
                for _ in range(window):
                    pdu = pdus[tid % len(pdus)]
                    tid = (tid + 1) & 0xFFFF
                    batch.append(struct.pack(">HHHB", tid, 0, len(pdu) + 1, 1) + pdu)
                writer.write(b"".join(batch))
                for _ in range(window):
                    header = await reader.readexactly(7)
                    body = await reader.readexactly(struct.unpack(">H", header[4:6])[0] - 1)
                    if body[0] & 0x80:
                        raise RuntimeError(f"exception answer {body.hex()}")
                counts[0] += window
        finally:
            writer.close()
            await writer.wait_closed()


async def snds_sent(port: int, process: int) -> int:
    """Input registers 100+20(k-1)+6, 7: the SNDs process k sent (u32, spec 3.2)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(struct.pack(">HHHBBHH", 1, 0, 6, 1, 4, 100 + 20 * (process - 1) + 6, 2))
        header = await reader.readexactly(7)
        body = await reader.readexactly(struct.unpack(">H", header[4:6])[0] - 1)
        return int(struct.unpack(">I", body[2:6])[0])
    finally:
        writer.close()
        await writer.wait_closed()


async def wait_listening(port: int, deadline_s: float = 30.0) -> None:
    end = time.perf_counter() + deadline_s
    while True:
        try:
            _, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.close()
            await writer.wait_closed()
            return
        except OSError:
            if time.perf_counter() > end:
                raise
            await asyncio.sleep(0.1)  # the server process is starting: nothing to wait on


async def run(args: argparse.Namespace) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        config = write_cell(Path(tmp), port, args.time_scale, plc=args.plc, isg=args.isg)
        server = await asyncio.create_subprocess_exec(
            sys.executable, "-m", args.module, "run", "--config", str(config),
            stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL)
        try:
            await wait_listening(port)
            start_kib = rss_kib(server.pid)
            counts = [0]
            t0 = time.perf_counter()
            until = t0 + args.seconds
            clients = [asyncio.create_task(client_loop(port, c, until, args.reconnect_s,
                                                       counts))
                       for c in range(args.clients)]
            samples: list[tuple[float, int, int]] = []
            while time.perf_counter() < until:
                await asyncio.sleep(args.sample_s)  # the sampling period is the point here
                samples.append((time.perf_counter() - t0, rss_kib(server.pid), counts[0]))
            await asyncio.gather(*clients)
            elapsed = time.perf_counter() - t0
            round_trips = await snds_sent(port, process=1)
        finally:
            server.terminate()
            await server.wait()
    warm = next((s for s in samples if s[0] >= args.warmup_s), samples[0])
    middle = samples[len(samples) // 2]
    end = samples[-1]
    print(f"load: {counts[0]:,} writes in {elapsed:.0f} s = {counts[0] / elapsed:,.0f} "
          f"writes/s (FC16 x8 + FC5, half changing), {args.clients} clients reconnecting "
          f"every {args.reconnect_s:g} s; {'#SIGNAL/#WAIT' if args.isg else 'SND/WAI'} loop "
          f"with 10 ms of {'motion' if args.isg else 'dwell'} at time_scale "
          f"{args.time_scale:g}: {round_trips:,} {'signals' if args.isg else 'round trips'}")
    print("RSS curve (s: MiB): " + ", ".join(f"{t:.0f}: {kib / 1024:.1f}"
                                              for t, kib, _ in samples))
    print(f"RSS: start {start_kib / 1024:.1f} MiB, after warm-up ({warm[0]:.0f} s) "
          f"{warm[1] / 1024:.1f} MiB, middle ({middle[0]:.0f} s) {middle[1] / 1024:.1f} MiB, "
          f"end ({end[0]:.0f} s) {end[1] / 1024:.1f} MiB; end / warm-up = "
          f"{end[1] / warm[1]:.3f}x   (target <= 1.10x)")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=180.0)
    parser.add_argument("--warmup-s", type=float, default=30.0)
    parser.add_argument("--sample-s", type=float, default=10.0)
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--reconnect-s", type=float, default=2.0)
    parser.add_argument("--time-scale", type=float, default=10.0)
    parser.add_argument("--module", default="ncgate", help="python -m MODULE run")
    parser.add_argument("--plc", action="store_true", help="with PLC logic scanning every "
                        "10 ms, writing the image and a RETAIN value each scan")
    parser.add_argument("--isg", action="store_true", help="the ISG dialect: signals stored, "
                        "consumed, broadcast and removed every 10 ms")
    return asyncio.run(run(parser.parse_args()))


if __name__ == "__main__":
    sys.exit(main())
