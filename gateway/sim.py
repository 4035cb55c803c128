"""``ncgate sim``: a closed simulation on the virtual clock (spec 4.1, 2.5, 4.3).

MAIN runs in process 1; the script plays the PLC; the run ends when every process is idle,
at ``--until``, or with a stall (nothing runnable, no timer, no scripted input left).  With
``--until``, idle processes do not end the run while the PLC logic runs or a scripted input is
still to come: the PLC may press cycle start for the next part (docs/decisions.md).
"""

from __future__ import annotations

import dataclasses
import functools
import io
import random
import signal
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TextIO

from ncgate.config import Config, ConfigError
from ncgate.config.script import Script, ScriptEntry
from ncgate.errors import InputRefused, Reason
from ncgate.gateway.door import Door
from ncgate.gateway.errors import UsageError
from ncgate.gateway.plc import (
    prepare_logic,
    start_plant_logic,
    start_plc,
    warn_shared_writes,
)
from ncgate.gateway.scenario import (
    Expectations,
    Verdict,
    never_changes,
    seconds,
    unknown_name,
)
from ncgate.gateway.wiring import (
    ImageVar,
    Runtime,
    build_runtime,
    parse_assignment,
    parse_condition,
    start_plant,
)
from ncgate.inputs import (
    Break,
    ClearFault,
    Command,
    CommandKind,
    Fault,
    Override,
    Snd,
    Source,
    SourceKind,
    Start,
    Var,
    Write,
)
from ncgate.interpreter.diagnostics import ProgramError, ProgramNotFoundError
from ncgate.interpreter.dialects import comparison
from ncgate.interpreter.engine import Engine, Process, ProcessState, run_virtual
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.breaks import parse_breakpoint
from ncgate.interpreter.engine.events import Event
from ncgate.interpreter.engine.trace import EventDict, write_jsonl
from ncgate.plc.image import PlcError
from ncgate.plc.scan import PlcState

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


@dataclass
class SimResult:
    outcome: str  # "idle", "until", "stall", "alarm", "interrupted"
    exit_status: int
    runtime: Runtime
    plc_alarms: int = 0  # alarms of the PLC/fieldbus side (process 0: AL160, a PLC fault)
    interrupted_by: str = ""  # "Ctrl-C" or "SIGTERM" when the outcome is "interrupted"
    verdicts: list[Verdict] = dataclasses.field(default_factory=list)  # the script's [[expect]]
    scenario_end: bool = False  # it ran to its scenario's last window (no --until given)

    @property
    def alarms(self) -> int:
        """Every alarm of the run, the processes' and the PLC's."""
        return self.plc_alarms + sum(p.stats.alarms
                                     for p in self.runtime.engine.processes.values())

    @property
    def events(self) -> list[EventDict]:
        return self.runtime.trace.events


@dataclass(frozen=True, slots=True)
class StateTrigger:
    process: int
    state: ProcessState


@dataclass(frozen=True, slots=True)
class CondTrigger:
    var: ImageVar
    op: str
    value: int


SIM = Source(SourceKind.SCRIPT)  # the programs `ncgate sim` starts at t = 0


