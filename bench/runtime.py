"""Runtime speed (issue: the co-simulation runtime).  Each figure beside its baseline:

1. decoder blocks/s of a loop of E-parameter arithmetic and jumps with no motion
   (target >= 200,000 blocks/s), beside the same loop written in plain Python;
2. SND/WAI round trips/s between two processes on the virtual clock (target >= 50,000/s),
   beside two asyncio tasks ping-ponging on asyncio.Event;
3. a 10-minute machining job (three processes, thousands of G1/G2 moves, syncs) on the
   virtual clock: simulated time / CPU time (target >= 1,000x);
4. the cost of one image write with 10,000 waits registered (on distinct K bytes and SYVARs)
   against the same with 10 registered (target <= 1.5x).

    python3 dev.py bench        # or: .venv/bin/python bench/runtime.py
"""

from __future__ import annotations

import asyncio
import gc
import time
from collections.abc import Callable

from ncgate.interpreter.diagnostics import ProgramNotFoundError, ProgramSyntaxError
from ncgate.interpreter.engine import Engine, run_virtual
from ncgate.interpreter.engine.trace import Trace
from ncgate.interpreter.nc110.checker import CheckContext, check_program
from ncgate.interpreter.nc110.compiler import NC110
from ncgate.interpreter.nc110.parser import Program
from ncgate.interpreter.settings import RuntimeSettings
from ncgate.plc.image import IOImage


class Loader:
    def __init__(self, programs: dict[str, str]) -> None:
        self.programs = programs

    def load(self, name: str, device: str | None, process: int) -> Program:
        if name not in self.programs:
            raise ProgramNotFoundError(name)
        program = Program(name, f"{name}.nc", self.programs[name])
        errors = [d for d in check_program(program, CheckContext(runs_in=frozenset({process})))
                  if d.is_error]
        if errors:
            raise ProgramSyntaxError(errors)
        return program


def simulate(programs: dict[str, str], **settings: object) -> tuple[Engine, float, float]:
    # The loops measured here have no motion on purpose: no runaway limit (nc.runaway_blocks).
    settings.setdefault("runaway_blocks", 0)
    engine = Engine(RuntimeSettings(**settings), IOImage(), Loader(programs),  # type: ignore[arg-type]
                    NC110(), Trace())
    gc.collect()
    wall, cpu = time.perf_counter(), time.process_time()
    engine.start("MAIN")
    outcome = run_virtual(engine)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    assert outcome == "idle", outcome
    assert not [e for e in engine.trace.events if e["event"] == "alarm"]
    return engine, wall, cpu


def best(rounds: int, fn: Callable[[], float]) -> float:
    return min(fn() for _ in range(rounds))


# -- 1. blocks per second ------------------------------------------------------------------

LOOPS = 100_000
ARITHMETIC = f"""N1E1=0
"LOOP"
N2E1=E1+1
N3E2=E2*0.5+E1
N4(BLT,E1,{LOOPS},LOOP)
N5M30
"""


def python_loop() -> float:
    start = time.perf_counter()
    e = [0.0] * 1000
    e[1] = 0.0
    while True:
        e[1] = e[1] + 1
        e[2] = e[2] * 0.5 + e[1]
        if not e[1] < LOOPS:
            break
    return time.perf_counter() - start


def blocks_per_second() -> None:
    engine, _, _ = simulate({"MAIN": ARITHMETIC})
    blocks = engine.processes[1].stats.blocks
    engine_s = best(3, lambda: simulate({"MAIN": ARITHMETIC})[1])
    python_s = best(3, python_loop)
    print(f"1. decoder: {blocks / engine_s:12,.0f} blocks/s ({blocks} blocks in {engine_s:.3f} s)"
          f"; plain Python loop {3 * LOOPS / python_s:,.0f} statements/s; "
          f"ratio {engine_s / python_s:.1f}x slower   (target >= 200,000 blocks/s)")


# -- 2. SND/WAI round trips ----------------------------------------------------------------

TRIPS = 50_000
PING = f"""N1(EXE,2,PONG)
"L"
N2(SND,2)
N3(WAI,2)
N4E1=E1+1
N5(BLT,E1,{TRIPS},L)
N6M30
"""
PONG = f""""L"
N1(WAI,1)
N2(SND,1)
N3E1=E1+1
N4(BLT,E1,{TRIPS},L)
N5(REL)
"""


