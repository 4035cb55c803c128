"""The engine: processes, the run queue, the decoder and interpolator loops, waits and alarms.

The :class:`Engine` is synchronous and deterministic.  It owns the processes, a timer heap and
a run queue; it never sleeps and never reads a clock.  A driver decides when time passes: the
virtual clock (``clock.run_virtual``, ``ncgate sim``) runs everything runnable, then jumps to
the next timer; the gateway's wall-clock driver arms one loop timer for the next engine timer
and runs the engine whenever something outside (a fieldbus write) made work runnable.

Each process is a two-stage pipeline (spec 2.4): a *decoder* that runs a program's blocks in
order, as decoder ops compiled by the dialect's front end (:class:`~.ports.FrontEnd`), and
turns motion into items of a bounded *motion queue*; and an *interpolator* that executes those
items in simulated time.  A ``#`` block is queued as one item whose actions act when the
interpolator reaches it.

The rooms: ``states`` (enums and records), ``process`` (one process), ``timers``, ``actions``
(what compiled blocks hand over), ``sync`` (the EXE/REL/WAI/SND rules, a part the engine owns),
``deadlock`` (the pure search), ``events``/``trace`` (what happened), ``clock`` (the virtual
clock), ``ports`` (what the engine needs, and what a front end may ask of it), ``aux`` (the
auxiliary functions and their handshake with the PLC, a part the engine owns when
``[nc.aux]`` is configured).

Must not import ``plc``, ``gateway``, ``config`` or any front end.
"""

from __future__ import annotations

import functools
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from ncgate.interpreter.cache import block_table
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import ProgramError, ProgramNotFoundError, RuntimeAlarm
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.actions import (
    Action,
    Execute,
    ItemKind,
    Motion,
    Send,
    ShowText,
    Step,
    WaitCondition,
    WaitProcess,
    WriteSyvar,
)
from ncgate.interpreter.engine.aux import AuxInterface, AuxOutput
from ncgate.interpreter.engine.breaks import Breakpoint
from ncgate.interpreter.engine.events import Blocked, FlushOn, WaitOn
from ncgate.interpreter.engine.ports import FrontEnd, ImagePort, ProgramLoader, ProgramText
from ncgate.interpreter.engine.process import CompiledBlock, LoadedProgram, Process, QueueItem
from ncgate.interpreter.engine.states import (
    ALLOWED,
    RUNNING_STATES,
    WAITING_STATES,
    DecoderHold,
    ProcessState,
    ProcessStatus,
    Stage,
    WaitKind,
    WaitRecord,
    Where,
    derive_state,
    describe_where,
)
from ncgate.interpreter.engine.sync import Sync, first_line
from ncgate.interpreter.engine.timers import Timer, TimerHeap
from ncgate.interpreter.engine.trace import Trace
from ncgate.interpreter.motion import Modal
from ncgate.interpreter.settings import RuntimeSettings

NEXT, WAIT_NEXT, WAIT_RETRY, JUMP = Step.NEXT, Step.WAIT_NEXT, Step.WAIT_RETRY, Step.JUMP
ActionHandler = Callable[[Process, Stage, Any, Where], bool]
# A stop after a block as the stall report words its cause (Process.stopped).
_STOPS = {"single_block": "single block", "step": "a step", "M00": "M00", "M01": "M01",
          "break": "a breakpoint"}
_new = tuple.__new__  # a NamedTuple without its generated __new__ (the SND/WAI hot path)


def _held(p: Process) -> str:
    """"held since 1.010 s (feed hold by plc plc.st:41)": who holds ``p``, since when."""
    return f"held since {p.held_since:.3f} s ({p.held_by or 'a feed hold'})"


