"""What users' own test suites use: the pytest plugin (``ncgate[pytest]``), the virtual-PLC
Modbus client (``modbus_kit``), the CANopen master (``canopen_kit``), :func:`wait_event`,
which awaits an event of a running gateway's trace, :func:`replay`, which turns a session
recorded at the machine (``ncgate run --record``) into a regression test, and
:func:`ncgate_sweep`, which makes a sweep's variants one test each."""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING

from ncgate.gateway.errors import WaitIdleTimeout
from ncgate.gateway.record import ReplayResult
from ncgate.gateway.record import replay as _replay
from ncgate.interpreter.engine.events import Event

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway


async def wait_event(gateway: Gateway, kind: str, timeout_s: float = 10.0,
                     test: Callable[[Event], bool] | None = None) -> Event:
    """Until ``gateway``'s trace records an event of ``kind`` (``"stall"``, ``"snd"``,
    ``"alarm"``, ... as spec 4.4 names them) for which ``test`` holds, if given; returns that
    typed event (``event.t``, ``event.proc``, and its own fields).  Only events recorded from
    the call on count.  Event-driven: a trace listener, no polling.  Raises WaitIdleTimeout
    with the why-records of the blocked processes when none comes in ``timeout_s``.

        stall = await wait_event(gw, "stall", timeout_s=5)
    """
    seen: asyncio.Future[Event] = asyncio.get_running_loop().create_future()

    def listener(event: Event) -> None:
        # The trace calls its listeners on the loop's thread, inside the engine's step.
        if event.kind == kind and not seen.done() and (test is None or test(event)):
            seen.set_result(event)

    unsubscribe = gateway.runtime.trace.subscribe(listener)
    try:
        async with asyncio.timeout(timeout_s):
            return await seen
    except TimeoutError:
        which = f"{kind!r} event" + (" that passes the test" if test is not None else "")
        raise WaitIdleTimeout(f"no {which} in {timeout_s:g} s\n"
                              + gateway.describe_blocked()) from None
    finally:
        unsubscribe()


def replay(record: str | Path, config: str | Path | None = None,
           tolerance_ms: float = 10.0) -> ReplayResult:
    """Replay a recorded session on the virtual clock; AssertionError with the first
    divergence (recorded vs replayed) unless every process did the same, in the same order,
    within ``tolerance_ms`` of machine time.  In a test, relative paths are relative to the
    test file's folder.

        def test_the_field_problem_of_march_3():
            replay("sessions/2026-03-03.jsonl")
    """
    from ncgate.gateway.testing.pytest_plugin import from_test_folder

    result = _replay(from_test_folder(record) or record, from_test_folder(config),
                     tolerance_ms)
    if result.divergence is not None:
        raise AssertionError(result.divergence)
    return result


def ncgate_sweep(spec: str | Path, *, allow: Iterable[str] = ("ok",),
                 timeout_s: float | None = 60.0) -> Callable[..., None]:
    """One test per variant of a sweep's spec (``ncgate sweep``, docs/sweep.md); a relative
    path is relative to the test file's folder.

        test_library = ncgate_sweep("sweeps/library.toml")
    """
    from ncgate.gateway.testing.sweep_kit import ncgate_sweep as make

    if not Path(spec).is_absolute():
        caller = sys._getframe(1).f_globals.get("__file__")
        if caller:
            spec = Path(caller).resolve().parent / spec
    return make(spec, allow=allow, timeout_s=timeout_s)


__all__ = ["ncgate_sweep", "replay", "wait_event"]
