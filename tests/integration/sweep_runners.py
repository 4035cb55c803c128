"""Stand-ins for ``run_variant`` that misbehave, for the sweep's pools to survive: module-level
functions, so that a local worker (forked from the forkserver) and a Dask worker import them."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

from ncgate.gateway.sweep.run import Result, run_variant
from ncgate.gateway.sweep.spec import Variant


def misbehaving(variant: Variant, timeout_s: float | None) -> Result:
    """DIE.nc ends its worker process at once (as a crash of the interpreter would); HANG.nc
    hangs where the worker's own timer cannot reach it (the timer signal blocked, a sleep in
    C); RAISE.nc raises out of the runner (on Dask, a task that errs: no row, no death); any
    other program runs as usual."""
    name = Path(variant.program).stem
    if name == "DIE":
        os._exit(3)
    if name == "RAISE":
        raise RuntimeError("RAISE.nc: out of the runner")
    if name == "HANG":
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
        time.sleep(3600)
    return run_variant(variant, timeout_s)


SLOW_S = 0.5


def slow(variant: Variant, timeout_s: float | None) -> Result:
    """``run_variant`` after half a second of the wall clock, as a long program takes: a
    sweep of a few such variants on one worker thread is still running when the test takes
    its workers away after the first result."""
    time.sleep(SLOW_S)
    return run_variant(variant, timeout_s)


def slow_tagged(variant: Variant, timeout_s: float | None) -> Result:
    """:func:`slow`, its report saying which runner made it: two sweeps of one spec on one
    cluster must each get their own runner's rows."""
    result = slow(variant, timeout_s)
    result["report"] = "tagged"
    return result
