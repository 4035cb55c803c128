"""The co-simulation runtime: processes, EXE/REL/WAI/SND, motion, deadlocks (spec 2).

The :class:`Engine` is synchronous and deterministic.  It owns the processes, a timer heap and
a run queue; it never sleeps and never reads a clock.  A driver decides when time passes:

- on the virtual clock (``ncgate sim``) a plain loop runs everything runnable, then jumps to
  the next timer (:func:`run_virtual`);
- on the wall clock (the gateway) an asyncio driver arms one loop timer for the next engine
  timer and runs the engine whenever something outside (a fieldbus write) made work runnable.

Each process is a two-stage pipeline (spec 2.4): a *decoder* that runs blocks in program order
-- assignments, jumps, EXE/REL/WAI/SND -- and turns motion into items of a bounded *motion
queue*, and an *interpolator* that executes those items in simulated time.  A block marked
``#`` is evaluated by the decoder (values, targets, positions) but queued as one item: its
SYVAR writes, WAIs, SNDs and EXEs act when the interpolator reaches it.

Items of one block run in a fixed order (spec 1.5, LinuxCNC-style): assignments, then WAI,
then motion and auxiliary words, then SND/EXE/REL/jumps/DIS in the order written.

Must not import ``plc`` or ``gateway``: the image and the program store come in through the
protocols of :mod:`interpreter.ports`.
"""

from __future__ import annotations

import enum
import functools
import heapq
import itertools
import operator
import re
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import ProgramError, ProgramNotFoundError, ProgramSyntaxError
from ncgate.interpreter.evaluate import RuntimeAlarm, compile_expr, reads_image, round_half_away
from ncgate.interpreter.formatter import format_item
from ncgate.interpreter.motion import AXES, Modal, Move, plan_move
from ncgate.interpreter.nodes import (
    Assign,
    Branch,
    BranchOp,
    Display,
    Dwell,
    EndRepeat,
    Exe,
    Expr,
    InertCode,
    Item,
    Jump,
    Num,
    Rel,
    Repeat,
    Snd,
    VarKind,
    WaitCond,
    WaitProc,
    Word,
)
from ncgate.interpreter.parser import Program, gc_paused
from ncgate.interpreter.ports import Cancellable, ImagePort, ProgramLoader
from ncgate.interpreter.settings import RuntimeSettings, SndPolicy
from ncgate.interpreter.trace import Trace


class ProcessState(enum.IntEnum):
    """Spec 2.1; the value is the code on the fieldbus."""

    IDLE = 0
    RUNNING = 1
    WAIT_PROC = 2
    WAIT_COND = 3
    WAIT_SND = 4
    WAIT_EXE = 5
    DWELL = 6
    HOLD = 7
    ALARM = 8


class WaitKind(enum.IntEnum):
    """Spec 3.2 (process status, wait kind)."""

    NONE = 0
    PROC = 1
    COND = 2
    SND = 3
    EXE = 4


_STATE_OF_WAIT: Final = {WaitKind.PROC: ProcessState.WAIT_PROC,
                         WaitKind.COND: ProcessState.WAIT_COND,
                         WaitKind.SND: ProcessState.WAIT_SND,
                         WaitKind.EXE: ProcessState.WAIT_EXE}


_EXE_ARG: Final = re.compile(r"\(\s*EXE\s*,\s*([^,)\s]*)", re.IGNORECASE)
_RUNNING_STATES: Final = frozenset({ProcessState.RUNNING, ProcessState.DWELL, ProcessState.HOLD})
_WAITING_STATES: Final = frozenset(_STATE_OF_WAIT.values())
_ON_KEY: Final = {WaitKind.PROC: "proc", WaitKind.SND: "snd", WaitKind.EXE: "exe"}


Where = tuple[str, int, int | None]  # program file, line, N


@dataclass(slots=True)
class WaitRecord:
    """Why a process waits (spec 2.2.6): what the status registers and reports show."""

    kind: WaitKind
    target: int  # the process waited for (PROC, SND, EXE); 0 for a condition
    code: str  # the code as written, e.g. "(WAI,2)"
    where: Where
    since: float
    stage: str  # "decoder" or "interpolator"
    cond: str | None = None
    value: float | None = None
    writer: str | None = None
    handle: Cancellable | None = None
    timeout: _Timer | None = None

    def describe(self, proc: int) -> str:
        file, line, n = self.where
        number = f" N{n}" if n is not None else ""
        return f"P{proc} {file}:{line}{number} {self.code}"

    def reason(self) -> str:
        if self.kind is WaitKind.COND:
            writer = f", last written by {self.writer}" if self.writer else ""
            return f"waits for {self.cond} (now {_fmt(self.value)}{writer})"
        return {WaitKind.PROC: f"waits for an SND from P{self.target}",
                WaitKind.SND: f"waits for P{self.target} to take its SND",
                WaitKind.EXE: f"waits for P{self.target} to be free"}.get(self.kind, "waits")


def _fmt(value: float | None) -> str:
    if value is None:
        return "?"
    return str(int(value)) if value == int(value) else f"{value:g}"


class _Timer:
    __slots__ = ("callback", "time")

    def __init__(self, time: float, callback: Callable[[], None] | None) -> None:
        self.time = time
        self.callback = callback

    def cancel(self) -> None:
        self.callback = None


# Queue item kinds
MOVE, TOOL, DWELL, SYNC, AUX = range(5)


@dataclass(slots=True)
class QueueItem:
    kind: int
    duration: float
    where: Where
    move: Move | None = None
    actions: list[tuple[Any, ...]] | None = None  # SYNC: the evaluated codes of a # block


@dataclass(slots=True)
class Stats:
    programs: int = 0
    blocks: int = 0
    running_s: float = 0.0
    waiting_s: float = 0.0
    moving_s: float = 0.0
    snd_sent: int = 0
    snd_received: int = 0
    alarms: int = 0


@dataclass(frozen=True, slots=True)
class ProcessStatus:
    number: int
    state: ProcessState
    external: bool
    program: str | None
    line: int
    n: int | None
    wait: WaitRecord | None
    alarm_code: int
    alarm_message: str | None
    snd_sent: int
    snd_received: int
    blocks: int
    position: tuple[float, ...]
    motion_active: bool
    held: bool

    @property
    def wait_kind(self) -> WaitKind:
        return self.wait.kind if self.wait else WaitKind.NONE

    @property
    def wait_target(self) -> int:
        return self.wait.target if self.wait else 0


# Decoder op results
NEXT, WAIT_NEXT, WAIT_RETRY, JUMP, END = range(5)
Op = Callable[["Process"], int]


