"""``ncgate run``: the gateway until SIGINT or SIGTERM (spec 4.1).

It logs what happens -- the listening addresses, connections, and every sync event in one line
each at INFO (start, wait with its condition, resume with who, SND, EXE, end, alarm, deadlock,
stall), PLC and fieldbus writes at DEBUG (``-v``) -- and on a signal closes every connection
and returns, leaving no task behind.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import signal
import sys
from collections.abc import Sequence
from contextlib import suppress
from pathlib import Path
from typing import Any

from ncgate.config import Config
from ncgate.config.schema import DEFAULT_WEB_PORT
from ncgate.config.script import Script
from ncgate.errors import InputRefused, Reason
from ncgate.gateway.adapters import plugin
from ncgate.gateway.app import Gateway
from ncgate.gateway.plc import LogicWatcher
from ncgate.gateway.programs import CheckedFile
from ncgate.gateway.ratelimit import RateLimitedLog
from ncgate.gateway.stdout import stdout
from ncgate.inputs import Command, CommandKind, Source, SourceKind, Start
from ncgate.interpreter.diagnostics import fmt_number
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.events import Event
from ncgate.interpreter.engine.states import WaitKind, describe_where
from ncgate.interpreter.engine.timers import grid_index

log = logging.getLogger("ncgate")


GRID_WAIT_MS = 1000  # the longest shared period a scenario's start waits for (machine ms)


def scan_grid_s(config: Config) -> float | None:
    """The period (machine seconds) on whose multiples every scan of the cell falls: the PLC
    logic's, the plant's (its ticks and its logic), both (their least common multiple); None
    when nothing scans."""
    periods = ([config.plc.scan_ms] if config.plc.logic else []) + (
        [config.plant.scan_ms] if config.plant.model or config.plant.logic else [])
    if not periods:
        return None
    shared = math.lcm(*periods)
    # Periods that share an instant only now and then (97 and 100 ms: every 9.7 s) would keep
    # the scenario waiting: the PLC's grid alone then, its reactions being what a window sees.
    return (shared if shared <= GRID_WAIT_MS else periods[0]) / 1000.0


def _on(on: object) -> str:
    if isinstance(on, ev.WaitOn):
        if on.cond is not None:
            cond = f"{on.name} ({on.cond})" if on.name else on.cond
            return f"{cond} (now {fmt_number(on.value or 0)})"
        return {WaitKind.PROC: f"an SND from P{on.target}",
                WaitKind.SND: f"P{on.target} to take its SND",
                WaitKind.EXE: f"P{on.target} to be free"}.get(on.kind, on.kind.name)
    if isinstance(on, ev.SignalOn):
        source = on.from_ if isinstance(on.from_, str) else ",".join(map(str, on.from_))
        return f"signal {on.signal} from {source} ({on.level})"
    if isinstance(on, ev.FlushOn):
        return "its interpolator (#FLUSH WAIT)"
    if isinstance(on, ev.AuxOn):
        return f"the PLC to acknowledge {on.shown or on.code} ({on.ack})"
    return str(on)


def describe(event: Event) -> str | None:
    """A log line for the events worth a line; None for the rest."""
    proc, where = event.proc, event.where
    at = ""
    if where is not None and where[0]:
        at = f" at {where[0]}:{where[1]}" + (f" N{where[2]}" if where[2] is not None else "")
    if isinstance(event, ev.Start):
        return f"P{proc} starts {event.prog} (by {event.by})"
    if isinstance(event, ev.Wait):
        return f"P{proc} waits{at} for {_on(event.on)}"
    if isinstance(event, ev.Resume):
        by = f"P{event.by}" if isinstance(event.by, int) else event.by
        writer = f", written by {event.writer}" if event.writer else ""
        return f"P{proc} resumes{at} (by {by}{writer})"
    if isinstance(event, ev.Snd):
        return f"P{proc} SND to P{event.to}{at}"
    if isinstance(event, ev.Exe):
        return f"P{proc} EXE {event.target_prog} in P{event.to}{at}"
    if isinstance(event, ev.Write):
        return f"{event.var} = {event.value} (by {event.who})"
    if isinstance(event, ev.Display):
        return f"P{proc} DIS{at}: {event.text}"
    if isinstance(event, ev.End):
        return f"P{proc} ends ({event.how}){at}"
    if isinstance(event, ev.Alarm):
        who = f"P{proc}" if proc else "fieldbus"  # process 0: the PLC/fieldbus side
        return f"{who} ALARM {event.code.label}{at}: {event.message}"
    if isinstance(event, ev.Deadlock):
        return event.message
    if isinstance(event, ev.Stall):
        return "stall: " + "; ".join(
            f"P{b.proc} {describe_where((b.prog, b.line, b.n))} {b.reason}"
            for b in event.blocked)
    if isinstance(event, ev.Hazard):
        return f"P{proc} hazard{at}: {event.message}"
    if isinstance(event, ev.Force):
        if event.var is None:
            return f"every force released (by {event.who})"
        if event.value is None:
            return f"{event.var} released (by {event.who})"
        return f"{event.var} forced to {event.value} (by {event.who})"
    if isinstance(event, ev.Forced):
        return f"{event.var} = {event.value} by {event.who} overridden by force"
    if isinstance(event, ev.Aux):
        return f"P{proc} outputs {event.code} ({event.handshake}){at}"
    if isinstance(event, ev.AuxAck):
        return f"P{proc} {event.code} acknowledged by {event.by}{at}"
    if isinstance(event, ev.Stop):
        return f"P{proc} stopped after a block ({event.cause}){at}"
    if isinstance(event, ev.Step):
        return f"P{proc} steps{at}"
    if isinstance(event, ev.Hold):
        return f"P{proc} feed hold {'on' if event.on else 'off'}{at}"
    if isinstance(event, ev.Fault):
        params = ", ".join(f"{k} {v}" for k, v in event.params.items())
        return (f"fault {event.fault_kind} on {event.target}{f' ({params})' if params else ''}"
                f" (by {event.who})")
    if isinstance(event, ev.FaultClear):
        by = event.who if event.who.startswith(("for_s", "replaced by")) else f"by {event.who}"
        return f"fault {event.fault_kind} on {event.target} cleared ({by})"
    return None


def _watch(gw: Gateway, config: Config, loop: asyncio.AbstractEventLoop) -> LogicWatcher | None:
    """``run --watch``: a change of a ``[plc] logic`` file reloads the logic (the command
    reload_plc, attributed ``api run --watch``)."""
    if not config.plc.logic:
        log.warning("--watch: there is no PLC logic to watch ([plc] logic)")
        return None
    source = Source(SourceKind.API, "run --watch")

    def reload() -> None:
        try:
            gw.apply(Command(CommandKind.RELOAD_PLC, None, source))
        except InputRefused as exc:  # (the PLC is always there when logic is configured)
            log.error("--watch: reload_plc refused: %s", exc)

    watcher = LogicWatcher(config.plc.logic, reload, loop)
    watcher.start()
    log.info("watching %s: a change reloads the PLC logic",
             ", ".join(p.name for p in config.plc.logic))
    return watcher


HAZARDS_LOGGED = 1000  # distinct blocks whose hazard the log shows (the trace has them all)
# Sync events worded per second: a loop that SNDs a thousand times a second must not flood the
# log (or block the loop on a full stdout pipe); the trace and the console have every event.
LOG_LINES_PER_S = 100


async def serve(config: Config, stop: asyncio.Event | None = None, cold: bool = False,
                record: str | None = None, overrides: dict[str, Any] | None = None,
                watch: bool = False, checked: Sequence[CheckedFile] = (),
                script: Script | None = None, junit: tuple[Path, str] | None = None) -> int:
    """``watch``: reload the PLC logic when one of its files changes (``run --watch``).
    ``checked``: what the start-up check found no error in (``Gateway``'s ``checked``).
    ``script``: a scenario played on the wall clock (``run --script``): its inputs and faults
    at their machine times, its expectations judged as in ``sim``; it stops at the end of
    its last window (or at a signal) and returns 1 when an expectation failed, else 0;
    ``junit``: the file its verdicts are written to as JUnit XML, and the scenario's name
    there (``run --junit``)."""
    status = 0
    stop = stop if stop is not None else asyncio.Event()
    loop = asyncio.get_running_loop()
    installed = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        with suppress(NotImplementedError, RuntimeError):  # not on every platform or thread
            loop.add_signal_handler(sig, stop.set)
            installed.append(sig)

    hazards_logged: set[tuple[int, object]] = set()
    debug = functools.partial(log.isEnabledFor, logging.DEBUG)
    info = functools.partial(log.isEnabledFor, logging.INFO)
    budget = RateLimitedLog(log, level=logging.INFO, burst=LOG_LINES_PER_S,
                            held="... %d more sync events not logged in the last second (the "
                                 "trace and the web console have every one)")

    def on_event(event: Event) -> None:
        if isinstance(event, ev.Hazard):
            # A loop repeats its hazards every turn: the log names each block once, the
            # trace has every one.
            key = (event.proc, event.where)
            if key in hazards_logged or len(hazards_logged) >= HAZARDS_LOGGED:
                return
            hazards_logged.add(key)
        warn = isinstance(event, ev.Alarm | ev.Deadlock | ev.Stall | ev.Hazard)
        if isinstance(event, ev.Write | ev.Forced):
            if debug() and budget.take():  # a PLC writes every scan: worded only if asked
                log.debug(describe(event))
            return
        if not warn and not (info() and budget.take()):
            return
        line = describe(event)
        if line is not None:
            (log.warning if warn else log.info)(line)

    try:
        async with Gateway(config, listeners=[on_event], cold=cold, console=True,
                           web_default_port=DEFAULT_WEB_PORT, record=record,
                           overrides=overrides, checked=checked) as gw:
            source = str(config.source) if config.source else "built-in default"
            log.info("ncgate running: config %s, %d processes, main %s (%s)", source,
                     config.nc.processes, config.nc.main,
                     "started" if config.nc.autostart else "the scenario starts it"
                     if script is not None else "waits for cycle start")
            for name, adapter in gw.adapters.items():  # where each adapter serves
                for line in plugin(name).describe(adapter):
                    log.info("%s", line)
            if gw.recorder is not None:
                log.info("recording the session to %s", gw.recorder.path)
            watcher = _watch(gw, config, loop) if watch else None
            scenario = await _play(gw, script, stop, junit) if script is not None else None
            try:
                await stop.wait()
            finally:
                if watcher is not None:
                    watcher.close()
            if scenario is not None:
                status = scenario.finish()
            log.info("stopping")
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)
    log.info("stopped")
    return status


LATE_SAID_S = 0.01  # machine seconds behind the clock that a failed scenario's note says


class _Scenario:
    """A script played by ``run --script``: its player, its expectations, its end.

    The scenario starts the main program itself, as ``sim`` does, and that moment is its
    t = 0: its entries' ``at``, its faults and its windows count from the program's start,
    not from the gateway's (whose start-up takes a moment, seconds under load).  ``run
    --script`` turns ``nc.autostart`` off for it (the CLI does)."""

    def __init__(self, gw: Gateway, script: Script, stop: asyncio.Event,
                 junit: tuple[Path, str] | None = None) -> None:
        from ncgate.gateway.scenario import Expectations

        self.gw = gw
        self.script = script
        self.junit = junit
        self.stop = stop
        self.expectations = Expectations(gw.runtime, script)
        self.horizon = script.horizon if script.expects else None
        self.reached = False
        self.started = False  # (a stop while it waited for its instant: it never started)
        self._end: Any = None

    async def start(self) -> None:
        import dataclasses

        from ncgate.gateway.sim import ScriptPlayer

        gw, script = self.gw, self.script
        runtime, engine = gw.runtime, gw.runtime.engine
        main = runtime.config.nc.main
        if not main:
            raise InputRefused(Reason.NOT_CONFIGURED, f"run --script {script.file}: the "
                               "scenario starts the main program, and nc.main names none")
        starts = runtime.store.channels(main) or (1,)  # an ISG file: each section's channel
        source = Source(SourceKind.SCRIPT, "start")
        for number in starts:  # each read first: the starts then act at one instant
            await gw.prepare(Start(main, number, source))
        begun: asyncio.Future[float] = asyncio.get_running_loop().create_future()

        def begin() -> None:
            """At a scan's instant, after the plant's tick and before the scan (a *first*
            timer), as sim's t = 0: the programs start, the expectations watch from there,
            and the entries due at 0 act -- each first at the instant, after what the one
            before made runnable."""
            if begun.done():  # (stopped meanwhile: cancelled)
                return
            try:
                for number in starts:
                    gw.door.apply_first(Start(main, number, source))
            except InputRefused as exc:
                begun.set_exception(exc)
                return
            t0 = engine.now
            self.expectations.start(t0)
            entries = tuple(e if e.at is None else dataclasses.replace(e, at=t0 + e.at)
                            for e in script.entries)
            ScriptPlayer(runtime, dataclasses.replace(script, entries=entries),
                         gw.door).arm(first=True)
            begun.set_result(t0)

        # The scenario's 0 is the next instant the cell's scans share (sim's 0 is one), so
        # that each PLC reaction comes the scans after it that it comes in sim: started
        # between two scans, a reaction came 0..10 ms later than sim's, and a window sim
        # passed at its edge failed.  A stop meanwhile (Ctrl-C, SIGTERM) starts nothing.
        grid = scan_grid_s(runtime.config)
        now = engine.read_time()
        at = now if grid is None else (grid_index(now, grid, math.floor) + 1) * grid
        timer = engine.call_at(at, begin, first=True)
        log.info("scenario %s: starts at %.3f s of machine time, the next instant its scans "
                 "share", script.file, at)
        stopped = asyncio.ensure_future(self.stop.wait())
        try:
            await asyncio.wait((begun, stopped), return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopped.cancel()
        if not begun.done():
            timer.cancel()
            begun.cancel()
            log.info("scenario %s: stopped before its start", script.file)
            return
        t0 = begun.result()
        self.started = True
        where = f"P{starts[0]} {main}" if len(starts) == 1 else f"{main} in " + ", ".join(
            f"P{n}" for n in starts)
        log.info("scenario %s: %d expectations; %s started at %.3f s of machine time, the "
                 "scenario's t = 0", script.file, len(script.expects), where, t0)
        if self.horizon is not None:
            self._end = engine.call_at(t0 + self.horizon, self._ended)
            log.info("scenario %s: ends at its t = %.3f s", script.file, self.horizon)
        elif script.expects:
            log.info("scenario %s: its expectations are all 'always': it runs until Ctrl-C "
                     "(or SIGTERM), and is judged over that", script.file)

    def _ended(self) -> None:
        self.reached = True
        self.stop.set()

    def finish(self) -> int:
        if self._end is not None:
            self._end.cancel()
        if not self.started:  # judged over nothing: each window "not reached", at t = 0
            self.expectations.start()
        self.expectations.stop()
        # Judged up to the scenario's end when the run got there (the loop may take a moment
        # more to stop), else up to where it was stopped.
        end = self.horizon if self.reached else None
        verdicts = self.expectations.verdicts(end)
        out = stdout()  # (`run --script S | head -1`: the status is still the verdicts')
        for v in verdicts:
            print(v.line(), file=out, flush=True)
        ok = all(v.ok for v in verdicts)
        late = self.late()
        note = ""
        if late and not ok:
            # A FAIL of a machine too busy to keep the time scale blamed the cell (a hostile
            # try: coolant_wire_mended on a loaded host, 39 scans skipped).
            note = (f"note: {late}: a FAIL may be this machine's load, not the cell's "
                    "(ncgate sim runs the same scenario on the virtual clock)")
            print(f"ncgate run: {note}", file=sys.stderr, flush=True)
        if self.junit is not None:
            from ncgate.gateway.scenario import save_junit

            path, name = self.junit
            try:
                save_junit(path, [(name, verdicts)], {name: note} if note else None)
            except OSError as exc:  # (the folder was checked at the start: gone since)
                print(f"ncgate run: --junit {path}: {exc.strerror or exc}", file=sys.stderr,
                      flush=True)
                return 1
        return 0 if ok else 1

    def late(self) -> str:
        """What of the run was late on the wall clock, in words ("" if nothing was)."""
        gw = self.gw
        said = []
        if gw.max_lag_s >= LATE_SAID_S:
            said.append(f"the engine fell up to {gw.max_lag_s:.3f} s of machine time behind "
                        f"the clock (nc.time_scale {gw.config.nc.time_scale:g})")
        plc = gw.plc_status
        if plc is not None and plc.overruns:
            said.append(f"{plc.overruns} PLC scan{'s' if plc.overruns != 1 else ''} not run "
                        "(overruns)")
        return " and ".join(said)


async def _play(gw: Gateway, script: Script, stop: asyncio.Event,
                junit: tuple[Path, str] | None = None) -> _Scenario:
    scenario = _Scenario(gw, script, stop, junit)
    await scenario.start()
    return scenario