async def asyncio_ping_pong() -> float:
    ping, pong = asyncio.Event(), asyncio.Event()

    async def a() -> None:
        for _ in range(TRIPS):
            ping.set()
            await pong.wait()
            pong.clear()

    async def b() -> None:
        for _ in range(TRIPS):
            await ping.wait()
            ping.clear()
            pong.set()

    start = time.perf_counter()
    await asyncio.gather(a(), b())
    return time.perf_counter() - start


def round_trips() -> None:
    engine, _, _ = simulate({"MAIN": PING, "PONG": PONG})
    snds = sum(1 for e in engine.trace.events if e["event"] == "snd")
    assert snds == 2 * TRIPS, snds
    engine_s = best(3, lambda: simulate({"MAIN": PING, "PONG": PONG})[1])
    asyncio_s = best(3, lambda: asyncio.run(asyncio_ping_pong()))
    print(f"2. SND/WAI: {TRIPS / engine_s:12,.0f} round trips/s (trace kept: "
          f"{len(engine.trace.events):,} events); asyncio.Event ping-pong "
          f"{TRIPS / asyncio_s:,.0f}/s; ratio {asyncio_s / engine_s:.2f}x of asyncio's rate "
          f"  (target >= 50,000/s)")


# -- 3. a 10-minute machining job ----------------------------------------------------------

def machining_programs() -> dict[str, str]:
    def contour(passes: int, feed: int, tag: str, sync: str) -> list[str]:
        lines = [f"N1T1.1M6S3000F{feed}", "G0X0Y0Z5", "G1Z-1"]
        for i in range(passes):
            y = 2.0 * i
            lines += [f"G1X100Y{y:.1f}", f"G2X100Y{y + 1:.1f}I0J0.5", f"G1X0Y{y + 1:.1f}",
                      f"G3X0Y{y + 2:.1f}I0J0.5"]
            if i % 25 == 24:
                lines.append(sync.format(i=i))
        return lines

    main = ["N1(EXE,2,SIDE2)", "N2(EXE,3,SIDE3)"]
    main += contour(300, 6000, "P1", "(SND,2)\n(SND,3)\n(WAI,2)\n(WAI,3)")
    main += ["M30"]
    side2 = [*contour(300, 6000, "P2", "(WAI,1)\n#(SND,1)"), "(REL)"]
    side3 = [*contour(300, 6000, "P3", "(WAI,1)\n#(SND,1)"), "(REL)"]
    return {"MAIN": "\n".join(main) + "\n", "SIDE2": "\n".join(side2) + "\n",
            "SIDE3": "\n".join(side3) + "\n"}


def machining() -> None:
    programs = machining_programs()
    engine, _, _ = simulate(programs)
    moves = sum(p.stats.blocks for p in engine.processes.values())
    runs = [simulate(programs) for _ in range(3)]
    cpu = min(r[2] for r in runs)
    simulated = runs[0][0].now
    print(f"3. machining: {simulated:,.1f} s simulated ({simulated / 60:.1f} min, {moves:,} "
          f"blocks in 3 processes) in {cpu:.3f} s CPU: simulated/CPU = {simulated / cpu:,.0f}x"
          f"   (target >= 1,000x)")


# -- 4. waking cost ------------------------------------------------------------------------

WRITES = 200_000


def write_cost(registered: int) -> float:
    image = IOImage(sa_bits=1024, k_bytes=8192, syvars=8192)
    for i in range(registered):
        if i % 2:
            image.wait("SK", 1 + i // 2, "BY", lambda v: v == 1, lambda: None)
        else:
            image.wait("SYVAR", 1 + i // 2, "IN", lambda v: v == 1, lambda: None)
    # One more wait, on the variable being written: each write looks at it and finds it false.
    image.wait("SK", 0, "BY", lambda v: v == 255, lambda: None)
    assert image.wait_count == registered + 1
    write = image.write
    gc.collect()
    start = time.perf_counter()
    for i in range(WRITES):
        write([("SK", 0, "BY", i & 127)], "bench")
    return (time.perf_counter() - start) / WRITES


def waking() -> None:
    few = best(5, lambda: write_cost(10))
    many = best(5, lambda: write_cost(10_000))
    print(f"4. waking: one write {many * 1e6:.2f} us with 10,000 waits registered, "
          f"{few * 1e6:.2f} us with 10; ratio {many / few:.2f}x   (target <= 1.5x)")


if __name__ == "__main__":
    blocks_per_second()
    round_trips()
    machining()
    waking()
