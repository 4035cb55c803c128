"""The virtual clock (spec 2.5): time advances only by the engine's timers, jumping straight to
the next one when every process is blocked or moving.  ``ncgate sim`` runs on it; the gateway
drives the same engine on the wall clock instead (``ncgate.gateway.wallclock``)."""

from __future__ import annotations

from collections.abc import Callable

from ncgate.interpreter.batch import gc_paused
from ncgate.interpreter.engine.engine import Engine


def run_virtual(engine: Engine, until: float | None = None,
                before_time: Callable[[float], None] | None = None) -> str:
    """Run on the virtual clock until every process is idle, or ``until``.

    Returns ``"idle"``, ``"until"`` or ``"blocked"`` (nothing runnable and no timer left
    while a process still has a program: the caller reports a stall).

    The cyclic collector is paused meanwhile (see ``gc_paused``): a simulation is a bounded
    batch job whose trace only grows.
    """
    with gc_paused():
        return _run_virtual(engine, until, before_time)


def _run_virtual(engine: Engine, until: float | None,
                 before_time: Callable[[float], None] | None) -> str:
    engine.run_until_blocked()
    while True:
        if engine.all_idle and not engine.has_runnable:
            return "idle"
        t = engine.next_timer()
        if t is None:
            return "blocked"
        if until is not None and t > until:
            engine.set_time(until)
            return "until"
        if before_time is not None:
            before_time(t)
        engine.advance_to(t)


def run_through(engine: Engine, until: float, first: bool = False) -> None:
    """Let the virtual clock run to ``until`` as ``run``'s wall clock does (a replay of a
    session): every timer due by then fires in time order -- the PLC logic's scans, the
    plant's moves and ticks, the processes' motion -- whether or not a process has a
    program, and the clock then stands at ``until``.  ``first``: of the timers due at
    ``until`` only the early ones fire (an input the session applied before the others:
    ``Door.apply_first``).

    (``run_virtual`` stops as soon as every process is idle: the clock would leap over an idle
    gap, the scans and the plant due in it then ran late, all at once, at the next input's
    time, and the logic's timers saw the leap.)"""
    with gc_paused():
        engine.run_until_blocked()
        while (t := engine.next_timer()) is not None and (t < until if first else t <= until):
            engine.advance_to(t)
        if first:
            engine.fire_early(until)
        engine.set_time(until)
