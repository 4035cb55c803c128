"""The event loop while a 10 MB program of each dialect is started (issue: the cell stays on
time under any load; "loading never blocks").

For each dialect, a ``Gateway`` (the Python API, ``run``'s interpreter settings) with a
generated program of ``--mb`` MB as its main (G01 moves; ISG: one ``%channel1`` section) and
no fieldbus; a probe task on the loop sleeps 1 ms at a time and records how late it wakes.
First a quiet second (the baseline, same process), then the start of the program, which the
gateway reads and checks in a thread (NC-110 from 512 KB: in a child process) while the loop
serves.  It prints how long the start took and the probe's p99 and max lateness in both
windows, with the max's ratio to the quiet one.

    .venv/bin/python bench/load.py [--mb 10] [--dialects nc110,isg]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import tempfile
import time
from pathlib import Path

from storm import big_program  # bench/storm.py's load phase writes the same program

from ncgate.config import load_config
from ncgate.gateway import Gateway
from ncgate.gateway.lifecycle import tune_interpreter


async def probe(late: list[float], stop: asyncio.Event) -> None:
    while not stop.is_set():
        t = time.perf_counter()
        await asyncio.sleep(0.001)
        late.append(time.perf_counter() - t - 0.001)


def summary(late: list[float]) -> tuple[float, float]:
    late = sorted(late)
    return late[int(0.99 * (len(late) - 1))] * 1e3, late[-1] * 1e3


async def one(dialect: str, megabytes: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        big_program(folder, megabytes, dialect)
        (folder / "ncgate.toml").write_text(
            f'[nc]\ndialect = "{dialect}"\nmain = "BIG"\n[nc.storage]\nMP0 = "."\n'
            '[modbus]\nport = 0\n[canopen]\nenabled = false\n[web]\nenabled = false\n')
        here = os.getcwd()
        os.chdir(tmp)  # the config's storage folder is "."
        try:
            config = load_config(str(folder / "ncgate.toml"), overrides={})
            async with Gateway(config) as gw:
                quiet: list[float] = []
                loading: list[float] = []
                stop = asyncio.Event()
                task = asyncio.create_task(probe(quiet, stop))
                await asyncio.sleep(1.0)  # the baseline: the same loop, nothing loading
                stop.set()
                await task
                stop = asyncio.Event()
                task = asyncio.create_task(probe(loading, stop))
                t0 = time.perf_counter()
                await gw.start("BIG", 1)
                took = time.perf_counter() - t0
                stop.set()
                await task
        finally:
            os.chdir(here)
    q99, qmax = summary(quiet)
    l99, lmax = summary(loading)
    print(f"{dialect:6} {megabytes:g} MB: started in {took:.2f} s; loop lateness quiet p99 "
          f"{q99:.2f} ms max {qmax:.2f} ms; while loading p99 {l99:.2f} ms max {lmax:.2f} ms "
          f"({lmax / qmax:.1f}x the quiet max; {sum(x > 0.01 for x in loading)} wake-ups "
          "over 10 ms)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mb", type=float, default=10.0)
    parser.add_argument("--dialects", default="nc110,isg")
    args = parser.parse_args()
    tune_interpreter()  # run's switch interval and young generation
    for dialect in args.dialects.split(","):
        asyncio.run(one(dialect.strip(), args.mb))


if __name__ == "__main__":
    main()
