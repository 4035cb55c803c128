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

from typing import Protocol

# The GIL switch interval while a gateway runs (seconds): how long another thread may keep
# the loop waiting, and the loop a thread (Gateway._open and docs/decisions.md say what it was
# measured against; `ncgate run` sets it for its whole process).  0.5 ms left the CANopen
# hub's thread, which needs the lock a dozen times a frame, so short of turns beside a busy
# loop that TPDOs came 50-90 ms after their SYNC (bench/storm.py, flood and storm phases;
# 5-7 ms at 0.2 ms, quiet 1-2 ms either way).
GIL_SWITCH_S = 0.0002


class Adapter(Protocol):
    async def start(self) -> None: ...

    async def close(self) -> None: ...
