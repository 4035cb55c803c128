"""The one life cycle of the gateway's adapters.

Every adapter that serves a protocol -- the Modbus server (plain and TLS), the CANopen node
(with its hub), the web console -- is an :class:`Adapter`: ``await start()`` begins serving,
``await close()`` stops it and cancels every task, timer and callback it scheduled (also from
other threads).  :class:`~ncgate.gateway.Gateway` starts them in order and pushes each close
on one :class:`contextlib.AsyncExitStack`, so a failing start closes what was started and a
failing close does not skip the others.  The resources without a protocol (the PLC scan,
the trace file, the session record, the wall clock) close on the same stack.
"""

from __future__ import annotations

import gc
import sys
from collections.abc import Callable
from typing import Protocol

# The GIL switch interval while a gateway runs (seconds): how long another thread may keep
# the loop waiting, and the loop a thread (Gateway._open and docs/decisions.md say what it was
# measured against; `ncgate run` sets it for its whole process).  0.5 ms left the CANopen
# hub's thread, which needs the lock a dozen times a frame, so short of turns beside a busy
# loop that TPDOs came 50-90 ms after their SYNC (bench/storm.py, flood and storm phases;
# 5-7 ms at 0.2 ms, quiet 1-2 ms either way).
GIL_SWITCH_S = 0.0002
# The young generation's size that starts a garbage collection while a gateway runs
# (CPython: 700).  A write through Modbus leaves a few tracked objects (its trace events in
# the ring): at 700 one write in 200 paid a 50-130 µs collection inside its write -> resume
# path, p99 52-80 µs (bench/modbus.py, 2,500 writes); at 5,000 the collections are 7x rarer
# and take 0.3-0.4 ms each, p99 39 µs -- well inside every budget that must stay on time.
GC_YOUNG_OBJECTS = 5000


def tune_interpreter(switch_interval: bool = True) -> Callable[[], None]:
    """Give this process the gateway's young generation and (``switch_interval``) its switch
    interval, at least: ``ncgate run`` takes both for its whole process.  A :class:`Gateway`
    of the Python API takes only the young generation while it is open: the switch interval
    decides how every thread of the process takes turns -- a test's own CANopen master
    receiving a TPDO storm in the same process was a quarter slower at 0.2 ms
    (bench/canopen_node.py) -- so a program that embeds a gateway calls this itself to choose
    ``run``'s.  Returns what puts back what was there."""
    interval, threshold = sys.getswitchinterval(), gc.get_threshold()
    if switch_interval:
        sys.setswitchinterval(min(interval, GIL_SWITCH_S))
    gc.set_threshold(max(threshold[0], GC_YOUNG_OBJECTS), *threshold[1:])

    def restore() -> None:
        sys.setswitchinterval(interval)
        gc.set_threshold(*threshold)
    return restore


class Adapter(Protocol):
    async def start(self) -> None: ...

    async def close(self) -> None: ...
