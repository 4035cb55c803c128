"""The synchronisation rules of spec 2.2: EXE, REL, WAI, SND, latched tokens, rendezvous.

The rules, as transitions (k is the process executing the code, n the one it names):

    (WAI,n)   n already waits in (SND,k)   -> the SND is delivered; n resumes, k goes on
              a latched token n->k exists  -> it is consumed (delivered); k goes on
              otherwise                    -> k waits in WAIT_PROC on n
                                              (orphan check, then deadlock check)
    (SND,n)   n is external                -> published on the fieldbus; k goes on
              n is IDLE or in ALARM        -> alarm of k (SND_TO_IDLE)
              n waits in (WAI,k)           -> delivered; n resumes, k goes on
              snd = latched                -> a token k->n, and a `hazard` event; k goes on
              otherwise (rendezvous)       -> k waits in WAIT_SND on n (deadlock check)
    (EXE,n,P) n is k or external           -> alarm of k
              P cannot be loaded           -> alarm of k
              n is IDLE                    -> P starts in n; k goes on
              otherwise                    -> k waits in WAIT_EXE, first come first served
    (WAI,var op value)                     -> level-triggered: goes on if it holds, else waits
                                              until the write that makes it true
    n becomes free (its program ended, or it is in ALARM):
              tokens to n are discarded; a rendezvous sender to n gets an alarm; the first
              EXE waiting for n starts its program (if n is IDLE); every WAI on an idle
              process is checked for being an orphan.
    An external process k (the fieldbus) sends (SND,n): delivered if n waits for k, else
    latched (it cannot be made to wait) with a `hazard` event.

:class:`Sync` holds the state these rules keep (who waits for whom, latched tokens, EXE
queues, the SND log) and is a part of the :class:`~.engine.Engine`, which owns it and calls it.
The engine core provides the waits, alarms and program starts the rules use: what it must
provide is :class:`SyncHost`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping
from typing import Protocol

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import (
    ProgramError,
    ProgramNotFoundError,
    RuntimeAlarm,
)
from ncgate.interpreter.engine import deadlock
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.actions import Execute, ItemKind, WaitCondition
from ncgate.interpreter.engine.aux import AuxOutput
from ncgate.interpreter.engine.events import Blocked
from ncgate.interpreter.engine.ports import FrontEnd, ImagePort, ProgramLoader, ProgramText
from ncgate.interpreter.engine.process import Process
from ncgate.interpreter.engine.states import Stage, WaitKind, WaitRecord, Where, describe_where
from ncgate.interpreter.engine.trace import Trace
from ncgate.interpreter.settings import Handshake, RuntimeSettings, SndPolicy

SND_LOG = 16  # entries of the SND log the fieldbus shows


class SyncHost(Protocol):
    """What the rules need of the engine core (the :class:`~.engine.Engine` is one)."""

    @property
    def settings(self) -> RuntimeSettings: ...

    @property
    def image(self) -> ImagePort: ...

    @property
    def loader(self) -> ProgramLoader: ...

    @property
    def trace(self) -> Trace: ...

    @property
    def processes(self) -> Mapping[int, Process]: ...

    @property
    def front_end(self) -> FrontEnd: ...

    @property
    def now(self) -> float: ...

    def begin_wait(self, p: Process, stage: Stage, wait: WaitRecord) -> None: ...

    def finish_wait(self, p: Process, wait: WaitRecord, by: int | str) -> None: ...

    def alarm(self, p: Process, code: AlarmCode, message: str, where: Where | None) -> None: ...

    def start_program(self, p: Process, program: ProgramText, by: str | int) -> None: ...

    def kick(self) -> None: ...


class Sync:
    """EXE/REL/WAI/SND between processes: the rules above and the state they keep."""

    def __init__(self, host: SyncHost) -> None:
        self._host = host
        # Bound once: the SND/WAI hot path reads these on every exchange.
        self.settings = host.settings
        self.image = host.image
        self.loader = host.loader
        self.trace = host.trace
        self.processes = host.processes
        self._record: Callable[..., None] = host.trace.record
        self._begin_wait = host.begin_wait
        self._finish_wait = host.finish_wait
        self._alarm = host.alarm
        self._start_program = host.start_program
        self._kick = host.kick
        self._names = dict(host.settings.names)
        # Whether something outside the programs may still start a program in a process (an
        # orphan wait is one nothing can end).  Open cell (run, the Gateway API): the
        # operator may start any process (console Start, Gateway.start), so yes.  Closed
        # (sim, replay): no, unless the simulator says so (a script's start to come, the
        # PLC logic's cycle start) by setting this.
        # What drives a variable a condition waits on (the plant's model, "clamp extends,
        # 120 of 300 ms"), for the why-record; None: nothing to say.
        self.explain: Callable[[tuple[str, int, str]], str | None] | None = None
        self.outside_starts: Callable[[int], bool] = (
            (lambda n: False) if host.settings.closed else (lambda n: True))

    # ---- state --------------------------------------------------------------------------

        self._proc_waiters: dict[tuple[int, int], Process] = {}  # (waited-for, waiter)
        self._snd_pending: dict[tuple[int, int], Process] = {}  # (sender, target)
        # Latched SNDs not yet taken: (sender, target) -> where each was sent from (None: by
        # the fieldbus), oldest first.
        self._tokens: dict[tuple[int, int], deque[Where | None]] = {}
        self._exe_waiters: dict[int, deque[tuple[Process, ProgramText, str]]] = {}
        self.writer_proc: Process | None = None
        self.writer_where: Where | None = None  # the block of the write under way
        # The last SND delivered: sender, target, N, its number on the event counter.
        self.last_snd: tuple[int, int, int, int] | None = None
        # The SND log (the Modbus window of the last SND_LOG): (sequence, sender, target, N,
        # id), newest last.  The sequence counts every SND since the engine was made (1, 2,
        # ...); a reset does not restart it, so a poller can tell what it missed.
        self.snd_seq = 0
        self.snd_log: deque[tuple[int, int, int, int, int]] = deque(maxlen=SND_LOG)

    def clear(self) -> None:
        """A reset: nobody waits, no token is latched, no EXE is queued."""
        self._proc_waiters.clear()
        self._snd_pending.clear()
        self._tokens.clear()
        self._exe_waiters.clear()

    def forget_waiter(self, p: Process) -> None:
        """P is in ALARM: it waits for nobody any more."""
        for key in [k for k, q in self._proc_waiters.items() if q is p]:
            del self._proc_waiters[key]
        for key in [k for k, q in self._snd_pending.items() if q is p]:
            del self._snd_pending[key]
        for n, waiters in self._exe_waiters.items():
            self._exe_waiters[n] = deque(w for w in waiters if w[0] is not p)

    # ---- WAI,n ----------------------------------------------------------------------------

    def wait_process(self, p: Process, stage: Stage, n: int, code: str, where: Where) -> bool:
        if p.queue and stage is Stage.DECODER:
            self.acts_early(p, code, where)
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
        wait = WaitRecord(WaitKind.PROC, n, code, where, self._host.now, stage)
        self._proc_waiters[(n, p.number)] = p
        self._begin_wait(p, stage, wait)
        if not self.check_orphan(p, wait):
            self.check_deadlock(p)
        return False

    def _end_wait_proc(self, p: Process, sender: int) -> None:
        self._proc_waiters.pop((sender, p.number), None)
        self._finish_wait(p, _wait_of(p, WaitKind.PROC), sender)

    # ---- SND,n ----------------------------------------------------------------------------

    def send(self, p: Process, stage: Stage, n: int, code: str, where: Where) -> bool:
        if p.queue and stage is Stage.DECODER:
            self.acts_early(p, code, where)
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
            self._record(ev.Hazard, self._host.now, p.number, where,
                         f"SND to P{n} before P{n} waits for P{p.number}: on the real control "
                         "this ordering is a race")
            return True
        wait = WaitRecord(WaitKind.SND, n, code, where, self._host.now, stage)
        self._snd_pending[(p.number, n)] = p
        self._begin_wait(p, stage, wait)
        self.check_deadlock(p)
        return False

    def external_snd(self, sender: int, target: int) -> None:
        """An SND in the name of external process ``sender`` (fieldbus mailbox, script)."""
        s = self.process(sender)
        if not s.external:
            raise ValueError(f"process {sender} is not external")
        t = self.process(target)
        if t.external:
            self._deliver_snd(s, t, None, external=True)
            return
        if t.loaded is None or t.alarm is not None:
            raise ValueError(f"SND to process {target}, which runs no program")
        if (sender, target) in self._proc_waiters:
            self._deliver_snd(s, t, None, external=True)
            self._end_wait_proc(t, sender)
        else:
            # An external sender cannot be made to wait: latch it, and say it is a race.
            self._tokens.setdefault((sender, target), deque()).append(None)
            self._record(ev.Hazard, self._host.now, sender, None,
                         f"SND from external P{sender} to P{target} before P{target} waits "
                         "for it: latched")
        self._kick()

    def count_signal(self, sender: Process, target: int, ident: int, where: Where) -> None:
        """A dialect's stored signal counts like an SND on the fieldbus (spec 5.6); call it
        just before recording the signal's event (its number is the counter's next value)."""
        sender.stats.snd_sent += 1
        n = where[2] if where[2] is not None else 0
        self.last_snd = (sender.number, target, n, (self.trace.counter + 1) & 0xFFFFFFFF)
        self._log_snd(sender.number, target, n, ident)

    def _log_snd(self, sender: int, target: int, n: int, ident: int = 0) -> None:
        """One entry of the SND log (target 0: a broadcast; ident: a signal's number)."""
        self.snd_seq = seq = self.snd_seq + 1
        self.snd_log.append((seq, sender, target, n, ident))

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
        self._log_snd(sender.number, target.number, n)
        self._record(ev.Snd, self._host.now, sender.number, where, target.number)

    # ---- WAI,var op value -----------------------------------------------------------------

    def wait_condition(self, p: Process, stage: Stage, cond: WaitCondition,
                        where: Where) -> bool:
        if p.queue and stage is Stage.DECODER:
            self.acts_early(p, f"(WAI,{cond.text})", where)
        area, index, view = cond.area, cond.index, cond.view
        wait = WaitRecord(WaitKind.COND, 0, f"(WAI,{cond.text})", where, self._host.now, stage,
                          cond=cond.text)
        if self._names:
            wait.name = self._names.get((area, index, view))

        def satisfied() -> None:
            wait.handle = None
            wait.probe = None
            wait.value = self.image.read(area, index, view)
            wait.writer = self.image.last_writer(area, index, view)
            self._finish_wait(p, wait, "cond")

        handle = self.image.wait(area, index, view, cond.test, satisfied)
        if handle is None:
            return True
        wait.handle = handle
        wait.value = self.image.read(area, index, view)
        wait.writer = self.image.last_writer(area, index, view)
        image = self.image
        def probe() -> tuple[int, str | None]:
            writer = image.last_writer(area, index, view)
            explain = self.explain
            note = explain((area, index, view)) if explain is not None else None
            if note:  # the plant model that drives it: what it is doing now
                writer = f"{writer}; {note}" if writer else note
            return image.read(area, index, view), writer

        wait.probe = probe
        self._begin_wait(p, stage, wait)
        return False

    def write_syvar(self, p: Process, index: int, value: int, where: Where,
                    stage: Stage = Stage.DECODER) -> None:
        if p.queue and stage is Stage.DECODER:
            self.acts_early(p, f"SYVAR{index}={value}", where)
        self.write_image(p, "SYVAR", index, "IN", value, where)

    def write_image(self, p: Process, area: str, index: int, view: str, value: int,
                    where: Where) -> None:
        """A program's write of an image variable, in the name of its block (the trace's
        ``write`` event names the process and the block)."""
        self.write_changes(p, [(area, index, view, value)], where)

    def write_changes(self, p: Process, changes: list[tuple[str, int, str, int]],
                      where: Where) -> None:
        """Several variables in one atomic write, in the name of ``p``'s block."""
        self.writer_proc = p
        self.writer_where = where
        try:
            n = f" N{where[2]}" if where[2] is not None else f" line {where[1]}"
            self.image.write(changes, f"P{p.number}{n}")
        finally:
            self.writer_proc = None

    def acts_early(self, p: Process, code: str, where: Where) -> None:
        """A plain (not #) SND, WAI or SYVAR write acts when the decoder reaches it (spec 2.4),
        here while motion programmed above it is still queued: on the machine it happens
        before that motion ends.  Legal (manual 1.4), but rarely what was meant: say so.
        An auxiliary function with a handshake still queued is a sync point it crosses: the
        hazard names it."""
        for item in p.queue:
            if item.kind is ItemKind.AUX:
                for aux in item.actions or ():
                    if isinstance(aux, AuxOutput) and aux.handshake is not Handshake.NONE:
                        _, line, n = item.where
                        above = f"N{n}" if n is not None else f"line {line}"
                        self._record(ev.Hazard, self._host.now, p.number, where,
                                     f"{code} acted at decode time before the PLC acknowledged "
                                     f"{aux.shown} above it ({above}): a handshake is a sync "
                                     "point; mark the block # to act in motion order, or set "
                                     "nc.lookahead = 0")
                        return
        _, line, n = p.queue[0].where
        above = f"N{n}" if n is not None else f"line {line}"
        self._record(ev.Hazard, self._host.now, p.number, where,
                     f"{code} acted at decode time while motion programmed above it ({above}) "
                     "was still queued; mark the block # to act in motion order, or set "
                     "nc.lookahead = 0")

    # ---- EXE --------------------------------------------------------------------------------

    def execute(self, p: Process, stage: Stage, exe: Execute, where: Where) -> bool:
        n, name, code = exe.process, exe.program, exe.code
        if n == p.number:
            raise RuntimeAlarm(AlarmCode.EXE_ON_SELF,
                               f"a process cannot start a program in itself (EXE,{n})")
        target = self._process_arg(n)
        if target.external:
            raise RuntimeAlarm(AlarmCode.EXE_ON_EXTERNAL,
                               f"process {n} is external: it runs no part program")
        try:
            program = self.loader.load(name, exe.device, n)
        except ProgramNotFoundError as exc:
            raise RuntimeAlarm(AlarmCode.PROGRAM_NOT_FOUND, str(exc)) from None
        except ProgramError as exc:
            raise RuntimeAlarm(AlarmCode.PROGRAM_INVALID,
                               f"program {name} does not check: {first_line(exc)}") from None
        if target.loaded is None and target.alarm is None:
            self._record(ev.Exe, self._host.now, p.number, where, n, program.name)
            self._start_program(target, program, p.number)
            return True
        wait = WaitRecord(WaitKind.EXE, n, code, where, self._host.now, stage)
        self._exe_waiters.setdefault(n, deque()).append((p, program, code))
        self._begin_wait(p, stage, wait)
        self.check_deadlock(p)
        return False

    def process(self, number: int) -> Process:
        p = self.processes.get(number)
        if p is None:
            raise ValueError(f"process {number} is not configured (1..{len(self.processes)})")
        return p

    def _process_arg(self, n: int) -> Process:
        p = self.processes.get(n)
        if p is None:
            raise RuntimeAlarm(AlarmCode.PROCESS_OUT_OF_RANGE,
                               f"process {n} is not configured (1..{len(self.processes)})")
        return p

    # ---- a process becomes free ---------------------------------------------------------

    def became_free(self, p: Process) -> None:
        """P is IDLE (or in ALARM): tokens to it go, its SND partners and EXE waiters move."""
        for key in [k for k in self._tokens if k[1] == p.number]:
            state = "is in ALARM" if p.alarm is not None else "ended its program"
            for sent_from in self._tokens.pop(key):
                at = f" at {describe_where(sent_from)}" if sent_from is not None else ""
                self._record(ev.Hazard, self._host.now, key[0], sent_from,
                             f"latched SND from P{key[0]}{at} to P{p.number} discarded: "
                             f"P{p.number} {state} before a WAI took it")
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
                self._record(ev.Exe, self._host.now, q.number, wait.where, p.number, program.name)
                self._start_program(p, program, q.number)
                self._finish_wait(q, wait, p.number)
        for q in self.processes.values():
            for wait in (q.dec_wait, q.int_wait):
                if wait is not None and wait.kind is WaitKind.PROC:
                    self.check_orphan(q, wait)

    # ---- deadlocks and orphans (the search itself: deadlock.py) ----------------------------

    def check_orphan(self, p: Process, wait: WaitRecord) -> bool:
        for number in (wait.targets if wait.targets is not None else (wait.target,)):
            if not number:  # a broadcast signal wait: anyone may send it
                continue
            target = self.processes[number]
            if target.external or target.loaded is not None or target.alarm is not None:
                continue
            queued = [program for waiters in self._exe_waiters.values()
                      for _, program, _ in waiters]
            if self._exe_waiters.get(number) or deadlock.can_be_started(
                    number, p, self.processes, queued, self.outside_starts, self._scan,
                    self._load_quietly):
                continue
            self._alarm(p, AlarmCode.ORPHAN_WAIT, deadlock.orphan_message(p, wait, number),
                        wait.where)
            return True
        return False

    def _scan(self, program: ProgramText) -> deadlock.Scan:
        front_end = self._host.front_end
        targets, dynamic = front_end.exe_targets(program)
        return targets, dynamic, front_end.exe_calls(program)

    def _load_quietly(self, name: str, process: int) -> ProgramText | None:
        """A program an EXE names, for the orphan check: None when it cannot be loaded (its
        EXE will be the alarm, when it runs)."""
        try:
            return self.loader.load(name, None, process)
        except (ProgramError, ProgramNotFoundError):
            return None

    def check_deadlock(self, start: Process) -> None:
        cycle = deadlock.find_cycle(start, self.processes)
        if cycle is None:
            return
        message = deadlock.describe_cycle(start, cycle)
        blocked = tuple(Blocked(p.number, *w.where, w.code) for p, w in cycle)
        self._record(ev.Deadlock, self._host.now, 0, None, blocked, message)
        # Every member is the deadlock: none of them may first be alarmed as the partner of
        # another (an SND to a process in ALARM), so none of them waits for anyone any more.
        for p, _ in cycle:
            self.forget_waiter(p)
        for p, wait in cycle:
            self._alarm(p, AlarmCode.DEADLOCK, message, wait.where)


def _wait_of(p: Process, kind: WaitKind) -> WaitRecord:
    """The wait of that kind a process is in (its interpolator's, else its decoder's)."""
    if p.int_wait is not None and p.int_wait.kind is kind:
        return p.int_wait
    if p.dec_wait is not None and p.dec_wait.kind is kind:
        return p.dec_wait
    raise AssertionError(f"P{p.number} is in no {kind.name} wait")


def first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__