class Engine:
    """Processes, their synchronisation, the motion queues and the timer heap."""

    def __init__(self, settings: RuntimeSettings, image: ImagePort, loader: ProgramLoader,
                 front_end: FrontEnd, trace: Trace | None = None) -> None:
        self.settings = settings
        self.image = image
        self.loader = loader
        self.front_end = front_end
        self.trace = trace if trace is not None else Trace()
        self._record = self.trace.record  # bound once: every SND and WAI records
        self.now = 0.0
        self._wait_timeout_s = settings.wait_timeout_s
        self.processes = {
            k: Process(k, k in settings.external, settings.e_params)
            for k in range(1, settings.processes + 1)
        }
        for p in self.processes.values():
            p.feed_override = settings.feed_override
        self._timers = TimerHeap()
        self._runnable: deque[Process] = deque()
        self._running = False
        self._unfinished = False  # a run limited in blocks left work at the current time
        self._decoded = 0  # blocks decoded, all processes
        self._epoch = 0  # counts the moments the engine stood still (runaway detection)
        self._block_time = settings.block_time_ms / 1000.0
        # ISG's buffer effect (spec 5.4): the interpolator takes a block only from a full
        # buffer, or once the decoder has reached the end, a flush or a synchronous read.
        self._buffered = settings.buffered and settings.lookahead > 0
        # By (file, process): the latest version of each, with its compiled blocks.
        self._loaded: dict[tuple[str, int], LoadedProgram] = {}
        self.last_change = 0.0  # the time of the last state change or image write
        # The operator's switches: M01 stops only while optional stop is on; a block marked
        # "/" is skipped while block skip is on (nc.optional_skip is its initial position).
        self.optional_stop = False
        self.block_skip = settings.optional_skip
        # Breakpoints (breaks.py): the decoder looks at block ones only when there are any.
        self.breakpoints: list[Breakpoint] = []
        self._block_breaks = False
        self._wait_breaks = False
        self._sync_listener: Callable[[], None] | None = None
        # The EXE/REL/WAI/SND rules and their state (sync.py): a part, not a base class.  The
        # SND/WAI hot path calls it directly (the front end binds wait_process and send once).
        self.sync = sync = Sync(self)
        self.wait_process = sync.wait_process
        self.send = sync.send
        # Actions by type: what a compiled block may ask the engine to do.  A dialect's own
        # actions come in through register_action.
        self._actions: dict[type, ActionHandler] = {
            WriteSyvar: self._do_write_syvar,
            WaitProcess: lambda p, s, a, w: sync.wait_process(p, s, a.process, a.code, w),
            WaitCondition: sync.wait_condition,
            Send: lambda p, s, a, w: sync.send(p, s, a.process, a.code, w),
            Execute: sync.execute,
            ShowText: self._show_text,
        }
        # The auxiliary functions' handshake with the PLC ([nc.aux]; aux.py), when configured.
        aux = settings.aux_interface
        self.aux = AuxInterface(self, aux, settings.processes) if aux is not None else None
        if self.aux is not None:
            self._actions[AuxOutput] = self.aux.output
        # Hooks for drivers and the gateway.
        self.on_kick: Callable[[], None] | None = None  # work became runnable from outside
        self.on_timer: Callable[[float], None] | None = None  # a timer was armed
        # The periodic tasks on this engine's timers (the ST tasks' scan drivers,
        # gateway/plc.py): a closed run is a stall when nothing but they is left.
        self.periodic: list[Any] = []
        # The driver's say on when a turn has taken long enough (the wall clock's: timers
        # differ in weight -- a dwell's is a few blocks, a plant model's a write through the
        # door -- so a count of them does not bound a turn); None: only ``blocks`` does.
        self.turn_over: Callable[[], bool] | None = None
        # The driver's clock, for what a status read shows between the engine's own moments
        # (the position along a move): the engine's time moves only when something is due
        # or an input arrives.  None: the engine's own time (the virtual clock).
        self.clock: Callable[[], float] | None = None
        self.state_listeners: list[Callable[[Process, ProcessState], None]] = []
        self.reset_listeners: list[Callable[[], None]] = []  # a dialect's own state to clear

    def register_action(self, kind: type, handler: ActionHandler) -> None:
        """Teach the engine a new action (a dialect's own code): ``handler(process, stage,
        action, where)`` returns True when the action completed, False when the process
        waits."""
        self._actions[kind] = handler

    # ==== what a dialect's own actions may use (ports.BlockHost) ===============================

    # begin_wait(p, stage, wait): p's decoder or interpolator waits; finish_wait(p, wait, by)
    # ends it.  Aliases of the engine's own (below): they are on every signal's path.

    def check_wait(self, p: Process, wait: WaitRecord) -> None:
        """After a wait began: an orphan wait, or a deadlock through ``p``, is an alarm."""
        if not self.sync.check_orphan(p, wait):
            self.sync.check_deadlock(p)

    def alarm(self, p: Process, code: AlarmCode, message: str, where: Where | None) -> None:
        self._alarm(p, code, message, where)

    def record(self, kind: type[ev.Event], proc: int, where: Where | None,
               *fields: object) -> None:
        """Record a dialect's own event (``events.Signal``, ...) at the current time."""
        self._record(kind, self.now, proc, where, *fields)

    def flush_wait(self, p: Process, where: Where, code: str) -> bool:
        """The decoder waits until the interpolator has run every block decoded before
        (``#FLUSH WAIT``, a synchronous V.E. read): True when there is nothing to wait for."""
        if not p.queue and p.int_item is None:
            return True
        wait = WaitRecord(WaitKind.FLUSH, 0, code, where, self.now, Stage.DECODER,
                          on=FlushOn())
        self._begin_wait(p, Stage.DECODER, wait)
        self._interp_run(p)  # a flush opens the buffer (spec 5.4)
        return False

    # ==== public API ========================================================================

    def start(self, name: str, process: int = 1, by: str = "operator",
              device: str | None = None, at: str | None = None,
              with_calc: bool = False) -> None:
        """The operator's SPG: load NAME into an idle process and start it -- at a label or
        an N number (``at``: a block search, :meth:`block_search`)."""
        p = self._process(process)
        if p.external:
            raise ValueError(f"process {process} is external: it runs no part program")
        if p.loaded is not None or p.alarm is not None:
            raise ValueError(f"process {process} is busy ({p.state.name})")
        program = self.loader.load(name, device, process)
        found = self.block_search(program, process, at, with_calc) if at else None
        self._start_program(p, program, by)
        if found is not None:
            p.pc, p.modal, e = found
            p.actual = list(p.modal.position)
            if with_calc:
                p.E = e
        self._kick()

    def block_search(self, program: ProgramText, process: int, at: str,
                     with_calc: bool = False) -> tuple[int, Modal, list[float]]:
        """Where a start of ``program`` at ``at`` begins and with what modal state (the
        front end's block search); ValueError saying why it cannot start there."""
        p = self._process(process)
        return self.front_end.block_search(program, at, p.modal, p.E, self.settings,
                                           self.image.read, with_calc)

    def cycle_start(self, by: str = "api", process: int | None = None) -> None:
        """Command 1: resume after a feed hold, or start the main program (``by``: who gave
        the command, as its input's source says).  Of the cell (``process`` None): resume
        every held process, or start ``main`` in process 1.  Of one process: resume it if
        held, or start its own main (``[[nc.process]] main``; process 1: ``main``)."""
        held = self._any_held(process)
        for p in self._targets(process):
            p.step_once = False  # a breakpoint's pending stops: the cell goes on
            p.stop_why = None
        if held:  # a hold and a stop after a block (a breakpoint's) go on together
            self.hold(False, process)
            # A decoder that stopped ahead of the held motion (M00 after a move) keeps its
            # stop: the machine has not felt it yet, and this start was the hold's.
            self._release_steps(process, felt=True)
            return
        if self._release_steps(process):
            return
        number = 1 if process is None else process
        main = self.cycle_start_program(process)
        if main is not None:
            p = self.processes[number]
            try:
                self.start(main, number, by=by)
            except (ProgramError, ProgramNotFoundError) as exc:
                self._alarm(p, AlarmCode.PROGRAM_NOT_FOUND
                            if isinstance(exc, ProgramNotFoundError)
                            else AlarmCode.PROGRAM_INVALID, first_line(exc), None)

    def cycle_start_program(self, process: int | None = None) -> str | None:
        """The program a cycle start (of the cell, or of ``process``) would start now; None
        when it resumes a feed hold or a single block, or starts nothing."""
        targets = self._targets(process)
        if any(p.held or p.dec_block is DecoderHold.STEP for p in targets):
            return None
        number = 1 if process is None else process
        p = self.processes.get(number)
        main = self.main_of(number)
        if main and p is not None and p.loaded is None and p.alarm is None and not p.external:
            return main
        return None

    def main_of(self, process: int) -> str | None:
        """The program a cycle start of ``process`` starts: ``main`` for process 1, its own
        ``[[nc.process]] main`` for the others (None: none)."""
        return self.settings.main if process == 1 else dict(self.settings.mains).get(process)

    def _targets(self, process: int | None) -> Iterable[Process]:
        """The processes a command of the cell (None) or of one process acts on."""
        return self.processes.values() if process is None else (self.processes[process],)

    def _release_steps(self, process: int | None, only: str | None = None,
                       felt: bool = False) -> bool:
        """Processes stopped after a block (single block) run their next block: True when
        there was one.  ``only``: just those stopped for that cause (``Process.stopped``);
        ``felt``: just those whose stop the machine has felt (STEP told) or a breakpoint's."""
        targets = self._targets(process)
        released = False
        for p in targets:
            if p.dec_block is DecoderHold.STEP and (only is None or p.stopped == only) and (
                    not felt or p.stop_told or p.stopped == "break"):
                p.dec_block = None
                p.stopped = None
                p.stop_told = False
                self._update_state(p)
                self._make_runnable(p)
                released = True
        return released

    # ---- breakpoints (breaks.py) ------------------------------------------------------------

    def set_break(self, breakpoint: Breakpoint, on: bool = True) -> None:
        """Set (or, ``on`` False, clear) a breakpoint."""
        if on and breakpoint not in self.breakpoints:
            self.breakpoints.append(breakpoint)
        elif not on and breakpoint in self.breakpoints:
            self.breakpoints.remove(breakpoint)
        self._breaks_changed()

    def _breaks_changed(self) -> None:
        self._block_breaks = any(b.at_block for b in self.breakpoints)
        self._wait_breaks = any(b.wait for b in self.breakpoints)
        sync = any(b.sync for b in self.breakpoints)
        if sync and self._sync_listener is None:
            self._sync_listener = self.trace.subscribe(self._sync_event)
        elif not sync and self._sync_listener is not None:
            self._sync_listener()
            self._sync_listener = None

    def _break_at_block(self, p: Process, pc: int, where: Where) -> bool:
        """A block breakpoint on the block at ``pc``: the process stops before it (STEP)
        and the cell holds."""
        file, line, n = where
        for bp in self.breakpoints:
            if bp.at_block and bp.matches_block(p.number, file, line, n):
                p.break_passed = pc
                p.dec_block = DecoderHold.STEP
                p.stopped = "break"
                self._update_state(p)
                self._hit(bp, p.number, where)
                return True
        return False

    def _sync_event(self, event: ev.Event) -> None:
        """Run to sync: the first EXE/WAI/SND/REL/#SIGNAL/#WAIT of any process stops the
        cell -- every process after the block it is in, motion held."""
        kind = type(event)
        if not (kind in (ev.Snd, ev.Exe, ev.Wait, ev.Signal)
                or (kind is ev.End and event.how == "REL")):  # type: ignore[union-attr]
            return
        bp = next(b for b in self.breakpoints if b.sync)
        self.breakpoints.remove(bp)  # one-shot
        self._breaks_changed()
        self._hit(bp, event.proc, event.where)

    def _hit(self, bp: Breakpoint, proc: int, where: Where | None) -> None:
        """The cell stops: motion holds, and every decoder stops after the block it is in
        (a held process's decoder would otherwise go on, and its plain codes act)."""
        self._record(ev.Break, self.now, proc, where, bp.text)
        for p in self.processes.values():
            if p.loaded is not None and p.alarm is None and p.dec_block is not DecoderHold.STEP:
                if not p.step_once:
                    p.stop_why = "break"
                p.step_once = True
        self.hold(True, by=f"breakpoint {bp.text}")

    def program_stop(self, p: Process, optional: bool = False) -> None:
        """M00 (``optional``: M01, only while the optional-stop switch is on): the process
        stops after this block, its motion done (STEP), until a cycle start."""
        if not optional or self.optional_stop:
            p.step_once = True
            p.stop_why = "M01" if optional else "M00"

    def switch(self, optional_stop: bool | None = None, block_skip: bool | None = None) -> None:
        """The operator's switches.  Block skip acts on the blocks decoded from now on (the
        compiled blocks are compiled again)."""
        if optional_stop is not None:
            self.optional_stop = optional_stop
        if block_skip is not None and block_skip != self.block_skip:
            self.block_skip = block_skip
            for loaded in self._loaded.values():
                loaded.blocks = block_table(loaded.length)

    def single_block(self, on: bool, process: int | None = None) -> None:
        """Single-block mode of one process or the cell: after each block the process stops
        (STEP) until a cycle start; off, a process stopped by single block goes on.  A stop
        of M00, M01, a step or a breakpoint stays: only NC start leaves it, as on a control."""
        targets = self._targets(process)
        for p in targets:
            if not p.external:
                p.single_block = on
        if not on:
            self._release_steps(process, only="single_block")

    def step(self, process: int | None = None) -> None:
        """Exactly one more block: a process stopped after a block runs its next one and stops
        again; a running one stops after the block it is in."""
        for p in self._targets(process):
            if p.loaded is None or p.alarm is not None or p.external:
                continue
            p.step_once = True
            p.stop_why = "step"
            self._record(ev.Step, self.now, p.number, p.where)
            self._release_steps(p.number)

    def _any_held(self, process: int | None) -> bool:
        return any(p.held for p in self._targets(process))

    def hold(self, on: bool = True, process: int | None = None, by: str | None = None) -> None:
        """Feed hold (of the cell, or of one process): motion stops where it is;
        ``hold(False)`` resumes it.  ``by``: who holds (a stall report names it)."""
        targets = self._targets(process)
        for p in targets:
            if p.external or p.held == on:
                continue
            self._record(ev.Hold, self.now, p.number,
                         p.where if p.loaded is not None else None, on)
            if on:
                p.held = True
                p.held_by, p.held_since = by, self.now
                if p.int_timer is not None:
                    self._stop_motion(p)
                    p.int_remaining = self._nominal_left(p)
            else:
                p.held = False
                if p.int_remaining is not None and p.int_move is not None:
                    remaining, p.int_remaining = p.int_remaining, None
                    self._arm_item(p, p.int_move, remaining)
                else:
                    self._interp_run(p)
            self._update_state(p)
        self._kick()

    def fieldbus_alarm(self, code: AlarmCode, message: str) -> None:
        """An alarm of the PLC/fieldbus side (process 0 in the trace, spec 4.4), e.g. a master
        whose heartbeat stopped; it stops no process by itself."""
        self._record(ev.Alarm, self.now, 0, None, code, message)

    def reset(self, process: int | None = None) -> None:
        """Command 3.  Of the cell: clear every alarm, discard queues, waits and tokens;
        every process to IDLE.  Of one process: that process to IDLE (its alarm, program,
        queue, waits and E parameters), and what the others had with it as when its program
        ends (tokens to it dropped, a rendezvous SND to it an alarm, an EXE waiting for it
        starts); a dialect's stored signals stay (a reset of the cell clears them)."""
        targets = self._targets(process)
        for p in targets:
            was_busy = p.loaded is not None or p.alarm is not None
            self._cancel_pending(p)
            if process is not None:
                self.sync.forget_waiter(p)
            where = p.where
            p.clear()
            p.loaded = None
            p.alarm = None
            p.held = False
            p.E = [0.0] * p.e_params
            p.vars.clear()
            if was_busy:
                self._record(ev.End, self.now, p.number, where, "reset")
            self._update_state(p)
        if process is not None:  # (if it is in the run queue, the decoder skips it there)
            self.sync.became_free(self.processes[process])
            self._kick()
            return
        self._runnable.clear()
        for p in self.processes.values():
            p.queued = False  # (else a start after the reset would never be run)
        self.sync.clear()
        for listener in list(self.reset_listeners):
            listener()

    def run_until_blocked(self, blocks: int | None = None) -> None:
        """Run everything runnable at the current time.  With ``blocks``, stop once about
        that many blocks were decoded (at most one turn of ``slice_blocks`` more) and leave
        the rest runnable: the wall-clock driver serves the fieldbus between such runs."""
        if self._running:
            return
        runnable = self._runnable
        if not runnable:  # the common case on a timer (a scan, a plant tick): as below
            self._unfinished = False
            self._epoch += 1
            return
        self._running = True
        try:
            stop_at = None if blocks is None else self._decoded + blocks
            self._unfinished = False
            while runnable:
                if stop_at is not None and self._decoded >= stop_at:
                    self._unfinished = True
                    return
                p = runnable.popleft()
                p.queued = False
                if p.loaded is not None and p.alarm is None and p.dec_block is None:
                    self._run_decoder(p)
            # Nothing runnable: the engine stands still, time may pass.  A process that
            # decodes runaway_blocks blocks between two such moments is a runaway.
            self._epoch += 1
        finally:
            self._running = False

    def next_timer(self) -> float | None:
        return self._timers.next_time()

    @property
    def live_timers(self) -> int:
        """Timers armed and neither fired nor cancelled (counted when asked: a stall's
        question, asked once it has stood still for stall_s)."""
        return self._timers.live()

    def advance_to(self, t: float, blocks: int | None = None) -> bool:
        """Let time pass to ``t``: fire the timers due, each followed by what it made
        runnable, then run what is runnable at ``t``.

        With ``blocks`` (see :meth:`run_until_blocked`) this may stop early; it returns True
        when work is left, and the caller calls again (with the same or a later ``t``): the
        work left over runs first, before any timer."""
        if self._unfinished:
            self.run_until_blocked(blocks)
            if self._unfinished:
                return True
        # The slice counts across timers too: a dense loop of dwells is thousands of timers
        # of a couple of blocks each, and must leave the event loop free between slices.
        budget_at = None if blocks is None else self._decoded + blocks
        fired = 0
        while (timer := self._timers.pop_due(t)) is not None:
            callback = timer.callback
            assert callback is not None
            # What a timer causes happens at its time, even if the wall clock that drives
            # the engine got round to it a little later.
            if timer.time > self.now:
                self.now = timer.time
            timer.callback = None
            callback()
            self.run_until_blocked(blocks)
            if self._unfinished:
                return True
            fired += 1
            if budget_at is not None and blocks is not None and (
                    self._decoded >= budget_at or fired >= blocks or (
                        self.turn_over is not None and self.turn_over())):
                later = self._timers.next_time()  # more due: the next call goes on from here
                return later is not None and later <= t
        if t > self.now:
            self.now = t
        self.run_until_blocked(blocks)
        return self._unfinished

    def fire_early(self, t: float) -> None:
        """Fire the timers due before ``t`` and the early ones at ``t`` (the plant's tick, not
        the *first* ones, which the replay's inputs stand for), each followed by what
        it made runnable, and not the others of ``t`` (a replay's input applied first at
        ``t``: ``record.replay``).  (The body of advance_to's loop, which keeps it inline:
        every timer of a simulation passes there, a replay's few inputs here.)"""
        while (timer := self._timers.pop_early(t)) is not None:
            callback = timer.callback
            assert callback is not None
            if timer.time > self.now:
                self.now = timer.time
            timer.callback = None
            callback()
            self.run_until_blocked()

    def call_at(self, t: float, callback: Callable[[], None], late: bool = False,
                early: bool = False, first: bool = False) -> Timer:
        """Run ``callback`` when the clock reaches ``t`` (scripts, PLC logic), or at once if
        it has; ``late``: after every other timer of that time (a script's entry:
        ``TimerHeap.push``); ``early``: before every other (the plant's tick); ``first``:
        after the early ones, before the rest (``run --script``'s start).  The timer's
        time is ``t`` on the nanosecond grid (``due_time``), so an instant worked out two ways
        is one time, its timers in the order armed."""
        now = self.now  # (the heap snaps it: due_time, the time a leap works out)
        return self._arm(t if t > now else now, callback, late, early, first)

    def set_time(self, t: float) -> None:
        """The wall-clock driver tells the engine what time it is before outside events."""
        if t > self.now:
            self.now = t

    @property
    def all_idle(self) -> bool:
        for p in self.processes.values():  # (a loop: asked at every step of the clock)
            if p.loaded is not None or p.alarm is not None:
                return False
        return True

    @property
    def has_unfinished(self) -> bool:
        """A run limited in blocks left work at the current time (it goes first)."""
        return self._unfinished

    @property
    def has_runnable(self) -> bool:
        return bool(self._runnable)

    def blocked(self) -> tuple[Blocked, ...]:
        """Every process with a program that is waiting, with its why-record."""
        out = []
        for p in self.processes.values():
            if p.loaded is None or p.alarm is not None:
                continue
            wait = p.int_wait or p.dec_wait
            if wait is not None:
                note = wait.note() if wait.note is not None else None
                reason = f"{wait.code} {wait.reason()}" + (f"; {note}" if note else "")
                reason += self._alarmed_partners(wait)
                if p.held:  # a wait under a hold: once it ends, the hold still stands
                    reason += f"; {_held(p)}: a cycle start goes on"
                out.append(Blocked(p.number, *wait.where, reason))
            elif p.held:
                out.append(Blocked(p.number, *p.where, f"{_held(p)}: a cycle start goes on"))
            elif p.dec_block is DecoderHold.STEP:
                why = _STOPS.get(p.stopped or "", "single block")
                out.append(Blocked(p.number, *p.where, f"stopped after a block ({why}): "
                                   "a cycle start or a step runs the next"))
            elif p.int_remaining is not None and p.int_move is not None:
                # Not held, yet the timed item stands: its override is 0 % (_arm_item).
                move = p.int_move.move
                which = "rapid" if move is not None and move.rapid else "feed"
                out.append(Blocked(p.number, *p.int_move.where,
                                   f"{which} override 0 %: the move stands until the "
                                   "override is raised"))
            else:
                out.append(Blocked(p.number, *p.where, "blocked"))
        return tuple(out)

    def _alarmed_partners(self, wait: WaitRecord) -> str:
        """"; P2 is in ALARM AL101 at DZ.nc:3 N30: division by zero" for each process the
        wait is on that is in ALARM: what ends a stall is that alarm's reset."""
        if wait.kind not in (WaitKind.PROC, WaitKind.SND, WaitKind.EXE):
            return ""
        out = ""
        for number in wait.targets if wait.targets is not None else (wait.target,):
            q = self.processes.get(number)
            if q is None or q.alarm is None:
                continue
            code, message, where = q.alarm
            at = f" at {describe_where(where)}" if where is not None else ""
            out += f"; P{number} is in ALARM {AlarmCode(code).label}{at}: {message}"
        return out

    @property
    def stalled(self) -> bool:
        """Some process has a program, and none of them can go on by itself: only something
        outside can change that.  On the gateway (``run``, a replay) every such process
        waits -- none runs, dwells, moves or is held: a hold is the operator's, who may end
        it.  In a closed simulation (``settings.closed``: ``sim``) there is no operator, so
        a process held (a feed hold, a breakpoint's stop), stopped after a block, or whose
        move stands at a 0 % override stands as a wait does: only the simulation's own
        inputs (the PLC logic, the script, the plant) could move it, and the stall rule
        (``nc.stall_s``) judges them as it judges a wait's."""
        if self._runnable:
            return False
        closed = self.settings.closed
        busy = False
        for p in self.processes.values():
            if p.loaded is None or p.alarm is not None:
                continue
            if p.state in WAITING_STATES and not p.motion_active:
                busy = True
                continue
            if not closed or p.int_timer is not None or p.dec_timer is not None:
                return False  # (a timer of its own: a move, a dwell, a block's time)
            if not (p.held or p.state is ProcessState.STEP or p.int_remaining is not None):
                return False
            busy = True
        return busy

    def record_stall(self) -> None:
        """Every process is blocked and nothing can change: say so in the trace."""
        self._record(ev.Stall, self.now, 0, None, self.blocked())

    def status(self, number: int) -> ProcessStatus:
        p = self._process(number)
        wait = p.int_wait if p.int_wait is not None else p.dec_wait
        alarm_code, alarm_message, alarm_where = p.alarm if p.alarm else (0, None, None)
        # In ALARM the process stays where the alarm struck, until a reset.
        _, line, n = alarm_where if alarm_where is not None else p.where
        if alarm_message is not None and alarm_where is not None:
            alarm_message = f"{describe_where(alarm_where)}: {alarm_message}"
        return ProcessStatus(
            number=p.number, state=p.state, external=p.external,
            program=p.loaded.program.name if p.loaded else None, line=line, n=n, wait=wait,
            alarm_code=alarm_code, alarm_message=alarm_message,
            snd_sent=p.stats.snd_sent, snd_received=p.stats.snd_received,
            blocks=p.stats.blocks, position=self._position(p),
            motion_active=p.motion_active,
            held=p.held, alarm_where=alarm_where,
        )

    # ---- the sync rules' part of the API (sync.py) ------------------------------------------

    def external_snd(self, sender: int, target: int) -> None:
        """An SND in the name of external process ``sender`` (fieldbus mailbox, script)."""
        self.sync.external_snd(sender, target)

    def acts_early(self, p: Process, code: str, where: Where) -> None:
        """A plain code acting while motion above it is still queued: a hazard (sync.py)."""
        self.sync.acts_early(p, code, where)

    def write_syvar(self, p: Process, index: int, value: int, where: Where,
                    stage: Stage = Stage.DECODER) -> None:
        self.sync.write_syvar(p, index, value, where, stage)

    def write_image(self, p: Process, area: str, index: int, view: str, value: int,
                    where: Where) -> None:
        self.sync.write_image(p, area, index, view, value, where)

    def write_many(self, p: Process, changes: list[tuple[str, int, str, int]],
                   where: Where) -> None:
        """Several image variables in one atomic write, in the name of ``p``'s block (an
        auxiliary function's value and strobe)."""
        self.sync.write_changes(p, changes, where)

    def count_signal(self, sender: Process, target: int, ident: int, where: Where) -> None:
        self.sync.count_signal(sender, target, ident, where)

    @property
    def last_snd(self) -> tuple[int, int, int, int] | None:
        """The last SND delivered: sender, target, N, its number on the event counter."""
        return self.sync.last_snd

    @property
    def snd_log(self) -> deque[tuple[int, int, int, int, int]]:
        """The last SND_LOG SNDs: (sequence, sender, target, N, id), newest last."""
        return self.sync.snd_log

    @property
    def snd_seq(self) -> int:
        return self.sync.snd_seq

    def _process(self, number: int) -> Process:
        return self.sync.process(number)

    def note_write(self, name: str, value: int, who: str) -> None:
        """Record an image write in the trace (the gateway forwards the image's changes)."""
        self.last_change = self.now
        p = self.sync.writer_proc
        if p is not None:  # a program's write (write_image): at the writing block
            self._record(ev.Write, self.now, p.number, self.sync.writer_where, name, value, who)
        else:
            self._record(ev.Write, self.now, 0, None, name, value, who)

    def note_force(self, var: str | None, value: int | float | None, who: str) -> None:
        """A force set (or released: ``value`` None) from outside: in the trace."""
        self.last_change = self.now
        self._record(ev.Force, self.now, 0, None, var, value, who)

    def note_forced(self, var: str, value: int | float, who: str) -> None:
        """A write a force overrode (``value``: what ``who`` tried to store)."""
        self._record(ev.Forced, self.now, 0, None, var, value, who)

    def note_fault(self, target: str, kind: str, params: dict[str, object], who: str) -> None:
        """A fault injected from outside (docs/plant.md): in the trace."""
        self.last_change = self.now
        self._record(ev.Fault, self.now, 0, None, target, kind, params, who)

    def note_fault_clear(self, target: str, kind: str, who: str) -> None:
        """A fault cleared: in the trace."""
        self.last_change = self.now
        self._record(ev.FaultClear, self.now, 0, None, target, kind, who)

    def note_hazard(self, proc: int, message: str) -> None:
        """Record a hazard found outside the engine (a script's SND that could not go)."""
        self._record(ev.Hazard, self.now, proc, None, message)

    def finish_stats(self) -> None:
        """Account the time of the current states up to now (for the summary), a move
        still under way included (its moving time so far; again from now on)."""
        for p in self.processes.values():
            self._account(p)
            if p.int_timer is not None:
                self._moved(p)

    # ==== processes =========================================================================

    def _loaded_program(self, program: ProgramText, process: int) -> LoadedProgram:
        key = (program.file, process)
        lp = self._loaded.get(key)
        if lp is None or lp.program is not program:
            targets, dynamic = self.front_end.exe_targets(program)
            file = program.file.replace("\\", "/").rsplit("/", 1)[-1]
            lp = LoadedProgram(program, file, block_table(len(program)), len(program), targets,
                               dynamic)
            self._loaded[key] = lp  # a new version replaces the old one
        return lp

    def _start_program(self, p: Process, program: ProgramText, by: str | int) -> None:
        p.clear()
        p.loaded = self._loaded_program(program, p.number)
        p.stats.programs += 1
        self._record(ev.Start, self.now, p.number, None, program.name, by)
        self._update_state(p)
        self._make_runnable(p)

    start_program = _start_program  # sync.SyncHost

    def _make_runnable(self, p: Process) -> None:
        if not p.queued:
            p.queued = True
            self._runnable.append(p)
            if not self._running and self.on_kick is not None:
                self.on_kick()

    def _kick(self) -> None:
        if self._runnable and not self._running and self.on_kick is not None:
            self.on_kick()

    kick = _kick  # sync.SyncHost

    def _schedule(self, delay: float, callback: Callable[[], None]) -> Timer:
        return self._arm(self.now + delay, callback)

    def _arm(self, t: float, callback: Callable[[], None], late: bool = False,
             early: bool = False, first: bool = False) -> Timer:
        timer = self._timers.push(t, callback, late, early, first)
        if self.on_timer is not None:
            self.on_timer(timer.time)  # (on the grid: the time it fires at)
        return timer

    # ---- state --------------------------------------------------------------------------

    def _account(self, p: Process) -> None:
        spent = self.now - p.state_since
        if spent > 0:
            if p.state in RUNNING_STATES and not p.standing:
                p.stats.running_s += spent
            elif p.standing or p.state in WAITING_STATES or p.state is ProcessState.HOLD or (
                    p.state is ProcessState.STEP):
                p.stats.waiting_s += spent
        p.state_since = self.now

    def _update_state(self, p: Process) -> None:
        state = derive_state(p)  # the state table's rules (states.STATE_RULES)
        if state is not p.state:
            if (p.state, state) not in ALLOWED:
                raise AssertionError(f"P{p.number}: {p.state.name} -> {state.name} is not in "
                                     "the state table (states.TRANSITIONS)")
            self.last_change = self.now
            self._account(p)
            old, p.state = p.state, state
            if state is ProcessState.STEP and not p.stop_told and p.stopped is not None:
                # The stop the machine feels: the block done and its motion run.  Told once
                # (a feed hold over it and its release come back to STEP).
                p.stop_told = True
                self._record(ev.Stop, self.now, p.number, p.where, p.stopped)
            if self.state_listeners:  # copied: a listener may unsubscribe
                for listener in list(self.state_listeners):
                    listener(p, old)

    def read_time(self) -> float:
        """The time a status read shows: the driver's clock's now (``clock``; never before
        the engine's own time), or the engine's time on the virtual clock."""
        return self.now if self.clock is None else max(self.now, self.clock())

    def _position(self, p: Process) -> tuple[float, ...]:
        item = p.int_move
        if item is not None and item.move is not None:
            move = item.move
            if p.int_remaining is not None:
                done = 1.0 - (p.int_remaining / item.duration if item.duration else 0.0)
            elif item.duration > 0:
                nominal = self._nominal_done(p, self.read_time())
                done = min(1.0, max(0.0, nominal / item.duration))
            else:
                done = 1.0
            return tuple(a + (b - a) * done for a, b in zip(move.start, move.end, strict=True))
        return tuple(p.actual)

    # ==== the decoder =======================================================================

    def _run_decoder(self, p: Process) -> None:
        loaded = p.loaded
        assert loaded is not None
        blocks = loaded.blocks
        lines = loaded.length
        if p.spin_epoch != self._epoch:  # the engine stood still since: time could pass
            p.spin_epoch = self._epoch
            p.spin = 0
        runaway = self.settings.runaway_blocks
        budget = self.settings.slice_blocks
        if runaway and runaway - p.spin < budget:
            budget = runaway - p.spin
        turn = budget
        block_time = self._block_time
        stats = p.stats
        try:
            while True:
                block = p.block
                if block is None:
                    pc = p.pc
                    if pc >= lines:
                        self.end_decoding(p, "eof", (loaded.file, lines, None))
                        return
                    block = blocks[pc] or self._compile(loaded, pc)
                    if self._block_breaks:
                        if p.break_passed == pc:  # stopped here before: go on this time
                            p.break_passed = -1
                        elif self._break_at_block(p, pc, block.where):
                            return
                    if block.counted:
                        stats.blocks += 1
                    p.block = block
                    i = 0
                else:
                    i = p.op_i
                ops = block.ops
                count = len(ops)
                # The op index lives in a local; p.op_i is written only when the decoder stops
                # (ops never read it).
                while i < count:
                    result = ops[i](p)
                    if result == NEXT:
                        i += 1
                    elif result == WAIT_NEXT:
                        p.op_i = i + 1
                        return
                    elif result == WAIT_RETRY:
                        p.op_i = i
                        return
                    elif result == JUMP:
                        p.loop = (block.where, p.pc)
                        break
                    else:  # END
                        return
                else:
                    p.pc += 1
                p.block = None
                if block.counted:  # blocks as the statistics count them: not empty lines
                    budget -= 1
                    p.last_where = block.where
                    if p.single_block or p.step_once:  # stop here until a cycle start
                        # A program's or a breakpoint's stop is its own; in single block a
                        # step's is single block's (the mode going off ends it).
                        why = p.stop_why if p.step_once else None
                        if why is None or (why == "step" and p.single_block):
                            why = "single_block"
                        p.step_once = False
                        p.stop_why = None
                        p.stopped = why
                        p.dec_block = DecoderHold.STEP
                        self._update_state(p)
                        return
                    if block_time:  # the block takes its processing time
                        p.dec_block = DecoderHold.BLOCK_TIME
                        p.dec_timer = self._schedule(block_time,
                                                     functools.partial(self._block_timed, p))
                        return
                if budget == 0:
                    p.spin += turn
                    self._decoded += turn
                    turn = 0
                    if runaway and p.spin >= runaway:
                        self._runaway(p)
                        return
                    self._make_runnable(p)  # let the others run; this one goes on after
                    return
        except RuntimeAlarm as alarm:
            # A block that does not compile (lazy parsing) strikes at its own line, not at
            # the block before, where the process stands (Process.where).
            where = p.where if p.block is not None else (loaded.file, min(p.pc + 1, lines),
                                                          None)
            self._alarm(p, alarm.code, alarm.message, where)
        finally:
            p.spin += turn - budget
            self._decoded += turn - budget
    def _block_timed(self, p: Process) -> None:
        p.dec_timer = None
        if p.dec_block is DecoderHold.BLOCK_TIME:
            p.dec_block = None
            self._make_runnable(p)

    def _runaway(self, p: Process) -> None:
        """A process decoded runaway_blocks blocks and no time passed: name its loop."""
        limit = self.settings.runaway_blocks
        advice = ("; give the loop motion, a dwell or a wait, or set nc.block_time_ms")
        if p.loop is None:
            self._alarm(p, AlarmCode.RUNAWAY,
                        f"runaway: {limit} blocks without time passing{advice}", p.where)
            return
        (file, line, n), target = p.loop
        assert p.loaded is not None
        lines = p.loaded.program.lines

        def shown(index: int) -> str:
            text = lines[index].strip() if 0 <= index < len(lines) else ""
            return f"line {index + 1}" + (f" '{text[:40]}'" if text else "")
        self._alarm(p, AlarmCode.RUNAWAY,
                    f"runaway: {limit} blocks without time passing in the loop from "
                    f"{shown(line - 1)} back to {shown(target)}{advice}", (file, line, n))

    def end_decoding(self, p: Process, how: str, where: Where) -> None:
        p.dec_block = DecoderHold.DONE
        p.end_how = how
        p.end_where = where
        self._interp_run(p)

    def _compile(self, loaded: LoadedProgram, index: int) -> CompiledBlock:
        compiled = self.front_end.compile_block(self, loaded, index)
        loaded.blocks[index] = compiled
        return compiled

    # ---- motion queue -------------------------------------------------------------------

    def queue_motion(self, p: Process, items: list[QueueItem]) -> Step:
        """Queue items (the decoder's pending ones first); NEXT, or WAIT_RETRY if full."""
        if p.pending is None:
            p.pending = items
        lookahead = self.settings.lookahead
        pending = p.pending
        while pending:
            # The queue holds the items waiting behind the one the interpolator executes;
            # lookahead 0: the next item only when the interpolator is done with the last.
            waiting = len(p.queue) - (1 if p.int_item is not None else 0)
            if (not lookahead and p.queue) or (lookahead and waiting >= lookahead):
                break
            p.queue.append(pending.pop(0))
            self._interp_run(p)
        if pending:
            p.dec_block = DecoderHold.FULL
            return WAIT_RETRY
        p.pending = None
        if self.settings.lookahead == 0 and (p.queue or p.int_item is not None):
            p.dec_block = DecoderHold.FLUSH  # lookahead 0: the decoder waits for each item
            return WAIT_NEXT
        return NEXT

    def flush(self, p: Process) -> Step:
        """Wait until the motion queue is empty (sync_reads, spec 2.4)."""
        if p.queue or p.int_item is not None:
            p.dec_block = DecoderHold.FLUSH
            if self._buffered:
                self._interp_run(p)
            return WAIT_RETRY
        return NEXT

    # ==== the interpolator ==================================================================

    def _interp_run(self, p: Process) -> None:
        while True:
            if p.int_timer is not None or p.int_wait is not None or p.held or p.alarm:
                return
            if p.int_remaining is not None:
                return
            if not p.queue:
                p.int_item = None
                self._queue_drained(p)
                return
            if self._buffered and p.int_item is None and not self._buffer_open(p):
                if not p.starved:  # its state is its decoder's; the deadlock search asks
                    p.starved = True
                    self.sync.check_deadlock(p)
                return
            p.starved = False
            item = p.queue[0]
            p.int_item = item
            if item.kind >= ItemKind.SYNC:  # a # block's actions, or auxiliary functions
                if not self._run_sync_item(p, item):
                    return
                self._item_done(p)
                continue
            if item.duration > 0:
                self._arm_item(p, item, item.duration)
                self._update_state(p)
                return
            self._item_done(p)

    def _buffer_open(self, p: Process) -> bool:
        """Spec 5.4: a full buffer, or a decoder at the end, a flush or a synchronous read."""
        if len(p.queue) >= self.settings.lookahead:
            return True
        hold = p.dec_block
        if hold is DecoderHold.DONE or hold is DecoderHold.FLUSH:
            return True
        return p.dec_wait is not None and p.dec_wait.kind is WaitKind.FLUSH

    def _arm_item(self, p: Process, item: QueueItem, remaining: float) -> None:
        """Time ``item`` from now, ``remaining`` of its nominal seconds left, at the process's
        override (a move's: feed or rapid; a dwell or tool change runs at 100 %).  At 0 % the
        motion stands where it is, the process not held."""
        p.int_move = item
        p.int_done = item.duration - remaining
        p.int_started = self.now
        rate = p.int_rate = self._rate(p, item)
        self._stand(p, rate <= 0.0)
        if rate <= 0.0:
            p.int_remaining = remaining
            return
        p.int_timer = self._schedule(remaining / rate, functools.partial(self._timed_done, p,
                                                                         item))

    @staticmethod
    def _rate(p: Process, item: QueueItem) -> float:
        move = item.move
        if move is None:
            return 1.0
        return (p.rapid_override if move.rapid else p.feed_override) / 100.0

    def _nominal_left(self, p: Process) -> float:
        """The nominal seconds of the timed item still to run."""
        item = p.int_move
        assert item is not None
        return max(0.0, item.duration - self._nominal_done(p, self.now))

    @staticmethod
    def _nominal_done(p: Process, at: float) -> float:
        """The nominal seconds of the timed item done at ``at``: those kept before its last
        rate change, and the time since at its rate."""
        return p.int_done + (at - p.int_started) * p.int_rate

    def override(self, feed: int | None = None, rapid: int | None = None,
                 process: int | None = None) -> None:
        """Set the feed (0..200 %) and/or rapid (0..100 %) override of one process or the
        cell, from the next interpolation step: a move under way goes on at the new rate
        from where it is; 0 % stands without a feed hold."""
        targets = self._targets(process)
        for p in targets:
            if p.external:
                continue
            if feed is not None:
                p.feed_override = feed
            if rapid is not None:
                p.rapid_override = rapid
            self._record(ev.Override, self.now, p.number, None, p.feed_override,
                         p.rapid_override)
            item = p.int_move
            if item is None or p.held:
                continue  # a hold keeps its nominal time left: the resume takes the new rate
            if p.int_timer is not None:
                self._stop_motion(p)
                left = self._nominal_left(p)
            elif p.int_remaining is not None:  # it stood at 0 %
                left, p.int_remaining = p.int_remaining, None
            else:
                continue
            self._arm_item(p, item, left)
        self.last_change = self.now

    def _stand(self, p: Process, on: bool) -> None:
        """``p``'s timed item stands at a 0 % override (``on``), or no longer: its RUNNING
        time from now on is waiting time (or running time again)."""
        if p.standing != on:
            self._account(p)
            p.standing = on

    def _moved(self, p: Process) -> None:
        """The time the timed item's timer has run since it was armed (or last counted) is
        the process's moving time (at the override it ran at: not its nominal time); it
        counts on from now, the nominal seconds it did kept (_nominal_left)."""
        ran = self.now - p.int_started
        p.stats.moving_s += ran
        p.int_done += ran * p.int_rate
        p.int_started = self.now

    def _stop_motion(self, p: Process) -> None:
        """The timed item's timer stops (a hold, a new override, an abort)."""
        assert p.int_timer is not None
        p.int_timer.cancel()
        p.int_timer = None
        self._moved(p)

    def _timed_done(self, p: Process, item: QueueItem) -> None:
        p.int_timer = None
        p.int_move = None
        if item.move is not None:
            p.actual = list(item.move.end)
        self._moved(p)
        if item.kind == ItemKind.SYNC:  # a move inside a # block
            p.sync_i += 1
            self._continue_sync(p)
            return
        self._item_done(p)
        self._interp_run(p)

    def _item_done(self, p: Process) -> None:
        item = p.queue.popleft()
        if item.move is not None:
            p.actual = list(item.move.end)
        p.int_item = None
        p.sync_i = 0
        if p.dec_block is DecoderHold.FULL:
            p.dec_block = None
            self._make_runnable(p)
        self._update_state(p)

    def _queue_drained(self, p: Process) -> None:
        wait = p.dec_wait
        if wait is not None and wait.kind is WaitKind.FLUSH:
            self._finish_wait(p, wait, "flush")
        elif p.dec_block is DecoderHold.FLUSH:
            p.dec_block = None
            self._make_runnable(p)
        elif p.dec_block is DecoderHold.DONE and p.loaded is not None and p.alarm is None:
            self._end_program(p)
        else:
            self._update_state(p)
            self.sync.check_deadlock(p)

    def _run_sync_item(self, p: Process, item: QueueItem) -> bool:
        """Run a # block's actions from ``p.sync_i``; False when one of them blocks."""
        actions = item.actions or []
        try:
            while p.sync_i < len(actions):
                action = actions[p.sync_i]
                if isinstance(action, Motion):
                    move = action.move
                    if move.duration_s > 0:
                        sub = QueueItem(ItemKind.SYNC, move.duration_s, item.where, move)
                        self._arm_item(p, sub, move.duration_s)
                        return False
                    p.actual = list(move.end)
                elif not self.perform(p, Stage.INTERPOLATOR, action, item.where):
                    p.sync_i += 1
                    return False
                p.sync_i += 1
        except RuntimeAlarm as alarm:
            self._alarm(p, alarm.code, alarm.message, item.where)
            return False
        return True

    def _continue_sync(self, p: Process) -> None:
        item = p.queue[0] if p.queue else None
        if item is None or item.kind < ItemKind.SYNC or p.alarm is not None:
            return
        if self._run_sync_item(p, item):
            self._item_done(p)
            self._interp_run(p)

    # ==== actions and waits ==================================================================

    def perform(self, p: Process, stage: Stage, action: Action | object, where: Where) -> bool:
        """Perform one action; True when it completed, False when the process waits."""
        return self._actions[type(action)](p, stage, action, where)

    def _do_write_syvar(self, p: Process, stage: Stage, action: WriteSyvar,
                        where: Where) -> bool:
        self.write_syvar(p, action.index, action.value, where, stage)
        return True

    def _show_text(self, p: Process, stage: Stage, action: ShowText, where: Where) -> bool:
        self._record(ev.Display, self.now, p.number, where, action.text)
        return True

    def _begin_wait(self, p: Process, stage: Stage, wait: WaitRecord) -> None:
        if stage is Stage.DECODER:
            p.dec_wait = wait
            p.dec_block = DecoderHold.WAIT
        else:
            p.int_wait = wait
        on = wait.on if wait.on is not None else _new(
            WaitOn, (wait.kind, wait.target, wait.cond, wait.value, wait.name))
        self._record(ev.Wait, self.now, p.number, wait.where, on)
        if self._wait_timeout_s:
            wait.timeout = self._schedule(self._wait_timeout_s,
                                          lambda: self._wait_timed_out(p, wait))
        self._update_state(p)
        if self._wait_breaks:
            for bp in self.breakpoints:
                if bp.matches_wait(p.number, wait.kind):
                    self._hit(bp, p.number, wait.where)
                    break

    def _finish_wait(self, p: Process, wait: WaitRecord, by: int | str) -> None:
        """The wait is over: resume the stage that waited."""
        if wait.timeout is not None:
            wait.timeout.cancel()
        self._record(ev.Resume, self.now, p.number, wait.where, by,
                     wait.writer if by == "cond" else None)
        if p.dec_wait is wait:
            p.dec_wait = None
            p.dec_block = None
            self._update_state(p)
            self._make_runnable(p)
        elif p.int_wait is wait:
            p.int_wait = None
            self._update_state(p)
            self._continue_sync(p)
            self._interp_run(p)

    begin_wait = _begin_wait
    finish_wait = _finish_wait

    def _drop_wait(self, wait: WaitRecord) -> None:
        if wait.handle is not None:
            wait.handle.cancel()
        if wait.timeout is not None:
            wait.timeout.cancel()

    def _wait_timed_out(self, p: Process, wait: WaitRecord) -> None:
        if wait is p.dec_wait or wait is p.int_wait:
            self._alarm(p, AlarmCode.WAIT_TIMEOUT,
                        f"wait longer than {self.settings.wait_timeout_s:g} s: "
                        f"{wait.describe(p.number)} {wait.reason()}", wait.where)

    # ==== ends and alarms ====================================================================

    def _end_program(self, p: Process) -> None:
        how = p.end_how or "eof"
        where = p.end_where
        p.clear()
        p.loaded = None
        self._record(ev.End, self.now, p.number, where, how)
        self._update_state(p)
        self.sync.became_free(p)

    def _cancel_pending(self, p: Process) -> None:
        """Its waits, its motion timer and its block-time timer: nothing of it fires later."""
        for wait in p.waits():
            self._drop_wait(wait)
        self._stand(p, False)
        if p.int_timer is not None:
            self._stop_motion(p)
        if p.dec_timer is not None:
            p.dec_timer.cancel()

    def _alarm(self, p: Process, code: AlarmCode, message: str, where: Where | None) -> None:
        if p.alarm is not None:
            return
        self._cancel_pending(p)
        self.sync.forget_waiter(p)
        loaded = p.loaded
        p.clear()
        p.loaded = loaded
        p.alarm = (int(code), message, where)
        p.stats.alarms += 1
        self._record(ev.Alarm, self.now, p.number, where, code, message)
        self._update_state(p)
        self.sync.became_free(p)

