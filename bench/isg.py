"""ISG dialect speed (issue: a second dialect on the same runtime).

Signal/WAIT round trips per second between two channels on the virtual clock, beside NC-110
SND/WAI round trips between two processes in the same run, both through the same wiring
(``build_runtime``: image, program store, front end, trace) and ``run_virtual``.
Target: both >= 50,000 round trips/s, and within 1.5x of each other.

    .venv/bin/python bench/isg.py
"""

from __future__ import annotations

import gc
import tempfile
import time
from pathlib import Path

from runtime import PING, PONG, TRIPS  # bench/runtime.py: the NC-110 ping-pong, as it is there

from ncgate.config import load_config
from ncgate.gateway.wiring import build_runtime
from ncgate.interpreter.engine import run_virtual
from ncgate.interpreter.engine.trace import Trace

ROUNDS = 3

ISG = f"""%channel1
P1 = 0
$WHILE P1 < {TRIPS}
#SIGNAL [ID1 CH2]
#WAIT [ID2 CH2]
P1 = P1 + 1
$ENDWHILE
M30
%channel2
P1 = 0
$WHILE P1 < {TRIPS}
#WAIT [ID1 CH1]
#SIGNAL [ID2 CH1]
P1 = P1 + 1
$ENDWHILE
M30
"""
def run(folder: Path, dialect: str, main: str) -> float:
    (folder / "ncgate.toml").write_text(
        f'[nc]\ndialect = "{dialect}"\nprocesses = 2\nmain = "{main}"\n'
        "runaway_blocks = 0  # a loop with no motion, on purpose\n", encoding="utf-8")
    config = load_config(folder / "ncgate.toml")
    runtime = build_runtime(config, closed=True, trace=Trace(keep=1000))
    engine = runtime.engine
    gc.collect()
    start = time.perf_counter()
    if dialect == "isg":
        engine.start(main, 1)
        engine.start(main, 2)
    else:
        engine.start(main, 1)
    outcome = run_virtual(engine)
    elapsed = time.perf_counter() - start
    assert outcome == "idle", outcome
    received = engine.processes[1].stats.snd_received
    assert received == TRIPS, received  # every round trip happened
    return elapsed


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        isg_dir, nc_dir = Path(tmp, "isg"), Path(tmp, "nc110")
        isg_dir.mkdir()
        nc_dir.mkdir()
        (isg_dir / "PINGPONG.nc").write_text(ISG, encoding="utf-8")
        (nc_dir / "PING.nc").write_text(PING, encoding="utf-8")
        (nc_dir / "PONG.nc").write_text(PONG, encoding="utf-8")
        isg_s, nc_s = [], []
        for _ in range(ROUNDS):  # interleaved, so that both see the same machine
            isg_s.append(run(isg_dir, "isg", "PINGPONG"))
            nc_s.append(run(nc_dir, "nc110", "PING"))
    isg_rate, nc_rate = TRIPS / min(isg_s), TRIPS / min(nc_s)
    print(f"ISG #SIGNAL/#WAIT: {isg_rate:10,.0f} round trips/s ({TRIPS} in {min(isg_s):.3f} s)")
    print(f"NC-110 SND/WAI:    {nc_rate:10,.0f} round trips/s ({TRIPS} in {min(nc_s):.3f} s)")
    print(f"ratio NC-110/ISG:  {nc_rate / isg_rate:.2f}x   (target: both >= 50,000/s, "
          "within 1.5x)")


if __name__ == "__main__":
    main()
