"""One variant, run in this process as ``ncgate sim`` runs it, and judged: its result fields.

A variant's verdict, first match wins:

- ``timeout``: it ran past its wall timeout, or past its virtual-time budget with no ``until``;
- ``crash``: ncgate raised (a bug): the traceback's last line is the report;
- ``error``: the program or config cannot start (``sim`` says so and exits 2);
- ``ok`` / ``expect_failed``: a scenario (a script with ``[[expect]]``) -- its verdicts decide;
- ``deadlock``, ``stall``, ``alarm``, ``hazard``: what the run's trace shows;
- ``ok``: none of these.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import re
import signal
import threading
import traceback
from collections.abc import Iterator
from typing import Any

from ncgate.gateway.sweep.spec import Variant

VERDICTS = ("ok", "deadlock", "stall", "alarm", "hazard", "expect_failed", "timeout", "crash",
            "error")
Result = dict[str, Any]  # verdict, cycle_s, alarms, hazards, running_s, waiting_s, signature,
# report
RESULT_FIELDS = ("verdict", "cycle_s", "alarms", "hazards", "running_s", "waiting_s",
                 "signature", "report")


# What of a stall's blocked reason differs from variant to variant of the same failure: the
# value when it stalled ("(now 0)", before a hold's note too) and when a hold came ("since
# 1.010 s").  The signature leaves them out.
_NOW = re.compile(r"\s*\(now [^)]*\)(?=; held |$)| since \d+(?:\.\d+)? s\b")


class WallTimeout(BaseException):
    """The variant's wall timeout: raised into the run (not an Exception: nothing in the
    engine catches it on the way)."""


class BudgetExceeded(BaseException):
    """The variant's virtual time passed its budget."""


@contextlib.contextmanager
def wall_limit(seconds: float | None) -> Iterator[None]:
    """Raise WallTimeout in this thread after ``seconds`` of the wall clock.

    In the main thread (a local worker) a timer signal does it; in another thread (a Dask
    worker's) the exception is set on the thread from a timer thread.  Both act between two
    bytecodes: the engine is pure Python, so a run that hangs in it is stopped."""
    if not seconds:
        yield
        return
    if threading.current_thread() is threading.main_thread():
        def expired(signum: int, frame: object) -> None:
            raise WallTimeout

        previous = signal.signal(signal.SIGALRM, expired)
        signal.setitimer(signal.ITIMER_REAL, seconds)
        try:
            yield
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
        return
    ident = threading.get_ident()
    done = threading.Event()

    def fire() -> None:
        if not done.is_set():
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(ident),
                                                       ctypes.py_object(WallTimeout))

    timer = threading.Timer(seconds, fire)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        done.set()
        timer.cancel()


def run_variant(variant: Variant, timeout_s: float | None) -> Result:
    """Run one variant; never raises (but KeyboardInterrupt): every outcome is a result."""
    try:
        with wall_limit(timeout_s):
            return _run(variant)
    except WallTimeout:
        return _result("timeout", signature="timeout wall",
                       report=f"ran past the wall timeout of {timeout_s:g} s")
    except BudgetExceeded:
        return _result("timeout", cycle_s=variant.budget_s,
                       report=f"still running at the virtual-time budget of "
                              f"{variant.budget_s:g} s (give until, or a larger budget_s)",
                       signature="timeout budget")
    except Exception as exc:
        last = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return _result("crash", report=last)


def _result(verdict: str, **fields: Any) -> Result:
    out: Result = {"verdict": verdict, "cycle_s": 0.0, "alarms": "", "hazards": 0,
                   "running_s": "", "waiting_s": "", "signature": "", "report": ""}
    out.update(fields)
    return out


def _run(variant: Variant) -> Result:
    from ncgate.config import ConfigError, load_config
    from ncgate.config.script import load_script
    from ncgate.errors import NcgateError
    from ncgate.gateway.sim import report, run_sim
    from ncgate.interpreter.diagnostics import ProgramError, ProgramNotFoundError

    overrides = variant.overrides()
    try:
        # The absolute paths: a Dask worker's working folder is not the client's.
        config = load_config(variant.config_file or variant.config, overrides=overrides,
                             origins=dict.fromkeys(overrides, "--set"), serving=False)
        script = load_script(variant.script_file or variant.script)
    except ConfigError as exc:
        return _result("error", report=str(exc).splitlines()[0])
    budget = variant.budget_s if variant.until is None else None

    def check(t: float) -> None:
        if budget is not None and t > budget:
            raise BudgetExceeded

    try:
        result = run_sim(config, [variant.main], script, variant.until,
                         before_time=None if budget is None else check)
    except (ProgramError, ProgramNotFoundError, NcgateError) as exc:
        return _result("error", report=str(exc).splitlines()[0])
    engine = result.runtime.engine
    events = result.events
    codes: list[str] = []
    hazards = 0
    deadlock = stall = alarm = None
    for event in events:
        kind = event["event"]
        if kind == "alarm":
            if event["code"] not in codes:
                codes.append(event["code"])
            alarm = alarm or event
        elif kind == "hazard":
            hazards += 1
        elif kind == "deadlock":
            deadlock = deadlock or event
        elif kind == "stall":
            stall = stall or event
    text = io.StringIO()
    report(result, text)
    lines = text.getvalue().splitlines()
    signature = ""
    if script.expects:
        failed = [v for v in result.verdicts if not v.ok]
        verdict = "expect_failed" if failed else "ok"
        if failed:
            signature = "expect " + failed[0].name
    elif deadlock is not None:
        verdict = "deadlock"
        signature = "deadlock " + " -> ".join(
            f"P{b['proc']} {b['prog']}:{b['line']} {b['reason']}" for b in deadlock["cycle"])
    elif result.outcome == "stall" and stall is not None:
        verdict = "stall"
        signature = "stall " + "; ".join(
            f"P{b['proc']} {b['prog']}:{b['line']} {_NOW.sub('', b['reason'])}"
            for b in stall["blocked"])
    elif result.alarms:
        verdict = "alarm"
        assert alarm is not None
        where = f" {alarm['prog']}:{alarm['line']}" if alarm.get("prog") else ""
        signature = f"alarm {alarm['code']}{where}"
    elif hazards:
        verdict = "hazard"
    else:
        verdict = "ok"
    running = " ".join(f"P{p.number}={p.stats.running_s:.3f}"
                       for p in engine.processes.values() if p.stats.programs)
    waiting = " ".join(f"P{p.number}={p.stats.waiting_s:.3f}"
                       for p in engine.processes.values() if p.stats.programs)
    return _result(verdict, cycle_s=round(engine.now, 6), alarms=" ".join(codes),
                   hazards=hazards, running_s=running, waiting_s=waiting,
                   signature=signature, report=_first_line(lines, result.verdicts))


def _first_line(lines: list[str], verdicts: list[Any]) -> str:
    """The report's first line that says something.  A scenario: its first failed
    expectation, else the closing ``simulated ... s`` line and the count passed.  Else the
    first alarm, stall, deadlock or hazard line, else the closing line."""
    closing = next((line for line in reversed(lines) if line.startswith("simulated ")), "")
    if verdicts:
        failed = [v for v in verdicts if not v.ok]
        if failed:
            return str(failed[0].line())
        return f"{closing}; {len(verdicts)} of {len(verdicts)} expectations passed"
    for i, line in enumerate(lines):
        if line.startswith("["):
            blocked = []  # a stall's lines below it: who waits for what
            for more in lines[i + 1:]:
                if not more.startswith("    "):
                    break
                blocked.append(more.strip())
            return line + (": " + "; ".join(blocked) if blocked else "")
    return closing
