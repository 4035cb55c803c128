"""The plant's cost (issue: the machine that isn't there yet).

Two figures:

1. **On time beside 100 moving models.** `ncgate run` serves a cell with PLC logic scanning
   every 10 ms and a 200 Hz Modbus poller (FC4: the PLC status block, whose scan lateness it
   samples), once *quiet* (no plant) and once with *100 models* at a 1 ms plant scan, kept
   moving: 50 square generators (period 200 ms) driving the valves of 50 cylinders with a
   position output (a stroke of 150 ms: written every 1 ms while it moves).  The generators
   switch in phase: every 100 ms, 100 switch points (50 valves, 50 cylinders leaving their
   ends) fall at one instant, about 4 ms of writes through the door, and a scan due among
   them runs after them, in order.  ``--spread`` gives generator i a period of 200 + 3i ms,
   so the same load of moving models switches at scattered instants.  Rounds alternate,
   each `ncgate run` a fresh process.  Printed: the poller's round trip p50/p99/max and the PLC
   scan's max lateness in each, and the ratio plant/quiet.  Target: <= 1.2x for the poller's
   p99 and the PLC's lateness.
2. **`sim` throughput.** The machine example's scenario suite (`ncgate sim --example
   machine`, each scenario in-process, after one untimed run that builds the grammars) in
   simulated seconds per CPU second, the best of ``--passes`` passes (7; a pass is 0.06-0.1
   CPU s, so one pass is at the mercy of a collection or a neighbour) and their median.  The
   target is absolute: >= 1,000x real time.

    .venv/bin/python bench/plant.py                 # 3 rounds of 5 s each
    .venv/bin/python bench/plant.py --rounds 1 --seconds 3
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from storm import poller  # a sibling script, not a package

LOGIC = """PROGRAM main
VAR n : DINT; END_VAR
n := n + 1;
SYVAR[200] := DINT_TO_INT(n MOD 30000);
END_PROGRAM
"""


def write_cell(folder: Path, port: int, models: int, spread: bool = False) -> Path:
    """The bench's cell; ``spread``: generator i's period is 200 + 3i ms instead of 200 ms, so
    the switch points spread out instead of falling 100 at one instant every 100 ms."""
    (folder / "PROG1.nc").write_text("N10 (DLY,1000)\nN20 M30\n")
    (folder / "plc.st").write_text(LOGIC)
    text = [f'[nc]\nprocesses = 1\nmain = "PROG1"\n[nc.storage]\nMP0 = "{folder}"\n'
            f'[plc]\nlogic = "plc.st"\nscan_ms = 10\n'
            f'[modbus]\nport = {port}\n[modbus.map]\nplc_status = 300\n'
            '[canopen]\nenabled = false\n[web]\nenabled = false\n[plant]\nscan_ms = 1\n']
    for i in range(models // 2):
        text.append(f'[[plant.model]]\nname = "valve{i}"\nkind = "generator"\n'
                    f'output = "SA{100 + i}"\nperiod_ms = {200 + 3 * i if spread else 200}\n'
                    f'[[plant.model]]\nname = "cyl{i}"\nkind = "cylinder"\n'
                    f'extend = "SA{100 + i}"\nextended = "SA{300 + i}"\n'
                    f'position = "SYVAR{i}"\ntravel_ms = 150\n')
    config = folder / "ncgate.toml"
    config.write_text("".join(text))
    return config


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


async def one_round(models: int, seconds: float, spread: bool = False
                    ) -> tuple[list[float], list[int]]:
    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        config = write_cell(Path(tmp), port, models, spread)
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "ncgate", "run", "--config", str(config), "-q",
            stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
        try:
            async with asyncio.timeout(30):
                while True:  # until it listens
                    try:
                        _, writer = await asyncio.open_connection("127.0.0.1", port)
                        writer.close()
                        break
                    except OSError:
                        await asyncio.sleep(0.05)
            await asyncio.sleep(1.0)  # the first scans and strokes: not measured
            stop = asyncio.Event()
            rtts: list[float] = []
            lateness: list[int] = []
            task = asyncio.create_task(poller(port, stop, rtts, lateness))
            await asyncio.sleep(seconds)
            stop.set()
            await task
            return rtts, lateness
        finally:
            proc.terminate()
            with contextlib.suppress(ProcessLookupError):
                await proc.wait()


def quantile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def sim_throughput(passes: int = 1) -> tuple[float, list[float], int] | None:
    """Simulated seconds, the CPU seconds of each of ``passes`` passes over the machine
    example's suite, and its scenarios."""
    from ncgate.config import load_config
    from ncgate.config.script import load_script
    from ncgate.gateway.errors import UsageError
    from ncgate.gateway.examples import find_example
    from ncgate.gateway.sim import run_sim

    try:
        example = find_example("machine")
    except UsageError:
        return None
    config = load_config(example.config)
    assert example.main is not None
    run_sim(config, example.main, load_script(example.scripts[0]))  # warm: grammars, imports
    scripts = [load_script(path) for path in example.scripts]
    cpus = []
    for _ in range(passes):
        simulated = cpu = 0.0
        for script in scripts:
            t0 = time.process_time()
            result = run_sim(config, example.main, script)
            cpu += time.process_time() - t0
            simulated += result.runtime.engine.now
        cpus.append(cpu)
    return simulated, cpus, len(example.scripts)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--models", type=int, default=100)
    parser.add_argument("--passes", type=int, default=7,
                        help="passes over the machine example's suite (the best is the figure)")
    parser.add_argument("--spread", action="store_true",
                        help="generators of different periods (200 + 3i ms): their switch "
                        "points spread out instead of 100 falling at one instant")
    args = parser.parse_args()
    results: dict[str, tuple[list[float], list[int]]] = {"quiet": ([], []), "plant": ([], [])}
    for _ in range(args.rounds):
        for name, models in (("quiet", 0), ("plant", args.models)):
            rtts, late = asyncio.run(one_round(models, args.seconds, args.spread))
            results[name][0].extend(rtts)
            results[name][1].extend(late)
    print(f"{'':8} {'poll p50 ms':>12} {'p99 ms':>8} {'max ms':>8} {'PLC late p99 ms':>16}"
          f" {'max ms':>8} {'polls':>6}")
    figures = {}
    for name, (rtts, late) in results.items():
        p50, p99 = quantile(rtts, 0.5) * 1e3, quantile(rtts, 0.99) * 1e3
        late_max = max(late) / 1e3 if late else 0.0
        late_p99 = quantile(late, 0.99) / 1e3 if late else 0.0
        figures[name] = (p99, late_max, late_p99)
        print(f"{name:8} {p50:12.2f} {p99:8.2f} {max(rtts) * 1e3:8.2f} {late_p99:16.2f}"
              f" {late_max:8.2f} {len(rtts):6}")
    (q99, qlate, qlate99), (p99, plate, plate99) = figures["quiet"], figures["plant"]
    # The lateness is sampled by the poller (the last scan's, 200 times a second): its max is
    # one scan, which a neighbour's burst on a shared machine sets as often as the plant; its
    # p99 is printed beside it.
    print(f"ratio plant/quiet: poll p99 {p99 / q99:.2f}x, PLC lateness max "
          f"{plate / max(qlate, 0.001):.2f}x, p99 {plate99 / max(qlate99, 0.001):.2f}x "
          "(target <= 1.2x)")
    found = sim_throughput(args.passes)
    if found is None:
        print("sim throughput: no machine example installed")
    else:
        simulated, cpus, count = found
        best, median = min(cpus), statistics.median(cpus)
        print(f"sim throughput: the machine example's {count} scenarios, {simulated:.1f} "
              f"simulated s in {best:.3f} CPU s (best of {len(cpus)} passes): "
              f"{simulated / best:,.0f}x real time, median {simulated / median:,.0f}x "
              "(target >= 1,000x)")
    with contextlib.suppress(Exception):
        print(f"rounds: {args.rounds} x {args.seconds:g} s; median poll p99 over both: "
              f"{statistics.median([q99, p99]):.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