class ScriptPlayer:
    """Feeds the script's writes and SNDs into the runtime at their times."""

    def __init__(self, runtime: Runtime, script: Script, door: Door,
                 extra: Sequence[ScriptEntry] = ()) -> None:
        """``extra``: entries of the config's own (``[[plant.fault]]``), played the same way."""
        self.runtime = runtime
        self.script = script
        self.door = door
        self.entries = (*extra, *script.entries)
        self._state_watch: list[tuple[StateTrigger, ScriptEntry]] = []
        self.due = 0  # entries armed on the clock and not fired yet
        self._unfired: list[ScriptEntry] = []  # (filled by arm: what may still come)
        for entry in self.entries:
            self._validate(entry)
        runtime.engine.state_listeners.append(self._on_state)

    def _fail(self, entry: ScriptEntry, key: str, message: str) -> ConfigError:
        file = self.script.file
        if entry.key.startswith("plant."):
            file = str(self.runtime.config.source or "<config>")
        return ConfigError(f"{file}: {entry.key}.{key}: {message}")

    def _fault(self, entry: ScriptEntry) -> Fault | ClearFault:
        f = entry.fault
        assert f is not None
        # The config's faults come with the plant: a replay arms them again, unrecorded.
        source = Source(SourceKind.PLANT if entry.key.startswith("plant.") else
                        SourceKind.SCRIPT, entry.key)
        if f.clear:
            return ClearFault(None if f.target == "*" else f.target, source)
        assert f.kind is not None
        return Fault(f.target, f.kind, f.params, f.for_s, source)

    def _validate(self, entry: ScriptEntry) -> None:
        config = self.runtime.config
        if entry.set is not None:
            try:
                self._write(entry)
            except (ValueError, InputRefused) as exc:
                raise self._fail(entry, "set", str(exc)) from None
        if entry.sender is not None:
            if entry.sender not in config.nc.external:
                raise self._fail(entry, "from", f"process {entry.sender} is not external "
                                 "(declare it with [[nc.process]] external = true)")
            if not 1 <= (entry.target or 0) <= config.nc.processes:
                raise self._fail(entry, "to", f"process {entry.target} is not configured")
        if entry.point is not None:
            try:
                parse_breakpoint(entry.point)
            except ValueError as exc:
                raise self._fail(entry, "point", str(exc)) from None
        if entry.command is not None:
            kinds = {k.label: k for k in CommandKind}
            if entry.command not in kinds:
                raise self._fail(entry, "command", f"unknown command {entry.command!r} "
                                 f"({', '.join(kinds)})")
        if entry.process is not None and not 1 <= entry.process <= config.nc.processes:
            raise self._fail(entry, "process", f"process {entry.process} is not configured")
        if entry.fault is not None:
            plant = self.runtime.plant
            item = self._fault(entry)
            try:
                if isinstance(item, ClearFault):
                    # A clear of a name nothing could target is a typo: refused now, as the
                    # console refuses it, not a hazard in a run whose verdicts then pass.
                    if plant is not None:
                        plant.clear(item)
                elif plant is None:
                    raise InputRefused(Reason.NOT_CONFIGURED, "no plant runs here")
                else:
                    plant.check(item)
            except InputRefused as exc:
                raise self._fail(entry, "target", str(exc)) from None
        if entry.when is not None:
            self._parse_when(entry)

    def _parse_when(self, entry: ScriptEntry) -> StateTrigger | CondTrigger:
        text = entry.when or ""
        words = text.split()
        if len(words) == 2 and words[0][:1].upper() == "P" and words[0][1:].isdigit():
            state_name = words[1].upper()
            if state_name not in ProcessState.__members__:
                names = ", ".join(ProcessState.__members__)
                raise self._fail(entry, "when", f"unknown state {words[1]!r} ({names})")
            number = int(words[0][1:])
            if not 1 <= number <= self.runtime.config.nc.processes:
                raise self._fail(entry, "when", f"process {number} is not configured")
            return StateTrigger(number, ProcessState[state_name])
        try:
            var, op, value = parse_condition(self.runtime.resolve(text))
            self.runtime.image.read(*var)
        except (ValueError, PlcError) as exc:
            raise self._fail(entry, "when", unknown_name(text, self.runtime.config.symbols)
                             or str(exc)) from None
        never = never_changes(self.runtime.image, var, value)
        if never is not None:
            raise self._fail(entry, "when", never)
        return CondTrigger(var, op, value)

    def may_start(self, n: int) -> bool:
        """A scripted input still to come may start a program in process ``n`` -- an
        operator's start, which the orphan check of a wait on ``n`` takes into account: a
        cycle start of ``n`` (or of the cell, for process 1) with a main program to start,
        and, with PLC logic, a write (the logic's NC.START may read it) for process 1."""
        engine = self.runtime.engine
        for entry in self._unfired:
            if entry.command == "cycle_start" and engine.main_of(n) and (
                    entry.process == n or (entry.process is None and n == 1)):
                return True
            if entry.set is not None and n == 1 and self.runtime.plc is not None and (
                    engine.settings.main is not None):
                return True
        return False

    def arm(self, first: bool = False) -> None:
        """Arm every entry on the clock, late: it acts after every other timer of its time
        (a PLC scan of that instant, the plant's tick), as a replay of the session applies
        it, a recorded input (docs/decisions.md).  An entry due as it is armed (its ``at``
        not past the engine's now, or its ``when`` holding with no ``after``: the
        scenario's t = 0) acts as the scenario starts, before any scan sees the program
        run, as in a replay: a plain timer of now, armed before the PLC's first scan
        (``run_sim`` arms the player before it starts the PLC), which fires once what the
        start made runnable has run.  ``first`` (``run --script``, armed by the timer that
        starts the program at a scan's instant): a *first* timer, applied first
        (``Door.apply_first``), so that it acts before that scan -- as its record's replay
        applies it."""
        engine = self.runtime.engine
        self._unfired = list(self.entries)
        for entry in self.entries:
            if entry.at is not None:
                self.due += 1
                now = entry.at <= engine.now
                engine.call_at(entry.at, functools.partial(self._fire, entry, first and now),
                               late=not now, first=first and now)
                continue
            trigger = self._parse_when(entry)
            if isinstance(trigger, StateTrigger):
                if engine.processes[trigger.process].state is trigger.state:
                    # (holds already: it fires now, and once -- watched too, it fired again
                    # as the process came back to the state)
                    self._triggered(entry, late=entry.after > 0,
                                    first=first and entry.after == 0)
                else:
                    self._state_watch.append((trigger, entry))
            else:
                area, index, view = trigger.var
                handle = self.runtime.image.wait(area, index, view,
                                                 comparison(trigger.op, trigger.value),
                                                 functools.partial(self._triggered, entry))
                if handle is None:  # (holds already: due as armed, as an `at` of now)
                    self._triggered(entry, late=entry.after > 0,
                                    first=first and entry.after == 0)

    def _on_state(self, process: Process, old: ProcessState) -> None:
        for watch in list(self._state_watch):
            trigger, entry = watch
            if trigger.process == process.number and trigger.state is process.state:
                self._state_watch.remove(watch)
                self._triggered(entry)

    def _triggered(self, entry: ScriptEntry, late: bool = True, first: bool = False) -> None:
        engine = self.runtime.engine
        self.due += 1
        engine.call_at(engine.now + entry.after, functools.partial(self._fire, entry, first),
                       late=late, first=first)

    def _write(self, entry: ScriptEntry) -> Write:
        """The entry's ``set`` as an input, checked against the image (not applied)."""
        (area, index, view), value = parse_assignment(self.runtime.resolve(entry.set or ""))
        item = Write(Var(area, index, view), value, Source(SourceKind.SCRIPT, entry.key))
        self.door.image_changes(((item.var, item.value),))
        return item

    def _fire(self, entry: ScriptEntry, first: bool = False) -> None:
        self.due -= 1
        if entry in self._unfired:
            self._unfired.remove(entry)
        source = Source(SourceKind.SCRIPT, entry.key)
        try:
            # At the entry's own time, on the wall clock too (run --script): a scenario's
            # times are the machine's, as in sim.
            apply = self.door.apply_first if first else self.door.apply_on_time
            if entry.set is not None:
                apply(self._write(entry))
            elif entry.fault is not None:
                apply(self._fault(entry))
            elif entry.command is not None:
                kind = next(k for k in CommandKind if k.label == entry.command)
                apply(Command(kind, entry.process, source))
            elif entry.point is not None:
                apply(Break(entry.point, entry.on, source))
            elif entry.feed is not None or entry.rapid is not None:
                apply(Override(entry.feed, entry.rapid, entry.process, source))
            else:
                assert entry.sender is not None and entry.target is not None
                apply(Snd(entry.sender, entry.target, source))
        except InputRefused as exc:
            self.runtime.engine.note_hazard(entry.sender or 0, f"script {entry.key}: {exc}")


