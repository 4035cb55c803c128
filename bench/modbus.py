"""Modbus gateway speed and size (issue: the gateway over Modbus TCP).  Side by side:

1. read-holding-registers requests/s with 1, 4 and 16 connections through the gateway (on
   asyncio's loop, and on uvloop when it is installed), a libmodbus server in C built here
   (bench/c, needs libmodbus-dev), a bare pymodbus ModbusTcpServer and a bare asyncio
   Protocol that answers a packed constant on uvloop (the floor of any Python server on that
   loop: with one connection a server is as fast as its loop's round trip), each in its own
   process, driven alternately by the same C load client (bench/c/load_client.c: one thread,
   one request in flight per connection); ratios to libmodbus (target: >= 0.8x with 16
   connections, >= 1.0x with 1);
2. latency from a client's FC5 / FC6 write to the waiting process resuming, measured inside
   the gateway (from the request's arrival to the resume) and end to end by the client (the
   write's answer leaves after the wake), p50 / p99 over >= 2,000 samples (target p99 <= 1 ms);
3. resident memory of `ncgate run` with the default config and 16 idle clients, beside a bare
   pymodbus server with 16 idle clients;
4. the server's own CPU time per FC3 request, in process (a connection's data_received on a
   transport that drops what it is given), one whole request a segment and 16 pipelined,
   beside a bare asyncio Protocol that unpacks the MBAP header and answers a packed constant:
   process time, so that the load of a shared machine moves it far less than it moves 1.
   (on a 2-core machine at load 2-7, 1.'s ratios varied by 0.2 for the same code);
5. Modbus RTU over a pty pair (socat): FC3 requests/s from a libmodbus RTU master
   (bench/c/rtu.c, one request in flight) to the gateway's RTU server and to libmodbus's RTU
   server on the same setup, alternately, as a ratio (target: >= 0.8x).

    python3 dev.py bench         # or: .venv/bin/python bench/modbus.py [throughput|cpu|rtu]
"""

from __future__ import annotations

import asyncio
import importlib.util
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import cast

SECONDS = 2.0
ROUNDS = 3


# -- the servers, each in a child process ----------------------------------------------------

async def serve_gateway() -> None:
    from ncgate.gateway import Gateway, load_config

    async with Gateway(load_config(None, overrides={"modbus.port": 0})) as gw:
        print(gw.modbus_address[1], flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)


async def serve_pymodbus() -> None:
    from pymodbus.server import ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice

    device = SimDevice(id=1, simdata=[SimData(address=0, count=2100, values=0,
                                              datatype=DataType.REGISTERS)])
    server = ModbusTcpServer(device, address=("127.0.0.1", 0))
    await server.serve_forever(background=True)
    transport = server.transport
    port = transport.sockets[0].getsockname()[1]  # type: ignore[union-attr]
    print(port, flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    await server.shutdown()


class _Constant(asyncio.Protocol):
    """The least a Python server does for a poller: unpack the header, answer a constant."""

    HEADER = struct.Struct(">HHHB")
    ANSWER = bytes.fromhex("03 14") + bytes(20)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)

    def data_received(self, data: bytes) -> None:
        tid, _, _, unit = self.HEADER.unpack_from(data)
        self.transport.write(self.HEADER.pack(tid, 0, len(self.ANSWER) + 1, unit) + self.ANSWER)


async def serve_bare() -> None:
    server = await asyncio.get_running_loop().create_server(_Constant, "127.0.0.1", 0)
    print(server.sockets[0].getsockname()[1], flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    server.close()


def start(kind: str) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen([sys.executable, __file__, "--serve", kind], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    return proc, int(proc.stdout.readline())


def stop(proc: subprocess.Popen[str]) -> None:
    assert proc.stdin is not None
    proc.stdin.close()
    proc.wait(timeout=10)


# -- 1. throughput ------------------------------------------------------------------------

REQUEST = struct.pack(">HHHBBHH", 0, 0, 6, 1, 3, 0, 10)  # FC3, holding 0..9
C_DIR = Path(__file__).resolve().parent / "c"


def build_c(folder: Path) -> tuple[Path, Path] | None:
    """The libmodbus server and the load client, compiled here; None without libmodbus-dev."""
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "libmodbus"],
                           capture_output=True, text=True)
    if flags.returncode != 0 or shutil.which("cc") is None:
        return None
    server, client = folder / "libmodbus_server", folder / "load_client"
    subprocess.run(["cc", "-O2", "-o", str(server), str(C_DIR / "libmodbus_server.c"),
                    *flags.stdout.split()], check=True)
    subprocess.run(["cc", "-O2", "-o", str(client), str(C_DIR / "load_client.c")], check=True)
    return server, client


