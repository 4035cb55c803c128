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
    C); any other program runs as usual."""
    name = Path(variant.program).stem
    if name == "DIE":
        os._exit(3)
    if name == "HANG":
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
        time.sleep(3600)
    return run_variant(variant, timeout_s)