def _require_end(script: Script, until: float | None) -> None:
    """A scenario of ``always`` expectations alone has no end of its own in ``sim``: run to the
    cell idle, a program that loops never ended, and a PLC's last change came a scan after
    the end.  It needs ``--until``."""
    if script.expects and script.horizon is None and until is None:
        raise ConfigError(f"{script.file}: expect: every expectation is 'always', which gives "
                          "the scenario no end in sim: give one a window (by = T), or run "
                          "it with --until T")


def check_scenario(config: Config, script: Script, *, until: float | None = None,
                   sim: bool = True) -> None:
    """Refuse (ConfigError) what :func:`run_sim` (``sim``; else ``run --script``) would refuse
    of ``script`` on this cell -- its entries, faults and conditions -- without running it:
    with several ``--script``s each is checked before the first runs (a bad third one was
    found after two had run, and no ``--junit`` was written)."""
    if sim:
        _require_end(script, until)
    script = timed_script(script, config)
    runtime = build_runtime(config, closed=True)
    door = Door(runtime, lambda: runtime.plc)
    start_plant(runtime, door.apply_on_time, closed=True)
    ScriptPlayer(runtime, script, door, plant_faults(config))
    Expectations(runtime, script)


def run_sim(config: Config, main: str | Sequence[str], script: Script,
            until: float | None = None, *, signals: bool = False,
            single_block: bool = False, breaks: Sequence[str] = (),
            keep_going: bool = False, at: str | None = None,
            with_calc: bool = False,
            before_time: Callable[[float], None] | None = None,
            warn: bool = True) -> SimResult:
    """Run a closed simulation: ``main`` in process 1, or each of several programs in its own
    process (1, 2, 3, ... as the operator's SPG starts them, manual section 4 (2)); in the ISG
    dialect one sectioned file starts each section in its channel.

    ``before_time`` is called with each time the clock is about to move to (``ncgate sweep``
    stops a variant past its virtual-time budget by raising from it).  ``warn``: say the
    warnings of the cell's logic, SW001..SW006 (a scenario suite says them with its first
    scenario only).

    Ctrl-C (KeyboardInterrupt) ends the run early with what happened so far; with
    ``signals`` (the command line, in the main thread) SIGTERM does the same for the run.

    Raises ProgramError/ProgramNotFoundError if a program cannot start, UsageError if one
    cannot run in its process (too many programs, an external process)."""
    mains = [main] if isinstance(main, str) else list(main)
    processes = config.nc.processes
    if len(mains) > processes:
        raise UsageError(f"{len(mains)} programs for {processes} processes")
    script = timed_script(script, config)
    runtime = build_runtime(config, closed=True)
    door = Door(runtime, lambda: runtime.plc)
    start_plant(runtime, door.apply_on_time, closed=True)
    player = ScriptPlayer(runtime, script, door, plant_faults(config))
    expectations = Expectations(runtime, script)
    engine = runtime.engine
    _require_end(script, until)
    horizon = script.horizon if script.expects else None
    to_horizon = until is None and horizon is not None
    if to_horizon:
        until = horizon  # a scenario runs until its last window closes
    if single_block:  # every process stops after each block: the script's steps go on
        door.apply(Command(CommandKind.SINGLE_BLOCK_ON, None, SIM))
    for point in breaks:  # --break: refused ones are usage errors
        try:
            door.apply(Break(point, True, SIM))
        except InputRefused as exc:
            raise UsageError(f"--break {point}: {exc}") from None
    if keep_going:  # --continue: each hit is traced, then the cell goes on at once

        def go_on(event: Event) -> None:
            if isinstance(event, ev.Break):
                engine.call_at(engine.now, lambda: door.apply(
                    Command(CommandKind.CYCLE_START, None, SIM)))

        runtime.trace.subscribe(go_on)
    if len(mains) == 1:
        # Spec 5.1 (ISG): one sectioned file starts every section in its channel at t = 0.
        starts = [(mains[0], channel) for channel in runtime.store.channels(mains[0]) or (1,)]
    else:
        starts = [(name, number) for number, name in enumerate(mains, start=1)]
    for i, (name, number) in enumerate(starts):
        try:  # --at: a block search of the first program
            door.apply(Start(name, number, SIM, at if i == 0 else None, with_calc))
        except InputRefused as exc:  # the program's own error, with its diagnostics
            if isinstance(exc.__cause__, ProgramError | ProgramNotFoundError):
                raise exc.__cause__ from None
            raise UsageError(str(exc)) from None
    plc_alarms = 0

    def count_plc_alarm(event: Event) -> None:
        nonlocal plc_alarms
        if isinstance(event, ev.Alarm) and event.proc == 0:
            plc_alarms += 1

    runtime.trace.subscribe(count_plc_alarm)
    expectations.start()
    player.arm()  # (before the PLC starts: its entries at t = 0 act before the first scan)
    # Every input of a sim is an engine timer, so still scans may be leapt over -- but not
    # under before_time, which hears each time the clock moves to (a budget acts there).
    leap = before_time is None
    drivers = [started[1] for started in (
        start_plc(config, runtime, door, closed=True, leap=leap,
                  prepared=prepare_logic(config, "plc", warn=warn)),
        start_plant_logic(config, runtime, door, closed=True, leap=leap,
                          prepared=prepare_logic(config, "plant", warn=warn))) if started]
    if warn:
        plant_logic = runtime.plant.logic if runtime.plant is not None else None
        warn_shared_writes(config, runtime.plc.logic if runtime.plc else None,
                           plant_logic.logic if plant_logic else None)

    def logic_runs() -> bool:
        """An ST task runs (the PLC's, or the plant's: either may press NC.START)."""
        plant = runtime.plant
        return any(logic is not None and logic.status.state is PlcState.RUNNING for logic in (
            runtime.plc, plant.logic if plant is not None else None))

    def active() -> bool:
        """Something may still start a program: an ST task's scan, a scripted input."""
        return player.due > 0 or logic_runs() \
            or (horizon is not None and engine.now < horizon) \
            or (runtime.plant is not None and runtime.plant.moving)

    def plc_may_start(n: int) -> bool:
        """An ST task's NC.START is a cycle start: nc.main in process 1 (orphan check)."""
        return n == 1 and engine.settings.main is not None and logic_runs()

    engine.sync.outside_starts = lambda n: plc_may_start(n) or player.may_start(n)

    previous: Any = None
    try:
        if signals:  # installed inside the try: a SIGTERM from now on is always reported
            previous = signal.signal(signal.SIGTERM, _terminated)
        try:
            outcome = _run_to_end(engine, until, active, before_time)
        finally:
            for driver in drivers:
                driver.settle()
    except KeyboardInterrupt as exc:  # what happened so far is still reported and written
        engine.finish_stats()
        by = "SIGTERM" if isinstance(exc, Terminated) else "Ctrl-C"
        return SimResult("interrupted", EXIT_FAILED, runtime, plc_alarms, by,
                         expectations.verdicts())
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    # Nothing can change any more: the windows close as they stood -- up to the scenario's
    # end, or --until's when it comes first (a run stopped there saw no further).
    end = horizon if horizon is None or until is None else min(horizon, until)
    if end is not None and engine.now < end:
        engine.set_time(end)
    engine.finish_stats()
    process_alarms = any(p.stats.alarms for p in engine.processes.values())
    if outcome == "blocked" and engine.blocked():
        engine.record_stall()
        result = SimResult("stall", EXIT_FAILED, runtime, plc_alarms)
    elif process_alarms:  # "blocked" with nobody blocked: every process left is in ALARM
        result = SimResult("alarm", EXIT_FAILED, runtime, plc_alarms)
    else:  # Any alarm is exit 1 (README): a PLC fault (AL160) is one, though no process stopped
        result = SimResult(outcome, EXIT_FAILED if plc_alarms else EXIT_OK, runtime, plc_alarms)
    if script.expects:  # a scenario: its verdicts decide (a bad case may expect an alarm)
        result.scenario_end = to_horizon
        expectations.stop()
        result.verdicts = expectations.verdicts()
        result.exit_status = EXIT_OK if all(v.ok for v in result.verdicts) else EXIT_FAILED
    return result