def start_c(server: Path) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen([str(server)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout is not None
    return proc, int(proc.stdout.readline())


def load_c(client: Path, port: int, connections: int, seconds: float) -> float:
    out = subprocess.run([str(client), str(port), str(connections), str(seconds)],
                         capture_output=True, text=True, check=True)
    return int(out.stdout) / seconds


def throughput() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        built = build_c(Path(tmp))
        if built is None:
            print("1. FC3 throughput: skipped -- needs a C compiler and libmodbus-dev "
                  "(apt-get install libmodbus-dev)")
            return
        c_server, client = built
        kinds = ["gateway", "libmodbus", "pymodbus"]
        if importlib.util.find_spec("uvloop") is not None:
            kinds.insert(1, "gateway-uvloop")
            kinds.append("bare-uvloop")
        servers = {kind: start_c(c_server) if kind == "libmodbus" else start(kind)
                   for kind in kinds}
        try:
            for connections in (1, 4, 16):
                rates: dict[str, list[float]] = {kind: [] for kind in kinds}
                for _ in range(ROUNDS):  # alternate, so all see the same machine
                    for kind in kinds:
                        rates[kind].append(load_c(client, servers[kind][1], connections,
                                                  SECONDS))
                best = {kind: max(r) for kind, r in rates.items()}
                c = best["libmodbus"]
                row = ", ".join(f"{kind} {rate:,.0f} ({rate / c:.2f}x)"
                                for kind, rate in best.items())
                print(f"1. FC3 read 10 registers, {connections:2d} connection(s), req/s "
                      f"(x libmodbus): {row}")
        finally:
            for proc, _ in servers.values():
                stop(proc)
    print("   target: gateway >= 0.8x libmodbus with 16 connections, >= 1.0x with 1 (the same C "
          "load client drives every server; bare-uvloop: a Protocol answering a constant)")

# -- 2. write -> wake latency ---------------------------------------------------------------

SAMPLES = 2500
LOOP = '"L"\nN1(WAI,SA10=1)\nN2(WAI,SK3=0)\nN3(WAI,SA10=0)\nN4(WAI,SK3=1)\nN5(BNC,L)\n'


async def latency() -> None:
    from ncgate.gateway import Gateway, load_config
    from ncgate.gateway.modbus.server import _Connection

    folder = Path(tempfile.mkdtemp())
    (folder / "LOOP.nc").write_text(LOOP)
    (folder / "ncgate.toml").write_text('[nc]\nmain = "LOOP"\n[modbus]\nport = 0\n')
    arrivals: list[float] = []
    resumes: list[float] = []
    original = _Connection.data_received

    def timed(self: _Connection, data: bytes) -> None:
        arrivals.append(time.perf_counter())
        original(self, data)

    _Connection.data_received = timed  # type: ignore[method-assign]
    try:
        async with Gateway(load_config(folder / "ncgate.toml"),
                           listeners=[lambda e: resumes.append(time.perf_counter())
                                      if e.kind == "resume" else None]) as gw:
            await gw.start()
            reader, writer = await asyncio.open_connection(*gw.modbus_address)
            e2e: list[float] = []
            # FC5 on SA10, FC6 on SK3, alternately: each write releases the wait it meets.
            writes = [struct.pack(">HHHBBHH", 0, 0, 6, 1, 5, 10, 0xFF00),
                      struct.pack(">HHHBBHH", 0, 0, 6, 1, 6, 3, 0),
                      struct.pack(">HHHBBHH", 0, 0, 6, 1, 5, 10, 0),
                      struct.pack(">HHHBBHH", 0, 0, 6, 1, 6, 3, 1)]
            gw.write("SK3", 1)
            arrivals.clear()
            resumes.clear()
            for i in range(SAMPLES):
                start_t = time.perf_counter()
                writer.write(writes[i % 4])
                await reader.readexactly(12)
                e2e.append(time.perf_counter() - start_t)
            writer.close()
    finally:
        _Connection.data_received = original  # type: ignore[method-assign]
    inside = [r - a for a, r in zip(arrivals, resumes, strict=False)]
    assert len(inside) == SAMPLES, (len(arrivals), len(resumes))

    def p(values: list[float], q: int) -> float:
        return statistics.quantiles(values, n=100)[q - 1] * 1e6

    print(f"2. write -> resume, {SAMPLES} samples: inside the gateway p50 {p(inside, 50):.0f} us, "
          f"p99 {p(inside, 99):.0f} us; end to end (client) p50 {p(e2e, 50):.0f} us, "
          f"p99 {p(e2e, 99):.0f} us   (target p99 <= 1000 us)")


# -- 3. memory -------------------------------------------------------------------------------

def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("no VmRSS")


def memory() -> None:
    import socket

    def with_clients(proc: subprocess.Popen[str], port: int) -> int:
        clients = [socket.create_connection(("127.0.0.1", port)) for _ in range(16)]
        for c in clients:  # each one answered: the server holds 16 live connections
            c.sendall(REQUEST)
            assert c.recv(64)[7] == 3
        rss = rss_kib(proc.pid)
        for c in clients:
            c.close()
        return rss

    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "ncgate.toml"
        config.write_text("[modbus]\nport = 0\n")  # the default config, on a free port
        # --allow-missing: the bench serves Modbus only; its folder holds no PROG91.
        run = subprocess.Popen([sys.executable, "-m", "ncgate", "run", "--config", str(config),
                                "--allow-missing"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert run.stdout is not None
        port = 0
        for line in run.stdout:
            if "Modbus TCP on" in line:
                port = int(line.split("Modbus TCP on ")[1].split(",")[0].rsplit(":", 1)[1])
                break
        try:
            ours = with_clients(run, port)
        finally:
            run.terminate()
            run.wait(timeout=10)
    bare, bare_port = start("pymodbus")
    try:
        theirs = with_clients(bare, bare_port)
    finally:
        stop(bare)
    print(f"3. resident memory with 16 idle clients: ncgate run {ours / 1024:.1f} MiB, bare "
          f"pymodbus server {theirs / 1024:.1f} MiB; ratio {ours / theirs:.2f}x")


# -- 4. CPU per request ----------------------------------------------------------------------

CPU_REQUESTS = 32_000
CPU_ROUNDS = 7


class _Sink(asyncio.Transport):
    """A transport that takes every answer and sends nothing."""

    def write(self, data: bytes | bytearray | memoryview) -> None:
        pass

    def is_closing(self) -> bool:
        return False

    def get_extra_info(self, name: str, default: object = None) -> object:
        return ("127.0.0.1", 1) if name == "peername" else default

    def get_write_buffer_size(self) -> int:
        return 0

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        pass

    def pause_reading(self) -> None:
        pass

    def resume_reading(self) -> None:
        pass


class _Bare(asyncio.Protocol):
    """The least a Python Modbus server does for a poller: unpack, answer."""

    HEADER = struct.Struct(">HHHB")
    ANSWER = bytes.fromhex("03 14") + bytes(20)

    def __init__(self, transport: asyncio.Transport) -> None:
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        tid, _, length, unit = self.HEADER.unpack_from(data)
        for at in range(0, len(data), 6 + length):  # whole frames of one length here
            tid, _, length, unit = self.HEADER.unpack_from(data, at)
            self.transport.write(self.HEADER.pack(tid, 0, len(self.ANSWER) + 1, unit)
                                 + self.ANSWER)


async def cpu() -> None:
    from ncgate.gateway import Gateway, load_config
    from ncgate.gateway.modbus.server import _Connection

    def per_request(feed: Callable[[bytes], None], data: bytes, settle: Callable[[], None]
                    ) -> float:
        frames = len(data) // len(REQUEST)
        times = []
        for _ in range(CPU_ROUNDS):
            began = time.process_time()
            for _ in range(CPU_REQUESTS // frames):
                feed(data)
                settle()
            times.append((time.process_time() - began) / CPU_REQUESTS)
        return min(times)

    async with Gateway(load_config(None, overrides={"modbus.port": 0})) as gw:
        assert gw.modbus_server is not None
        ours = _Connection(gw.modbus_server)
        ours.connection_made(_Sink())
        bare = _Bare(_Sink())

        def turns() -> None:  # the turns a pipelined burst is answered in, run here
            while ours.turn is not None:
                ours.turn.cancel()
                ours._process()

        for label, data in (("one request a segment", REQUEST),
                            ("16 pipelined", REQUEST * 16)):
            gateway_s = bare_s = float("inf")
            for _ in range(3):  # alternate, so both see the same machine
                gateway_s = min(gateway_s, per_request(ours.data_received, data, turns))
                bare_s = min(bare_s, per_request(bare.data_received, data, lambda: None))
            print(f"4. CPU per FC3 request, {label}: gateway {gateway_s * 1e6:.2f} us, bare "
                  f"Protocol {bare_s * 1e6:.2f} us; ratio {gateway_s / bare_s:.2f}x")
        ours.connection_lost(None)


# -- 5. Modbus RTU over a pty pair -----------------------------------------------------------

async def serve_gateway_rtu(device: str) -> None:
    from ncgate.gateway import Gateway, load_config

    # The built-in cell, as 1. serves it (its PLC, its CANopen node), without the console.
    config = load_config(None, overrides={"modbus.port": 0, "modbus.rtu.port": device,
                                          "web.enabled": False})
    async with Gateway(config):
        print("ready", flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)


def rtu() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        flags = subprocess.run(["pkg-config", "--cflags", "--libs", "libmodbus"],
                               capture_output=True, text=True)
        if flags.returncode != 0 or shutil.which("socat") is None:
            print("5. RTU: skipped -- needs socat and libmodbus-dev")
            return
        binary = folder / "rtu"
        subprocess.run(["cc", "-O2", "-o", str(binary), str(C_DIR / "rtu.c"),
                        *flags.stdout.split()], check=True)
        rates: dict[str, list[float]] = {"gateway": [], "libmodbus": []}
        for _ in range(ROUNDS + 2):  # a pty pair's rate swings with the machine: more rounds
            for kind in rates:
                a, b = str(folder / "ttyA"), str(folder / "ttyB")
                relay = subprocess.Popen(["socat", "-d", "-d", f"pty,raw,echo=0,link={a}",
                                          f"pty,raw,echo=0,link={b}"],
                                         stderr=subprocess.PIPE, text=True)
                assert relay.stderr is not None
                for line in relay.stderr:
                    if "starting data transfer loop" in line:
                        break
                command = ([sys.executable, __file__, "--serve-rtu", a] if kind == "gateway"
                           else [str(binary), "server", a])
                server = subprocess.Popen(command, stdin=subprocess.PIPE,
                                          stdout=subprocess.PIPE, text=True)
                assert server.stdout is not None
                server.stdout.readline()  # "ready"
                # Half a second of warm-up, unmeasured, for both (one client: socat ends the
                # pair when its end is closed): the first requests after a start pay for
                # cold caches and the gateway's first scans (a cold round measured 0.6x).
                out = subprocess.run([str(binary), "load", b, str(SECONDS), "0.5"],
                                     capture_output=True, text=True, check=True)
                answers, errors = map(int, out.stdout.split())
                rates[kind].append(answers / SECONDS if not errors else 0.0)
                server.kill()
                server.wait()
                relay.terminate()
                relay.wait()
        best = {kind: max(r) for kind, r in rates.items()}
        c = best["libmodbus"]
        print(f"5. RTU over a pty pair, FC3 read 10 registers, req/s: gateway "
              f"{best['gateway']:,.0f} ({best['gateway'] / c:.2f}x libmodbus), libmodbus "
              f"{c:,.0f}; every round: {rates}")
    print("   target: gateway >= 0.8x libmodbus's RTU server (the same libmodbus master, the "
          "same socat relay)")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--serve":
        if sys.argv[2] == "gateway-uvloop":
            import uvloop

            uvloop.run(serve_gateway())
        elif sys.argv[2] == "bare-uvloop":
            import uvloop

            uvloop.run(serve_bare())
        else:
            asyncio.run(serve_gateway() if sys.argv[2] == "gateway" else serve_pymodbus())
    elif sys.argv[1:] == ["throughput"]:
        throughput()
    elif len(sys.argv) == 3 and sys.argv[1] == "--serve-rtu":
        if importlib.util.find_spec("uvloop") is not None:  # as `ncgate run` takes it
            import uvloop

            uvloop.run(serve_gateway_rtu(sys.argv[2]))
        else:
            asyncio.run(serve_gateway_rtu(sys.argv[2]))
    elif sys.argv[1:] == ["cpu"]:
        asyncio.run(cpu())
    elif sys.argv[1:] == ["rtu"]:
        rtu()
    else:
        throughput()
        asyncio.run(latency())
        memory()
        asyncio.run(cpu())
        rtu()