@dataclass(slots=True)
class CompiledBlock:
    ops: tuple[Op, ...]
    where: Where
    counted: bool


@dataclass(slots=True)
class LoadedProgram:
    program: Program
    file: str  # display name in messages and the trace
    blocks: list[CompiledBlock | None]
    exe_targets: frozenset[int]
    dynamic_exe: bool


class Process:
    """One process (channel): decoder + motion queue + interpolator."""

    def __init__(self, number: int, external: bool, e_params: int) -> None:
        self.number = number
        self.external = external
        self.e_params = e_params
        self.E: list[float] = [0.0] * e_params
        self.loaded: LoadedProgram | None = None
        self.modal = Modal()
        self.stats = Stats()
        self.state = ProcessState.IDLE
        self.state_since = 0.0
        self.alarm: tuple[int, str, Where | None] | None = None
        self.held = False
        self.actual: list[float] = list(self.modal.position)  # the interpolator's position
        self.queued = False  # in the engine's run queue
        self.clear()

    def clear(self) -> None:
        """Forget the running program (not E parameters, position or statistics)."""
        self.pc = 0
        self.op_i = 0
        self.block: CompiledBlock | None = None
        self.repeats: list[list[int]] = []  # [line of the RPT, repetitions left]
        self.dec_block: str | None = None  # None runnable, "wait", "full", "flush", "done"
        self.dec_wait: WaitRecord | None = None
        self.end_how: str | None = None
        self.end_where: Where | None = None
        self.pending: list[QueueItem] | None = None
        self.queue: deque[QueueItem] = deque()
        self.int_item: QueueItem | None = None
        self.int_timer: _Timer | None = None
        self.int_started = 0.0
        self.int_remaining: float | None = None  # a timed item paused by a feed hold
        self.int_wait: WaitRecord | None = None
        self.sync_i = 0

    @property
    def motion_active(self) -> bool:
        """A timed queue item under way (or paused by a feed hold): spec 2.4's flag."""
        return self.int_timer is not None or self.int_remaining is not None

    @property
    def where(self) -> Where:
        if self.block is not None:
            return self.block.where
        if self.loaded is not None:  # between blocks: the line the decoder is at
            return (self.loaded.file, min(self.pc + 1, len(self.loaded.blocks)), None)
        return ("", 0, None)