def timed_script(script: Script, config: Config) -> Script:
    """The script with its inputs' times as ``[sim]`` has them: each ``at`` (or ``after``, past
    its ``when``) times ``input_delay_scale``, plus a draw of 0..``input_jitter_ms`` from
    ``seed``, one per entry in the script's order.  Its expectations keep their windows."""
    sim = config.sim
    if sim.input_delay_scale == 1.0 and not sim.input_jitter_ms:
        return script
    draws = random.Random(sim.seed)
    entries = []
    for entry in script.entries:
        late = draws.uniform(0.0, sim.input_jitter_ms / 1000.0) if sim.input_jitter_ms else 0.0
        if entry.at is not None:
            entries.append(dataclasses.replace(entry, at=entry.at * sim.input_delay_scale + late))
        else:
            entries.append(dataclasses.replace(
                entry, after=entry.after * sim.input_delay_scale + late))
    return dataclasses.replace(script, entries=tuple(entries))


def plant_faults(config: Config) -> list[ScriptEntry]:
    """``[[plant.fault]]`` as entries a script player plays: at a time, on a condition, or
    (neither) at the start."""
    return [ScriptEntry(f.key, f.at if f.at is not None else (0.0 if f.when is None else None),
                        f.when, f.after, fault=f) for f in config.plant.fault]


