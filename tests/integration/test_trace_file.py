"""The trace of `ncgate run` on disk: whole lines, rotation with a size cap, every event; and
in memory only a window of it (the gateway runs for a shift)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

from ncgate.gateway import Gateway, load_config
from ncgate.gateway.tracefile import TraceFile
from ncgate.inputs import Source, SourceKind
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.trace import Trace

from ..conftest import EXAMPLES

TEST_PLC = Source(SourceKind.API, "test PLC")


def lines_of(*paths: Path) -> list[dict[str, object]]:
    out = []
    for path in paths:
        text = path.read_text()
        assert text == "" or text.endswith("\n")  # no half-written line
        out.extend(json.loads(line) for line in text.splitlines())
    return out


def test_rotation_keeps_the_size_cap_and_the_newest_backups(tmp_path: Path) -> None:
    path = tmp_path / "trace.jsonl"
    trace = Trace(keep=0)
    sink = TraceFile(path, max_bytes=4000, backups=2)
    trace.subscribe(sink.write)
    for i in range(400):
        trace.record(ev.Write, i / 100, 0, None, "SK1", i % 256, "t")
        if i % 10 == 9:
            sink.flush()
    sink.close()
    files = sorted(tmp_path.iterdir())
    assert [f.name for f in files] == ["trace.jsonl", "trace.jsonl.1", "trace.jsonl.2"]
    assert all(f.stat().st_size <= 4000 for f in files)
    events = lines_of(path.with_name("trace.jsonl.2"), path.with_name("trace.jsonl.1"), path)
    seqs = [e["seq"] for e in events]
    assert seqs == list(range(seqs[0], 401))  # the newest, contiguous, ending with the last
    assert seqs[0] > 1  # the oldest went with the third rotation


def test_no_backups_starts_the_file_afresh(tmp_path: Path) -> None:
    path = tmp_path / "trace.jsonl"
    sink = TraceFile(path, max_bytes=500, backups=0)
    trace = Trace(keep=0)
    trace.subscribe(sink.write)
    for i in range(100):
        trace.record(ev.Display, 0.0, 1, None, f"line {i}")
        sink.flush()
    sink.close()
    assert [p.name for p in tmp_path.iterdir()] == ["trace.jsonl"]
    assert lines_of(path)[-1]["seq"] == 100


async def test_gateway_keeps_a_window_in_memory_and_everything_on_disk(tmp_path: Path) -> None:
    path = tmp_path / "run.jsonl"
    config = load_config(EXAMPLES / "scheme3" / "ncgate.toml", overrides={
        "nc.time_scale": 2000.0, "modbus.port": 0, "canopen.enabled": False,
        "trace.ring": 5, "trace.file": str(path)})
    async with Gateway(config) as gw:
        await gw.start("PROG91")
        await gw.wait_state(2, "WAIT_COND", timeout_s=10)
        gw.write("SA10", 1, source=TEST_PLC)
        await gw.wait_idle(timeout_s=20)
        window = gw.trace
        last_seq = gw.runtime.trace.seq
    on_disk = lines_of(path)
    assert len(window) == 5 and window == on_disk[-5:]
    assert [e["seq"] for e in on_disk] == list(range(1, last_seq + 1))
    assert sum(1 for e in on_disk if e["event"] == "end") == 5


def test_run_trace_survives_kill_9_with_whole_lines(tmp_path: Path) -> None:
    """`ncgate run --trace`: the file fills while it runs; kill -9 leaves only whole lines."""
    path = tmp_path / "run.jsonl"
    config = tmp_path / "ncgate.toml"
    (tmp_path / "LOOP.nc").write_text('"L"\nN1(DIS,"tick")\nN2(DLY,0.001)\nN3(BNC,L)\n')
    config.write_text('[nc]\nmain = "LOOP"\nautostart = true\ntime_scale = 10.0\n'
                      '[nc.storage]\nMP0 = "."\n[modbus]\nport = 0\n[canopen]\nenabled = false\n')
    proc = subprocess.Popen([sys.executable, "-m", "ncgate", "run", "--config", str(config),
                             "--trace", str(path)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        # Another process writes the file: nothing to wait on but its size (bounded in time).
        deadline = time.monotonic() + 30
        while not path.exists() or path.stat().st_size < 20_000:
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    events = lines_of(path)
    assert [e["seq"] for e in events] == list(range(1, len(events) + 1))
    assert {e["event"] for e in events} >= {"start", "display"}