class Engine:
    """Processes, their synchronisation, the motion queues and the timer heap."""

    def __init__(self, settings: RuntimeSettings, image: ImagePort, loader: ProgramLoader,
                 trace: Trace | None = None) -> None:
        self.settings = settings
        self.image = image
        self.loader = loader
        self.trace = trace if trace is not None else Trace()
        self._record = self.trace.record  # bound once: every SND and WAI records
        self.now = 0.0
        self._wait_timeout_s = settings.wait_timeout_s
        self.processes = {
            k: Process(k, k in settings.external, settings.e_params)
            for k in range(1, settings.processes + 1)
        }
        self._timers: list[tuple[float, int, _Timer]] = []
        self._timer_seq = itertools.count()
        self._runnable: deque[Process] = deque()
        self._running = False
        self._proc_waiters: dict[tuple[int, int], Process] = {}  # (waited-for, waiter)
        self._snd_pending: dict[tuple[int, int], Process] = {}  # (sender, target)
        # Latched SNDs not yet taken: (sender, target) -> where each was sent from (None: by
        # the fieldbus), oldest first.
        self._tokens: dict[tuple[int, int], deque[Where | None]] = {}
        self._exe_waiters: dict[int, deque[tuple[Process, Program, str]]] = {}
        self._loaded: dict[int, LoadedProgram] = {}
        self._writer_proc: Process | None = None
        # The last SND delivered: sender, target, N, its number on the event counter.
        self.last_snd: tuple[int, int, int, int] | None = None
        # Hooks for drivers and the gateway.
        self.on_kick: Callable[[], None] | None = None  # work became runnable from outside
        self.on_timer: Callable[[float], None] | None = None  # a timer was armed
        self.state_listeners: list[Callable[[Process, ProcessState], None]] = []

    # ==== public API ========================================================================

    def start(self, name: str, process: int = 1, by: str = "operator",
              device: str | None = None) -> None:
        """The operator's SPG: load NAME into an idle process and start it."""
        p = self._process(process)
        if p.external:
            raise ValueError(f"process {process} is external: it runs no part program")
        if p.loaded is not None or p.alarm is not None:
            raise ValueError(f"process {process} is busy ({p.state.name})")
        program = self.loader.load(name, device, process)
        self._start_program(p, program, by)
        self._kick()

    def cycle_start(self) -> None:
        """Fieldbus command 1: resume after a feed hold, or start ``main`` in process 1."""
        if any(p.held for p in self.processes.values()):
            self.hold(False)
            return
        p1 = self.processes[1]
        if self.settings.main and p1.loaded is None and p1.alarm is None:
            try:
                self.start(self.settings.main, 1, by="fieldbus")
            except (ProgramError, ProgramNotFoundError) as exc:
                self._alarm(p1, AlarmCode.PROGRAM_NOT_FOUND
                            if isinstance(exc, ProgramNotFoundError)
                            else AlarmCode.PROGRAM_INVALID, _first_line(exc), None)

    def hold(self, on: bool = True) -> None:
        """Feed hold: motion stops where it is; ``hold(False)`` resumes it."""
        for p in self.processes.values():
            if p.external or p.held == on:
                continue
            if on:
                p.held = True
                if p.int_timer is not None:
                    p.int_timer.cancel()
                    p.int_timer = None
                    assert p.int_item is not None
                    elapsed = self.now - p.int_started
                    p.int_remaining = max(0.0, p.int_item.duration - elapsed)
            else:
                p.held = False
                if p.int_remaining is not None and p.int_item is not None:
                    remaining, p.int_remaining = p.int_remaining, None
                    self._arm_item(p, p.int_item, remaining)
                else:
                    self._interp_run(p)
            self._update_state(p)
        self._kick()

    def reset(self) -> None:
        """Clear every alarm, discard queues, waits and tokens; every process to IDLE."""
        for p in self.processes.values():
            was_busy = p.loaded is not None or p.alarm is not None
            for wait in (p.dec_wait, p.int_wait):
                if wait is not None:
                    self._drop_wait(wait)
            if p.int_timer is not None:
                p.int_timer.cancel()
            where = p.where
            p.clear()
            p.loaded = None
            p.alarm = None
            p.held = False
            p.E = [0.0] * p.e_params
            if was_busy:
                self._emit("end", p.number, where, how="reset")
            self._update_state(p)
        self._runnable.clear()
        self._proc_waiters.clear()
        self._snd_pending.clear()
        self._tokens.clear()
        self._exe_waiters.clear()

    def external_snd(self, sender: int, target: int) -> None:
        """An SND in the name of external process ``sender`` (fieldbus mailbox, script)."""
        s = self._process(sender)
        if not s.external:
            raise ValueError(f"process {sender} is not external")
        t = self._process(target)
        if t.external:
            self._deliver_snd(s, t, None, external=True)
            return
        if t.loaded is None or t.alarm is not None:
            raise ValueError(f"SND to process {target}, which runs no program")
        waiter = self._proc_waiters.get((sender, target))
        if waiter is not None:
            self._deliver_snd(s, t, None, external=True)
            self._end_wait_proc(t, sender)
        else:
            # An external sender cannot be made to wait: latch it, and say it is a race.
            self._tokens.setdefault((sender, target), deque()).append(None)
            self._emit("hazard", sender, None,
                       message=f"SND from external P{sender} to P{target} before P{target} "
                       f"waits for it: latched")
        self._kick()

    def run_until_blocked(self) -> None:
        """Run everything runnable at the current time."""
        if self._running:
            return
        self._running = True
        try:
            runnable = self._runnable
            while runnable:
                p = runnable.popleft()
                p.queued = False
                if p.loaded is not None and p.alarm is None and p.dec_block is None:
                    self._run_decoder(p)
        finally:
            self._running = False

    def next_timer(self) -> float | None:
        timers = self._timers
        while timers and timers[0][2].callback is None:
            heapq.heappop(timers)
        return timers[0][0] if timers else None

    def advance_to(self, t: float) -> None:
        """Let time pass to ``t``: fire the timers due, then run what became runnable."""
        timers = self._timers
        while timers and timers[0][0] <= t:
            due, _, timer = heapq.heappop(timers)
            callback = timer.callback
            if callback is not None:
                # What a timer causes happens at its time, even if the wall clock that drives
                # the engine got round to it a little later.
                if due > self.now:
                    self.now = due
                timer.callback = None
                callback()
                self.run_until_blocked()
        if t > self.now:
            self.now = t
        self.run_until_blocked()

    def call_at(self, t: float, callback: Callable[[], None]) -> Cancellable:
        """Run ``callback`` when the clock reaches ``t`` (scripts, PLC logic)."""
        return self._schedule(max(0.0, t - self.now), callback)

    def set_time(self, t: float) -> None:
        """The wall-clock driver tells the engine what time it is before outside events."""
        if t > self.now:
            self.now = t

    @property
    def all_idle(self) -> bool:
        return all(p.loaded is None and p.alarm is None for p in self.processes.values())

    @property
    def has_runnable(self) -> bool:
        return bool(self._runnable)

    def blocked(self) -> list[dict[str, Any]]:
        """Every process with a program that is waiting, with its why-record."""
        out = []
        for p in self.processes.values():
            if p.loaded is None or p.alarm is not None:
                continue
            wait = p.int_wait or p.dec_wait
            if wait is not None:
                file, line, n = wait.where
                out.append({"proc": p.number, "prog": file, "line": line, "n": n,
                            "reason": f"{wait.code} {wait.reason()}"})
            else:
                file, line, n = p.where
                out.append({"proc": p.number, "prog": file, "line": line, "n": n,
                            "reason": "blocked"})
        return out

    def status(self, number: int) -> ProcessStatus:
        p = self._process(number)
        wait = p.int_wait if p.int_wait is not None else p.dec_wait
        _, line, n = p.where
        alarm_code, alarm_message = (p.alarm[0], p.alarm[1]) if p.alarm else (0, None)
        return ProcessStatus(
            number=p.number, state=p.state, external=p.external,
            program=p.loaded.program.name if p.loaded else None, line=line, n=n, wait=wait,
            alarm_code=alarm_code, alarm_message=alarm_message,
            snd_sent=p.stats.snd_sent, snd_received=p.stats.snd_received,
            blocks=p.stats.blocks, position=self._position(p),
            motion_active=p.motion_active,
            held=p.held,
        )

    def note_write(self, name: str, value: int, who: str) -> None:
        """Record an image write in the trace (the gateway forwards the image's changes)."""
        p = self._writer_proc
        if p is not None and who.startswith(f"P{p.number} "):
            self._emit("write", p.number, p.where, var=name, value=value, who=who)
        else:
            self._emit("write", 0, None, var=name, value=value, who=who)

    def finish_stats(self) -> None:
        """Account the time of the current states up to now (for the summary)."""
        for p in self.processes.values():
            self._account(p)

    # ==== processes =========================================================================

    def _process(self, number: int) -> Process:
        p = self.processes.get(number)
        if p is None:
            raise ValueError(f"process {number} is not configured (1..{len(self.processes)})")
        return p

    def _loaded_program(self, program: Program) -> LoadedProgram:
        key = id(program)
        lp = self._loaded.get(key)
        if lp is None or lp.program is not program:
            # Which processes this program may start (orphan-wait detection), from the text:
            # a program that is parsed lazily must not be parsed whole here.
            targets: set[int] = set()
            dynamic = False
            for m in _EXE_ARG.finditer("\n".join(program.lines)):
                if m.group(1).isdigit():
                    targets.add(int(m.group(1)))
                else:
                    dynamic = True
            file = program.file.replace("\\", "/").rsplit("/", 1)[-1]
            lp = LoadedProgram(program, file, [None] * len(program), frozenset(targets), dynamic)
            self._loaded[key] = lp
        return lp

    def _start_program(self, p: Process, program: Program, by: str | int) -> None:
        p.clear()
        p.loaded = self._loaded_program(program)
        p.stats.programs += 1
        self._emit("start", p.number, None, prog=program.name, by=by)
        self._update_state(p)
        self._make_runnable(p)

    def _make_runnable(self, p: Process) -> None:
        if not p.queued:
            p.queued = True
            self._runnable.append(p)
            if not self._running and self.on_kick is not None:
                self.on_kick()

    def _kick(self) -> None:
        if self._runnable and not self._running and self.on_kick is not None:
            self.on_kick()

    def _schedule(self, delay: float, callback: Callable[[], None]) -> _Timer:
        t = self.now + delay
        timer = _Timer(t, callback)
        heapq.heappush(self._timers, (t, next(self._timer_seq), timer))
        if self.on_timer is not None:
            self.on_timer(t)
        return timer

    def _emit(self, event: str, proc: int, where: Where | None, **fields: Any) -> None:
        self._record(self.now, event, proc, where, fields)

    # ---- state --------------------------------------------------------------------------

    def _derive_state(self, p: Process) -> ProcessState:
        if p.alarm is not None:
            return ProcessState.ALARM
        if p.loaded is None:
            return ProcessState.IDLE
        if p.held:
            return ProcessState.HOLD
        # The interpolator's wait is the one the machine feels (spec 2.4).
        if p.int_wait is not None:
            return _STATE_OF_WAIT[p.int_wait.kind]
        if p.dec_wait is not None:
            return _STATE_OF_WAIT[p.dec_wait.kind]
        if p.int_item is not None and p.int_item.kind == DWELL:
            return ProcessState.DWELL
        return ProcessState.RUNNING

    def _account(self, p: Process) -> None:
        spent = self.now - p.state_since
        if spent > 0:
            if p.state in _RUNNING_STATES:
                p.stats.running_s += spent
            elif p.state in _WAITING_STATES:
                p.stats.waiting_s += spent
        p.state_since = self.now

    def _update_state(self, p: Process) -> None:
        state = self._derive_state(p)
        if state is not p.state:
            self._account(p)
            old, p.state = p.state, state
            if self.state_listeners:  # copied: a listener may unsubscribe
                for listener in list(self.state_listeners):
                    listener(p, old)

    def _position(self, p: Process) -> tuple[float, ...]:
        item = p.int_item
        if item is not None and item.move is not None:
            move = item.move
            if p.int_remaining is not None:
                done = 1.0 - (p.int_remaining / item.duration if item.duration else 0.0)
            elif item.duration > 0:
                done = min(1.0, max(0.0, (self.now - p.int_started) / item.duration))
            else:
                done = 1.0
            return tuple(a + (b - a) * done for a, b in zip(move.start, move.end, strict=True))
        return tuple(p.actual)

    # ==== the decoder =======================================================================

    def _run_decoder(self, p: Process) -> None:
        loaded = p.loaded
        assert loaded is not None
        blocks = loaded.blocks
        lines = len(blocks)
        budget = self.settings.slice_blocks
        skip_deleted = self.settings.optional_skip
        stats = p.stats
        try:
            while True:
                block = p.block
                if block is None:
                    pc = p.pc
                    if pc >= lines:
                        self._decoder_end(p, "eof", (loaded.file, lines, None))
                        return
                    block = blocks[pc] or self._compile(loaded, pc)
                    if skip_deleted and loaded.program.block(pc).deleted:
                        p.pc += 1
                        continue
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
                        break
                    else:  # END
                        return
                else:
                    p.pc += 1
                p.block = None
                budget -= 1
                if budget == 0:  # let the others run; a loop with no motion never blocks
                    self._make_runnable(p)
                    return
        except RuntimeAlarm as alarm:
            self._alarm(p, alarm.code, alarm.message, p.where)

    def _decoder_end(self, p: Process, how: str, where: Where) -> None:
        p.dec_block = "done"
        p.end_how = how
        p.end_where = where
        self._interp_run(p)

    def _compile(self, loaded: LoadedProgram, index: int) -> CompiledBlock:
        try:
            block = loaded.program.block(index)
        except ProgramSyntaxError as exc:  # only with lazy parsing: checked programs parse
            d = exc.diagnostics[0]
            raise RuntimeAlarm(AlarmCode.PROGRAM_INVALID,
                               f"{d.span}: {d.code.code}: {d.message}") from None
        where: Where = (loaded.file, index + 1, block.number)
        ops = _BlockCompiler(self, loaded, index, where).compile(block)
        compiled = CompiledBlock(tuple(ops), where, bool(block.items) or block.number is not None)
        loaded.blocks[index] = compiled
        return compiled

    # ---- motion queue -------------------------------------------------------------------

    def _push(self, p: Process, items: list[QueueItem]) -> int:
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
            p.dec_block = "full"
            return WAIT_RETRY
        p.pending = None
        if self.settings.lookahead == 0 and (p.queue or p.int_item is not None):
            p.dec_block = "flush"  # lookahead 0: the decoder waits for each item
            return WAIT_NEXT
        return NEXT

    def _flush(self, p: Process) -> int:
        """Wait until the motion queue is empty (sync_reads, spec 2.4)."""
        if p.queue or p.int_item is not None:
            p.dec_block = "flush"
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
            item = p.queue[0]
            p.int_item = item
            if item.kind == SYNC:
                if not self._run_sync_item(p, item):
                    return
                self._item_done(p)
                continue
            if item.duration > 0:
                self._arm_item(p, item, item.duration)
                self._update_state(p)
                return
            self._item_done(p)

    def _arm_item(self, p: Process, item: QueueItem, duration: float) -> None:
        p.int_started = self.now - (item.duration - duration)
        p.int_timer = self._schedule(duration, lambda: self._timed_done(p, item))

    def _timed_done(self, p: Process, item: QueueItem) -> None:
        p.int_timer = None
        if item.move is not None:
            p.actual = list(item.move.end)
        if item.kind == SYNC:  # a move inside a # block
            p.stats.moving_s += item.duration
            p.sync_i += 1
            self._continue_sync(p)
            return
        p.stats.moving_s += item.duration
        self._item_done(p)
        self._interp_run(p)

    def _item_done(self, p: Process) -> None:
        item = p.queue.popleft()
        if item.move is not None:
            p.actual = list(item.move.end)
        p.int_item = None
        p.sync_i = 0
        if p.dec_block == "full":
            p.dec_block = None
            self._make_runnable(p)
        self._update_state(p)

    def _queue_drained(self, p: Process) -> None:
        if p.dec_block == "flush":
            p.dec_block = None
            self._make_runnable(p)
        elif p.dec_block == "done" and p.loaded is not None and p.alarm is None:
            self._end_program(p)
        else:
            self._update_state(p)
            self._check_deadlock(p)

    def _run_sync_item(self, p: Process, item: QueueItem) -> bool:
        """Run a # block's actions from ``p.sync_i``; False when one of them blocks."""
        actions = item.actions or []
        try:
            while p.sync_i < len(actions):
                action = actions[p.sync_i]
                kind = action[0]
                if kind == "move":
                    move: Move = action[1]
                    if move.duration_s > 0:
                        sub = QueueItem(SYNC, move.duration_s, item.where, move)
                        p.int_started = self.now
                        p.int_timer = self._schedule(move.duration_s,
                                                     functools.partial(self._timed_done, p, sub))
                        return False
                    p.actual = list(move.end)
                elif not self._sync_action(p, "interpolator", action, item.where):
                    p.sync_i += 1
                    return False
                p.sync_i += 1
        except RuntimeAlarm as alarm:
            self._alarm(p, alarm.code, alarm.message, item.where)
            return False
        return True

    def _continue_sync(self, p: Process) -> None:
        item = p.queue[0] if p.queue else None
        if item is None or item.kind != SYNC or p.alarm is not None:
            return
        if self._run_sync_item(p, item):
            self._item_done(p)
            self._interp_run(p)

    # ==== synchronisation ===================================================================

    def _sync_action(self, p: Process, stage: str, action: tuple[Any, ...], where: Where) -> bool:
        """Perform one evaluated code; True when it completed, False when it waits."""
        kind = action[0]
        if kind == "syvar":
            self._write_syvar(p, action[1], action[2], where)
            return True
        if kind == "waip":
            return self._wai_proc(p, stage, action[1], action[2], where)
        if kind == "waic":
            return self._wai_cond(p, stage, action[1], where)
        if kind == "snd":
            return self._snd(p, stage, action[1], action[2], where)
        if kind == "exe":
            return self._exe(p, stage, action[1], action[2], action[3], action[4], where)
        if kind == "dis":
            self._emit("display", p.number, where, text=action[1])
            return True
        if kind in ("tool", "dwell"):
            return True
        raise AssertionError(kind)

    def _begin_wait(self, p: Process, stage: str, wait: WaitRecord) -> None:
        if stage == "decoder":
            p.dec_wait = wait
            p.dec_block = "wait"
        else:
            p.int_wait = wait
        on: dict[str, Any]
        if wait.kind is WaitKind.COND:
            on = {"cond": wait.cond, "value": _json_number(wait.value)}
        else:
            on = {_ON_KEY[wait.kind]: wait.target}
        self._emit("wait", p.number, wait.where, on=on)
        if self._wait_timeout_s:
            wait.timeout = self._schedule(self._wait_timeout_s,
                                          lambda: self._wait_timed_out(p, wait))
        self._update_state(p)

    def _finish_wait(self, p: Process, wait: WaitRecord, by: int | str) -> None:
        """The wait is over: resume the stage that waited."""
        if wait.timeout is not None:
            wait.timeout.cancel()
        self._emit("resume", p.number, wait.where, by=by)
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

    # ---- WAI,n ---------------------------------------------------------------------------

    def _wai_proc(self, p: Process, stage: str, n: int, code: str, where: Where) -> bool:
        if n == p.number:
            raise RuntimeAlarm(AlarmCode.WAIT_FOR_SELF, "a process cannot wait for itself")
        sender = self._process_arg(n)
        pending = self._snd_pending.pop((n, p.number), None)
        if pending is not None:  # a rendezvous sender is already there
            wait = _wait_of(pending, WaitKind.SND)
            self._deliver_snd(pending, p, wait)
            self._finish_wait(pending, wait, p.number)
            return True
        tokens = self._tokens.get((n, p.number))
        if tokens:
            sent_from = tokens.popleft()
            if not tokens:
                del self._tokens[(n, p.number)]
            self._deliver_snd(sender, p, None, where=sent_from, external=sent_from is None)
            return True
        wait = WaitRecord(WaitKind.PROC, n, code, where, self.now, stage)
        self._proc_waiters[(n, p.number)] = p
        self._begin_wait(p, stage, wait)
        if not self._check_orphan(p, wait):
            self._check_deadlock(p)
        return False

    def _end_wait_proc(self, p: Process, sender: int) -> None:
        self._proc_waiters.pop((sender, p.number), None)
        self._finish_wait(p, _wait_of(p, WaitKind.PROC), sender)

    # ---- SND,n ---------------------------------------------------------------------------

    def _snd(self, p: Process, stage: str, n: int, code: str, where: Where) -> bool:
        target = self._process_arg(n)
        if target.external:
            self._deliver_snd(p, target, None, where=where)
            return True
        if target.loaded is None or target.alarm is not None:
            state = "runs no program" if target.alarm is None else "is in ALARM"
            raise RuntimeAlarm(AlarmCode.SND_TO_IDLE, f"SND to process {n}, which {state}")
        if (p.number, n) in self._proc_waiters:
            self._deliver_snd(p, target, None, where=where)
            self._end_wait_proc(target, p.number)
            return True
        if self.settings.snd is SndPolicy.LATCHED:
            self._tokens.setdefault((p.number, n), deque()).append(where)
            self._emit("hazard", p.number, where,
                       message=f"SND to P{n} before P{n} waits for P{p.number}: on the real "
                       f"control this ordering is a race")
            return True
        wait = WaitRecord(WaitKind.SND, n, code, where, self.now, stage)
        self._snd_pending[(p.number, n)] = p
        self._begin_wait(p, stage, wait)
        self._check_deadlock(p)
        return False

    def _deliver_snd(self, sender: Process, target: Process, wait: WaitRecord | None,
                     where: Where | None = None, external: bool = False) -> None:
        if where is None and wait is not None:
            where = wait.where
        if where is None and not external:
            where = sender.where
        sender.stats.snd_sent += 1
        target.stats.snd_received += 1
        n = where[2] if where is not None and where[2] is not None else 0
        # Recorded before the event, so that whoever hears it reads this SND; its number is
        # the value the event counter takes with it.
        self.last_snd = (sender.number, target.number, n, (self.trace.counter + 1) & 0xFFFFFFFF)
        self._emit("snd", sender.number, where, to=target.number)

    # ---- WAI,var op value --------------------------------------------------------------

    def _wai_cond(self, p: Process, stage: str, cond: tuple[Any, ...], where: Where) -> bool:
        area, index, view, op, value, text = cond
        wait = WaitRecord(WaitKind.COND, 0, f"(WAI,{text})", where, self.now, stage, cond=text)

        def satisfied() -> None:
            wait.handle = None
            wait.value = self.image.read(area, index, view)
            self._finish_wait(p, wait, "cond")

        handle = self.image.wait(area, index, view, op, value, satisfied)
        if handle is None:
            return True
        wait.handle = handle
        wait.value = self.image.read(area, index, view)
        wait.writer = self.image.last_writer(area, index, view)
        self._begin_wait(p, stage, wait)
        return False

    def _write_syvar(self, p: Process, index: int, value: int, where: Where) -> None:
        self._writer_proc = p
        try:
            n = f" N{where[2]}" if where[2] is not None else f" line {where[1]}"
            self.image.write([("SYVAR", index, "IN", value)], f"P{p.number}{n}")
        finally:
            self._writer_proc = None

    # ---- EXE -------------------------------------------------------------------------------

    def _exe(self, p: Process, stage: str, n: int, name: str, device: str | None, code: str,
             where: Where) -> bool:
        if n == p.number:
            raise RuntimeAlarm(AlarmCode.EXE_ON_SELF,
                               f"a process cannot start a program in itself (EXE,{n})")
        target = self._process_arg(n)
        if target.external:
            raise RuntimeAlarm(AlarmCode.EXE_ON_EXTERNAL,
                               f"process {n} is external: it runs no part program")
        try:
            program = self.loader.load(name, device, n)
        except ProgramNotFoundError as exc:
            raise RuntimeAlarm(AlarmCode.PROGRAM_NOT_FOUND, str(exc)) from None
        except ProgramError as exc:
            raise RuntimeAlarm(AlarmCode.PROGRAM_INVALID,
                               f"program {name} does not check: {_first_line(exc)}") from None
        if target.loaded is None and target.alarm is None:
            self._emit("exe", p.number, where, to=n, target_prog=program.name)
            self._start_program(target, program, p.number)
            return True
        wait = WaitRecord(WaitKind.EXE, n, code, where, self.now, stage)
        self._exe_waiters.setdefault(n, deque()).append((p, program, code))
        self._begin_wait(p, stage, wait)
        self._check_deadlock(p)
        return False

    def _process_arg(self, n: int) -> Process:
        p = self.processes.get(n)
        if p is None:
            raise RuntimeAlarm(AlarmCode.PROCESS_OUT_OF_RANGE,
                               f"process {n} is not configured (1..{len(self.processes)})")
        return p

    # ==== ends, alarms, deadlocks ============================================================

    def _end_program(self, p: Process) -> None:
        how = p.end_how or "eof"
        where = p.end_where
        p.clear()
        p.loaded = None
        self._emit("end", p.number, where, how=how)
        self._update_state(p)
        self._became_free(p)

    def _became_free(self, p: Process) -> None:
        """P is IDLE (or in ALARM): tokens to it go, its SND partners and EXE waiters move."""
        for key in [k for k in self._tokens if k[1] == p.number]:
            del self._tokens[key]
        for (sender, target), q in list(self._snd_pending.items()):
            if target == p.number:
                del self._snd_pending[(sender, target)]
                state = "runs no program" if p.alarm is None else "is in ALARM"
                wait = q.int_wait or q.dec_wait
                self._alarm(q, AlarmCode.SND_TO_IDLE,
                            f"SND to process {p.number}, which {state}",
                            wait.where if wait else q.where)
        if p.alarm is None and p.loaded is None:
            waiters = self._exe_waiters.get(p.number)
            if waiters:
                q, program, _ = waiters.popleft()
                wait = _wait_of(q, WaitKind.EXE)
                self._emit("exe", q.number, wait.where, to=p.number, target_prog=program.name)
                self._start_program(p, program, q.number)
                self._finish_wait(q, wait, p.number)
        for q in self.processes.values():
            for wait in (q.dec_wait, q.int_wait):
                if wait is not None and wait.kind is WaitKind.PROC:
                    self._check_orphan(q, wait)

    def _alarm(self, p: Process, code: AlarmCode, message: str, where: Where | None) -> None:
        if p.alarm is not None:
            return
        for wait in (p.dec_wait, p.int_wait):
            if wait is not None:
                self._drop_wait(wait)
        if p.int_timer is not None:
            p.int_timer.cancel()
        for key in [k for k, q in self._proc_waiters.items() if q is p]:
            del self._proc_waiters[key]
        for key in [k for k, q in self._snd_pending.items() if q is p]:
            del self._snd_pending[key]
        for n, waiters in self._exe_waiters.items():
            self._exe_waiters[n] = deque(w for w in waiters if w[0] is not p)
        loaded = p.loaded
        p.clear()
        p.loaded = loaded
        p.alarm = (int(code), message, where)
        p.stats.alarms += 1
        self._emit("alarm", p.number, where, code=code.label, message=message)
        self._update_state(p)
        self._became_free(p)

    def _can_be_started(self, n: int, waiter: Process) -> bool:
        if self._exe_waiters.get(n):
            return True
        if not self.settings.closed and n == 1 and self.settings.main:
            return True  # the fieldbus cycle-start command can start main
        for q in self.processes.values():
            if q is waiter or q.loaded is None or q.alarm is not None:
                continue
            if n in q.loaded.exe_targets or q.loaded.dynamic_exe:
                return True
        return False

    def _check_orphan(self, p: Process, wait: WaitRecord) -> bool:
        target = self.processes[wait.target]
        if target.external or target.loaded is not None or target.alarm is not None:
            return False
        if self._can_be_started(wait.target, p):
            return False
        message = (f"orphan wait: {wait.describe(p.number)} waits for P{wait.target}, which "
                   f"runs no program and which no running program can start")
        self._alarm(p, AlarmCode.ORPHAN_WAIT, message, wait.where)
        return True

    def _edges(self, p: Process) -> list[tuple[int, WaitRecord]]:
        return [(w.target, w) for w in (p.int_wait, p.dec_wait)
                if w is not None and w.kind is not WaitKind.COND]

    def _stuck(self, p: Process) -> bool:
        if p.loaded is None or p.alarm is not None or p.held or p.external:
            return False
        if p.dec_block is None:
            return False
        if p.int_timer is not None:
            return False
        return p.int_wait is not None or not p.queue

    def _check_deadlock(self, start: Process) -> None:
        if not self._stuck(start):
            return
        # Most waits are on a process that can still move: no cycle through it.
        stuck = self._stuck
        procs = self.processes
        if not ((start.dec_wait is not None and start.dec_wait.target
                 and stuck(procs[start.dec_wait.target]))
                or (start.int_wait is not None and start.int_wait.target
                    and stuck(procs[start.int_wait.target]))):
            return
        path: list[tuple[Process, WaitRecord]] = []
        on_path: set[int] = set()

        def walk(p: Process) -> bool:
            for target, wait in self._edges(p):
                path.append((p, wait))
                if target == start.number:
                    return True
                q = self.processes[target]
                if target not in on_path and self._stuck(q):
                    on_path.add(target)
                    if walk(q):
                        return True
                    on_path.discard(target)
                path.pop()
            return False

        on_path.add(start.number)
        if not walk(start):
            return
        parts = [wait.describe(p.number) for p, wait in path]
        message = "deadlock: " + " -> ".join(parts) + f" -> P{start.number}"
        cycle = [{"proc": p.number, "prog": w.where[0], "line": w.where[1], "n": w.where[2],
                  "reason": w.code} for p, w in path]
        self._emit("deadlock", 0, None, cycle=cycle, message=message)
        for p, wait in path:
            self._alarm(p, AlarmCode.DEADLOCK, message, wait.where)