class Terminated(KeyboardInterrupt):
    """SIGTERM during ``run_sim(signals=True)``: the run ends as it does on Ctrl-C."""


def _terminated(signum: int, frame: object) -> None:
    raise Terminated


def _run_to_end(engine: Engine, until: float | None, active: Callable[[], bool],
                before_time: Callable[[float], None] | None = None) -> str:
    """``run_virtual``, except that with ``until`` every process being idle does not end the
    run while ``active()``: the clock moves on to the next timer (the PLC's next scan, the
    next scripted input), which may start a program again."""
    while True:
        outcome = (run_virtual(engine, until) if before_time is None
                   else run_virtual(engine, until, before_time))
        if outcome != "idle" or until is None or not active():
            return outcome
        t = engine.next_timer()
        if t is None:
            return outcome
        if t > until:
            engine.set_time(until)
            return "until"
        if before_time is not None:
            before_time(t)
        engine.advance_to(t)


def summary_table(result: SimResult) -> str:
    engine = result.runtime.engine
    header = ("proc", "programs", "blocks", "running s", "waiting s", "moving s", "snd sent",
              "snd recv", "alarms", "state")
    rows: list[Sequence[str]] = [header]
    for p in engine.processes.values():
        s = p.stats
        state = p.state.name + (" (external)" if p.external else "")
        rows.append((f"P{p.number}", str(s.programs), str(s.blocks), f"{s.running_s:.3f}",
                     f"{s.waiting_s:.3f}", f"{s.moving_s:.3f}", str(s.snd_sent),
                     str(s.snd_received), str(s.alarms), state))
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    out = io.StringIO()
    for i, row in enumerate(rows):
        out.write("  ".join(c.rjust(w) if j else c.ljust(w)
                            for j, (c, w) in enumerate(zip(row, widths, strict=True))).rstrip())
        out.write("\n")
        if i == 0:
            out.write("  ".join("-" * w for w in widths) + "\n")
    return out.getvalue()


