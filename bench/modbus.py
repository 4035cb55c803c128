"""Modbus gateway speed and size (issue: the gateway over Modbus TCP).  Side by side:

1. read-holding-registers requests/s through the gateway vs a bare pymodbus ModbusTcpServer,
   each served by its own child process, both driven alternately by the same raw-socket
   load client (target: >= 0.9x of bare pymodbus);
2. latency from a client's FC5 / FC6 write to the waiting process resuming, measured inside
   the gateway (from the request's arrival to the resume) and end to end by the client (the
   write's answer leaves after the wake), p50 / p99 over >= 2,000 samples (target p99 <= 1 ms);
3. resident memory of `ncgate run` with the default config and 16 idle clients, beside a bare
   pymodbus server with 16 idle clients.

    python3 dev.py bench         # or: .venv/bin/python bench/modbus.py
"""

from __future__ import annotations

import asyncio
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CONNECTIONS = 4
SECONDS = 3.0
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


def start(kind: str) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen([sys.executable, __file__, "--serve", kind], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    return proc, int(proc.stdout.readline())


def stop(proc: subprocess.Popen[str]) -> None:
    assert proc.stdin is not None
    proc.stdin.close()
    proc.wait(timeout=10)


# -- 1. throughput ------------------------------------------------------------------------

REQUEST = struct.pack(">HHHBBHH", 0, 0, 6, 1, 3, 0, 10)  # FC3, holding 0..9


async def load(port: int, seconds: float) -> int:
    async def one() -> int:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        done = 0
        deadline = time.perf_counter() + seconds
        while time.perf_counter() < deadline:
            writer.write(REQUEST)
            header = await reader.readexactly(7)
            body = await reader.readexactly(struct.unpack(">H", header[4:6])[0] - 1)
            assert body[0] == 3, body
            done += 1
        writer.close()
        return done

    return sum(await asyncio.gather(*(one() for _ in range(CONNECTIONS))))


def throughput() -> None:
    ours, ours_port = start("gateway")
    bare, bare_port = start("pymodbus")
    try:
        rates: dict[str, list[float]] = {"gateway": [], "pymodbus": []}
        for _ in range(ROUNDS):  # alternate, so both see the same machine
            for name, port in (("gateway", ours_port), ("pymodbus", bare_port)):
                rates[name].append(asyncio.run(load(port, SECONDS)) / SECONDS)
    finally:
        stop(ours)
        stop(bare)
    g, b = max(rates["gateway"]), max(rates["pymodbus"])
    print(f"1. FC3 read 10 registers, {CONNECTIONS} connections: gateway {g:,.0f} req/s, "
          f"bare pymodbus {b:,.0f} req/s; ratio {g / b:.2f}x   (target >= 0.9x)")


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
        run = subprocess.Popen([sys.executable, "-m", "ncgate", "run", "--config", str(config)],
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


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--serve":
        asyncio.run(serve_gateway() if sys.argv[2] == "gateway" else serve_pymodbus())
    else:
        throughput()
        asyncio.run(latency())
        memory()