def _wait_of(p: Process, kind: WaitKind) -> WaitRecord:
    """The wait of that kind a process is in (its interpolator's, else its decoder's)."""
    for wait in (p.int_wait, p.dec_wait):
        if wait is not None and wait.kind is kind:
            return wait
    raise AssertionError(f"P{p.number} is in no {kind.name} wait")


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _json_number(value: float | None) -> float | int | None:
    if value is None:
        return None
    return int(value) if value == int(value) else value


# ==== compiling a block into decoder ops =====================================================

_MOTION_WORDS: Final = frozenset(AXES) | {"I", "J", "K", "R"}


class _BlockCompiler:
    """Turns one block into the decoder's ops (closures over the engine)."""

    def __init__(self, engine: Engine, loaded: LoadedProgram, index: int, where: Where) -> None:
        self.engine = engine
        self.loaded = loaded
        self.index = index
        self.where = where

    def compile(self, block: Any) -> list[Op]:
        items: tuple[Item, ...] = block.items
        assigns = [i for i in items if isinstance(i, Assign)]
        waits = [i for i in items if isinstance(i, WaitProc | WaitCond)]
        words = [i for i in items if isinstance(i, Word)]
        dwells = [i for i in items if isinstance(i, Dwell)]
        codes = [i for i in items if not isinstance(i, Assign | WaitProc | WaitCond | Word |
                                                     Dwell | InertCode)]
        ops: list[Op] = []
        if self.engine.settings.sync_reads and self._reads_image(items):
            ops.append(self.engine._flush)
        if block.synced:
            ops.extend(self._assign_op(a) for a in assigns if a.target.kind is VarKind.E)
            ops.append(self._synced_op(assigns, waits, words, dwells, codes))
            ops.extend(self._code_op(c) for c in codes if isinstance(c, Jump | Branch | Repeat |
                                                                       EndRepeat | Rel))
            ops.extend(self._end_words(words))
            return ops
        ops.extend(self._assign_op(a) for a in assigns)
        ops.extend(self._wait_op(w) for w in waits)
        if words or dwells:
            ops.append(self._motion_op(words, dwells))
        ops.extend(self._code_op(c) for c in codes)
        ops.extend(self._end_words(words))
        return ops

    @staticmethod
    def _reads_image(items: tuple[Item, ...]) -> bool:
        for item in items:
            exprs: list[Expr] = []
            if isinstance(item, Assign):
                exprs = [item.expr]
            elif isinstance(item, Branch):
                exprs = [item.left, item.right]
            elif isinstance(item, Repeat):
                exprs = [item.count]
            elif isinstance(item, Dwell):
                exprs = [item.seconds]
            elif isinstance(item, Display):
                exprs = list(item.args)
            if any(reads_image(e) for e in exprs):
                return True
        return False

    # ---- evaluation helpers (decode time) ---------------------------------------------

    def _int_arg(self, expr: Expr, what: str) -> Callable[[Process], int]:
        if isinstance(expr, Num) and expr.value == int(expr.value):
            constant = int(expr.value)
            return lambda p: constant
        fn = compile_expr(expr)
        read = self.engine.image.read

        def value(p: Process) -> int:
            v = fn(p.E, read)
            if v != int(v):
                raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"{what} {v:g} is not a whole number")
            return int(v)

        return value

    # ---- assignments ---------------------------------------------------------------------

    def _assign_op(self, item: Assign) -> Op:
        fn = compile_expr(item.expr)
        read = self.engine.image.read
        index = item.target.index
        if item.target.kind is VarKind.E:
            def assign_e(p: Process) -> int:
                p.E[index] = fn(p.E, read)
                return NEXT
            return assign_e
        engine = self.engine
        where = self.where

        def assign_syvar(p: Process) -> int:
            engine._write_syvar(p, index, _int16(fn(p.E, read), f"SYVAR{index}"), where)
            return NEXT
        return assign_syvar

    # ---- waits ---------------------------------------------------------------------------

    def _wait_action(self, item: WaitProc | WaitCond) -> Callable[[Process], tuple[Any, ...]]:
        code = format_item(item)
        if isinstance(item, WaitProc):
            n = self._int_arg(item.process, "process number")
            return lambda p: ("waip", n(p), code)
        var = item.var
        fn = compile_expr(item.value)
        read = self.engine.image.read
        area, index, view = var.kind.value, var.index, var.view.value
        op = item.op.value

        def cond(p: Process) -> tuple[Any, ...]:
            value = fn(p.E, read)
            shown = _fmt(value)
            text = f"{var.name}{op}{shown}"
            if value != int(value):
                # An integer variable never equals a fraction: compare as the spec's types do.
                raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT,
                                   f"(WAI,{text}): {var.name} holds whole numbers")
            return ("waic", (area, index, view, op, int(value), text))
        return cond

    def _exchange_op(self, item: WaitProc | Snd,
                     method: Callable[[Process, str, int, str, Where], bool]) -> Op:
        """(WAI,n) and (SND,n): the hot path of a SND/WAI exchange, no action tuple and no
        dispatch between the op and the engine."""
        n = self._int_arg(item.process, "process number")
        code = format_item(item)
        where = self.where

        def exchange(p: Process) -> int:
            return NEXT if method(p, "decoder", n(p), code, where) else WAIT_NEXT
        return exchange

    def _wait_op(self, item: WaitProc | WaitCond) -> Op:
        engine = self.engine
        where = self.where
        if isinstance(item, WaitProc):
            return self._exchange_op(item, engine._wai_proc)
        action = self._wait_action(item)

        def wait(p: Process) -> int:
            if engine._sync_action(p, "decoder", action(p), where):
                return NEXT
            return WAIT_NEXT
        return wait

    # ---- motion --------------------------------------------------------------------------

    def _plan(self, p: Process, words: list[Word], dwells: list[Dwell]) -> list[QueueItem]:
        engine = self.engine
        settings = engine.settings
        read = engine.image.read
        modal = p.modal
        axes: dict[str, float] = {}
        arc: dict[str, float] = {}
        items: list[QueueItem] = []
        tool_change = False
        for word in words:
            value = word.value
            v = p.E[value.index] if not isinstance(value, float) else value
            letter = word.letter
            if letter == "G":
                g = int(v)
                if g in (0, 1, 2, 3):
                    modal.motion = g
                elif g in (17, 18, 19):
                    modal.plane = g
                elif g == 90:
                    modal.absolute = True
                elif g == 91:
                    modal.absolute = False
            elif letter == "F":
                modal.feed_mm_min = v
            elif letter == "T":
                modal.tool = word.text
            elif letter == "M" and int(v) == 6:
                tool_change = True
            elif letter in _MOTION_WORDS:
                (arc if letter in "IJKR" else axes)[letter] = v
        where = self.where
        if tool_change:
            items.append(QueueItem(TOOL, settings.tool_change_s, where))
        move = plan_move(modal, axes, arc, settings.rapid_mm_min)
        if move is not None:
            items.append(QueueItem(MOVE, move.duration_s, where, move))
        for dwell in dwells:
            seconds = compile_expr(dwell.seconds)(p.E, read)
            if seconds < 0:
                raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"(DLY,{seconds:g}): negative time")
            items.append(QueueItem(DWELL, seconds, where))
        return items

    def _motion_op(self, words: list[Word], dwells: list[Dwell]) -> Op:
        engine = self.engine

        def motion(p: Process) -> int:
            if p.pending is None:
                return engine._push(p, self._plan(p, words, dwells))
            return engine._push(p, p.pending)
        return motion

    def _end_words(self, words: list[Word]) -> list[Op]:
        for word in words:
            if word.letter == "M" and isinstance(word.value, float) and word.value in (30, 2):
                how = "M30" if word.value == 30 else "M02"
                return [self._end_op(how)]
        return []

    def _end_op(self, how: str) -> Op:
        engine = self.engine
        where = self.where

        def end(p: Process) -> int:
            engine._decoder_end(p, how, where)
            return END
        return end

    # ---- a # block: evaluated now, acting in motion order ---------------------------------

    def _synced_op(self, assigns: list[Assign], waits: list[WaitProc | WaitCond],
                   words: list[Word], dwells: list[Dwell], codes: Sequence[Item]) -> Op:
        engine = self.engine
        read = engine.image.read
        syvars = [(a.target.index, compile_expr(a.expr)) for a in assigns
                  if a.target.kind is VarKind.SYVAR]
        wait_actions = [self._wait_action(w) for w in waits]
        code_actions = [self._code_action(c) for c in codes
                        if isinstance(c, Snd | Exe | Display)]
        where = self.where

        def synced(p: Process) -> int:
            if p.pending is not None:
                return engine._push(p, p.pending)
            actions: list[tuple[Any, ...]] = [
                ("syvar", i, _int16(fn(p.E, read), f"SYVAR{i}")) for i, fn in syvars]
            actions.extend(make(p) for make in wait_actions)
            for item in self._plan(p, words, dwells):
                if item.move is not None:
                    actions.append(("move", item.move))
                else:  # tool change or dwell inside a # block: a timed move of no length
                    actions.append(("move", Move(tuple(p.modal.position),
                                                 tuple(p.modal.position), 0.0, item.duration)))
            actions.extend(make(p) for make in code_actions)
            return engine._push(p, [QueueItem(SYNC, 0.0, where, None, actions)])
        return synced

    # ---- codes ---------------------------------------------------------------------------

    def _code_action(self, item: Item) -> Callable[[Process], tuple[Any, ...]]:
        code = format_item(item)
        if isinstance(item, Snd):
            n = self._int_arg(item.process, "process number")
            return lambda p: ("snd", n(p), code)
        if isinstance(item, Exe):
            n = self._int_arg(item.process, "process number")
            name, device = item.program, item.device
            return lambda p: ("exe", n(p), name, device, code)
        assert isinstance(item, Display)
        fns = [compile_expr(a) for a in item.args]
        read = self.engine.image.read
        text = item.text

        def display(p: Process) -> tuple[Any, ...]:
            values = " ".join(_fmt(fn(p.E, read)) for fn in fns)
            return ("dis", f"{text} {values}" if values else text)
        return display

    def _code_op(self, item: Item) -> Op:
        engine = self.engine
        where = self.where
        labels = self.loaded.program.labels
        if isinstance(item, Snd):
            return self._exchange_op(item, engine._snd)
        if isinstance(item, Exe | Display):
            action = self._code_action(item)

            def code(p: Process) -> int:
                return NEXT if engine._sync_action(p, "decoder", action(p), where) else WAIT_NEXT
            return code
        if isinstance(item, Rel):
            return self._end_op("REL")
        if isinstance(item, Jump | Branch):
            target = labels.get(item.label.upper())
            label = item.label
            if isinstance(item, Branch):
                left, right = compile_expr(item.left), compile_expr(item.right)
                holds = _BRANCH_TESTS[item.op]
            read = engine.image.read

            def jump(p: Process) -> int:
                if target is None:
                    raise RuntimeAlarm(AlarmCode.UNKNOWN_LABEL, f'label "{label}" is not defined')
                p.pc = target
                p.block = None
                return JUMP

            if isinstance(item, Jump):
                return jump

            def branch(p: Process) -> int:
                if holds(left(p.E, read), right(p.E, read)):
                    return jump(p)
                return NEXT
            return branch
        if isinstance(item, Repeat):
            count = self._int_arg(item.count, "repeat count")
            index = self.index

            def repeat(p: Process) -> int:
                n = count(p)
                if n < 1:
                    raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"(RPT,{n}): count below 1")
                p.repeats.append([index, n])
                return NEXT
            return repeat
        assert isinstance(item, EndRepeat)

        def end_repeat(p: Process) -> int:
            if not p.repeats:
                raise RuntimeAlarm(AlarmCode.REPEAT_MISMATCH, "(ERP) without a matching (RPT)")
            frame = p.repeats[-1]
            frame[1] -= 1
            if frame[1] > 0:
                p.pc = frame[0] + 1
                p.block = None
                return JUMP
            p.repeats.pop()
            return NEXT
        return end_repeat


_BRANCH_TESTS: Final[dict[BranchOp, Callable[[float, float], bool]]] = {
    BranchOp.EQ: operator.eq, BranchOp.NE: operator.ne, BranchOp.GT: operator.gt,
    BranchOp.GE: operator.ge, BranchOp.LT: operator.lt, BranchOp.LE: operator.le,
}


def _int16(value: float, name: str) -> int:
    stored = round_half_away(value)
    if not -32768 <= stored <= 32767:
        raise RuntimeAlarm(AlarmCode.VALUE_OUT_OF_RANGE,
                           f"{name} holds -32768..32767, not {value:g}")
    return stored


def run_virtual(engine: Engine, until: float | None = None,
                before_time: Callable[[float], None] | None = None) -> str:
    """Run on the virtual clock until every process is idle, or ``until``.

    Returns ``"idle"``, ``"until"`` or ``"blocked"`` (nothing runnable and no timer left
    while a process still has a program: the caller reports a stall).

    The cyclic collector is paused meanwhile (see :func:`interpreter.parser.gc_paused`): a
    simulation is a bounded batch job whose trace only grows.
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