HAZARD_LINES = 20  # distinct hazards the summary lists; the trace has them all


def report(result: SimResult, out: TextIO) -> None:
    engine = result.runtime.engine
    hazards: dict[tuple[object, ...], list[EventDict]] = {}
    for event in result.events:
        if event["event"] in ("alarm", "stall", "deadlock"):
            out.write(_describe(event) + "\n")
        elif event["event"] == "hazard":
            key = (event["proc"], event.get("prog"), event.get("line"), event["message"])
            hazards.setdefault(key, []).append(event)
    for i, same in enumerate(hazards.values()):
        if i == HAZARD_LINES:
            out.write(f"... {len(hazards) - HAZARD_LINES} more hazards in the trace\n")
            break
        first = same[0]
        where = f" {first['prog']}:{first['line']}" if first.get("prog") else ""
        n = f" N{first['n']}" if first.get("n") is not None else ""
        times = f" ({len(same)} times)" if len(same) > 1 else ""
        out.write(f"[{first['t']:.3f}] P{first['proc']} hazard{where}{n}: "
                  f"{first['message']}{times}\n")
    out.write(summary_table(result))
    alarms = result.alarms
    until = "the scenario's last window closed" if result.scenario_end else "stopped at --until"
    verdict = {"idle": "every program ended", "until": until,
               "stall": "stall", "alarm": "ended with alarms",
               "interrupted": f"interrupted ({result.interrupted_by})"}[result.outcome]
    if alarms and result.outcome != "alarm":
        verdict += f", {alarms} alarm{'s' if alarms > 1 else ''}"
    out.write(f"simulated {seconds(engine.now)} s: {verdict}\n")
    for v in result.verdicts:
        out.write(v.line() + "\n")


def _describe(event: EventDict) -> str:
    t = f"{event['t']:.3f}"
    if event["event"] == "alarm":
        where = f" {event['prog']}:{event['line']}" if event.get("prog") else ""
        who = f"P{event['proc']}" if event["proc"] else "PLC"  # process 0: the PLC's side
        return f"[{t}] {who} alarm {event['code']}{where}: {event['message']}"
    if event["event"] == "deadlock":
        return f"[{t}] {event['message']}"
    lines = [f"[{t}] stall: every process is blocked and nothing can change"]
    for b in event["blocked"]:
        n = f" N{b['n']}" if b["n"] is not None else ""
        lines.append(f"    P{b['proc']} {b['prog']}:{b['line']}{n} {b['reason']}")
    return "\n".join(lines)


def write_trace(result: SimResult, out: TextIO) -> None:
    write_jsonl(result.events, out)
