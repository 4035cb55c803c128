"""States and records: what a process is doing and why (spec 2.1, 2.2.6), as enums and
dataclasses, and the state table the engine runs: :data:`STATE_RULES` (how a process's state
follows from what it is doing) and :data:`TRANSITIONS` (every change of state the engine may
make, and what causes it).  ARCHITECTURE.md prints both, from :func:`state_table_markdown` (a
test keeps it so).  Everything else in the engine speaks these types."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final, NamedTuple

from ncgate.interpreter.diagnostics import fmt_number
from ncgate.interpreter.engine.actions import ItemKind

if TYPE_CHECKING:
    from ncgate.interpreter.engine.ports import Cancellable
    from ncgate.interpreter.engine.process import Process
    from ncgate.interpreter.engine.timers import Timer

Where = tuple[str, int, int | None]  # program file, line, N


def describe_where(where: Where) -> str:
    """``DZ.nc:3 N30`` (no N: ``DZ.nc:3``)."""
    file, line, n = where
    return f"{file}:{line} N{n}" if n is not None else f"{file}:{line}"


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
    STEP = 9  # single block: stopped after a block, until a cycle start or a step


class WaitKind(enum.IntEnum):
    """Spec 3.2 (process status, wait kind)."""

    NONE = 0
    PROC = 1
    COND = 2
    SND = 3
    EXE = 4
    FLUSH = 5  # the decoder waits for its interpolator (#FLUSH, a synchronous V.E. read)
    AUX = 6  # an auxiliary function (M, S, T, H) waits for the PLC's acknowledge ([nc.aux])


class Stage(enum.Enum):
    """The two stages of a process's pipeline (spec 2.4): which one waits."""

    DECODER = "decoder"
    INTERPOLATOR = "interpolator"


class DecoderHold(enum.Enum):
    """Why the decoder does not run (None on a process: it may)."""

    WAIT = "wait"  # in a wait of its own (dec_wait)
    FULL = "full"  # the motion queue is full: retry the block when an item is done
    FLUSH = "flush"  # until the motion queue is empty (lookahead 0, sync_reads)
    DONE = "done"  # reached the end; the program ends when the queue drains
    BLOCK_TIME = "block_time"  # nc.block_time_ms: the last block's processing time runs
    STEP = "step"  # single block: stopped after a block until a cycle start or a step


STATE_OF_WAIT: Final = {WaitKind.PROC: ProcessState.WAIT_PROC,
                        WaitKind.COND: ProcessState.WAIT_COND,
                        WaitKind.SND: ProcessState.WAIT_SND,
                        WaitKind.EXE: ProcessState.WAIT_EXE,
                        WaitKind.FLUSH: ProcessState.WAIT_COND,
                        WaitKind.AUX: ProcessState.WAIT_COND}
# The summary's buckets: "running s" and "waiting s".  A feed hold is time spent waiting
# (for a cycle start), not running, whatever the process did when the hold came; so is a
# stop after a block (STEP: single block, M00/M01, a breakpoint), until a cycle start or a
# step -- an operator's minute at an M00 is no minute of running.
RUNNING_STATES: Final = frozenset({ProcessState.RUNNING, ProcessState.DWELL})
WAITING_STATES: Final = frozenset(STATE_OF_WAIT.values())


@dataclass(slots=True)
class WaitRecord:
    """Why a process waits (spec 2.2.6): what the status registers and reports show."""

    kind: WaitKind
    target: int  # the process waited for (PROC, SND, EXE); 0 for a condition
    code: str  # the code as written, e.g. "(WAI,2)"
    where: Where
    since: float
    stage: Stage
    cond: str | None = None
    value: float | None = None
    writer: str | None = None
    handle: Cancellable | None = None
    timeout: Timer | None = None
    # A condition's variable as it is now: (value, last writer).  The why-record shows the
    # current value and who wrote it last (spec 2.2.6), not those from when the wait began.
    probe: Callable[[], tuple[int, str | None]] | None = None
    # A dialect's own wait (an ISG signal): what the trace's ``wait`` event shows as ``on``,
    # the reason as said (instead of the built-in wording), every process that must still act
    # for it (the wait-for edges; None: ``target``), and a note for a deadlock or stall
    # report, asked for when one is found (the buffered #SIGNAL SYN and the fix).
    on: object | None = None
    text: str | Callable[[], str] | None = None
    targets: tuple[int, ...] | None = None
    note: Callable[[], str | None] | None = None
    name: str | None = None  # a condition's variable's I/O name ([symbols]), shown beside it

    def describe(self, proc: int) -> str:
        return f"P{proc} {describe_where(self.where)} {self.code}"

    def reason(self) -> str:
        if self.text is not None:
            return self.text if isinstance(self.text, str) else self.text()
        if self.kind is WaitKind.COND:
            value, writer = self.probe() if self.probe is not None else (self.value, self.writer)
            by = f", last written by {writer}" if writer else ""
            cond = f"{self.name} ({self.cond})" if self.name else self.cond
            return f"waits for {cond} (now {fmt_number(value)}{by})"
        return {WaitKind.PROC: f"waits for an SND from P{self.target}",
                WaitKind.SND: f"waits for P{self.target} to take its SND",
                WaitKind.EXE: f"waits for P{self.target} to be free",
                WaitKind.FLUSH: "waits for its interpolator to run every block before it",
                WaitKind.AUX: "waits for the PLC to acknowledge it",
                }.get(self.kind, "waits")


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
    """A process as the fieldbus and the API show it."""

    number: int
    state: ProcessState
    external: bool
    program: str | None
    line: int
    n: int | None
    wait: WaitRecord | None
    alarm_code: int
    alarm_message: str | None  # with the alarm's place first: "DZ.nc:3 N30: division by zero"
    snd_sent: int
    snd_received: int
    blocks: int
    position: tuple[float, ...]
    motion_active: bool
    held: bool
    alarm_where: Where | None = None  # where the alarm struck (line and n are its line and N)

    @property
    def wait_kind(self) -> WaitKind:
        return self.wait.kind if self.wait else WaitKind.NONE

    @property
    def wait_target(self) -> int:
        return self.wait.target if self.wait else 0


# ---- the state table ------------------------------------------------------------------------

class StateRule(NamedTuple):
    """A process whose ``test`` holds is in the state ``state`` gives; the first rule whose
    test holds wins.  Both are Python expressions over the process ``p``: the rules are
    compiled into one function (:func:`compile_state_rules`), because the engine derives a
    state on every wait and every resume (the SND/WAI hot path)."""

    states: tuple[ProcessState, ...]  # what the rule can decide (for the printed table)
    when: str
    test: str
    state: str


_WAITS = (ProcessState.WAIT_PROC, ProcessState.WAIT_COND, ProcessState.WAIT_SND,
          ProcessState.WAIT_EXE)

# A process's state is derived, never stored by hand: Engine._update_state runs these rules.
STATE_RULES: Final = (
    StateRule((ProcessState.ALARM,), "an alarm is pending (until a reset)",
              "p.alarm is not None", "ALARM"),
    StateRule((ProcessState.IDLE,), "no program is loaded (an external process always)",
              "p.loaded is None", "IDLE"),
    StateRule((ProcessState.HOLD,), "a feed hold is on", "p.held", "HOLD"),
    StateRule((ProcessState.STEP,), "single block: it stopped after a block whose motion has "
              "run, until a cycle start or a step",
              "p.dec_block is STEP_HOLD and p.int_item is None and not p.queue", "STEP"),
    StateRule(_WAITS, "the interpolator waits (the wait the machine feels, spec 2.4): the "
              "state of its wait kind (FLUSH and AUX show as WAIT_COND)",
              "p.int_wait is not None", "STATE_OF_WAIT[p.int_wait.kind]"),
    StateRule(_WAITS, "the decoder waits: the state of its wait kind",
              "p.dec_wait is not None", "STATE_OF_WAIT[p.dec_wait.kind]"),
    StateRule((ProcessState.DWELL,), "the interpolator runs a dwell (`DLY`, `G4`)",
              "p.int_item is not None and p.int_item.kind == DWELL_ITEM", "DWELL"),
    StateRule((ProcessState.RUNNING,), "otherwise", "True", "RUNNING"),
)


def compile_state_rules(rules: tuple[StateRule, ...]) -> Callable[[Process], ProcessState]:
    """The rules as one function ``derive(p)``: each rule an ``if`` in the table's order."""
    lines = ["def derive(p):"]
    for rule in rules:
        lines += [f"    if {rule.test}:", f"        return {rule.state}"]
    lines.append("    raise AssertionError('no state rule decides')")
    names: dict[str, object] = {s.name: s for s in ProcessState}
    names.update(STATE_OF_WAIT=STATE_OF_WAIT, DWELL_ITEM=ItemKind.DWELL,
                 STEP_HOLD=DecoderHold.STEP)
    exec(compile("\n".join(lines), "<states.STATE_RULES>", "exec"), names)
    derive: Callable[[Process], ProcessState] = names["derive"]  # type: ignore[assignment]
    return derive


derive_state: Final = compile_state_rules(STATE_RULES)


class Transition(NamedTuple):
    """``cause`` takes a process from any state of ``from_`` to one of ``to``."""

    from_: tuple[ProcessState, ...]
    cause: str
    to: tuple[ProcessState, ...]


_S = ProcessState
_BUSY = (_S.RUNNING, *_WAITS, _S.DWELL, _S.HOLD, _S.STEP)  # a program loaded, no alarm
# k is the process, n the one its code names.  Rows whose `to` is the state it was in (an
# SND delivered at once) say what happens without a change; the engine checks every change
# it makes against this table (Engine._update_state).
TRANSITIONS: Final = (
    Transition((_S.IDLE,), "`Start` input; cycle start with `nc.main` (P1); `(EXE,k,P)` from "
               "another process; the first EXE waiting for k when k becomes free",
               (_S.RUNNING,)),
    Transition((_S.IDLE,), "a program starts while a feed hold is on", (_S.HOLD,)),
    Transition((_S.IDLE,), "a cycle start whose main program cannot be loaded "
               "(AL120, AL121)", (_S.ALARM,)),
    Transition((_S.RUNNING,), "`(WAI,n)`: no SND from n pending and no latched token; "
               "ISG `#WAIT` for a signal not yet stored", (_S.WAIT_PROC,)),
    Transition((_S.RUNNING,), "`(WAI,n)`: n waits in `(SND,k)`, or a token n→k is latched "
               "(delivered; n resumes)", (_S.RUNNING,)),
    Transition((_S.RUNNING,), "`(WAI,var op value)` that does not hold now; ISG `#FLUSH` or "
               "a synchronous `V.E.` read with blocks still buffered (wait kind FLUSH); an "
               "auxiliary function with a handshake (`[nc.aux]`) output, the PLC's "
               "acknowledge to come (wait kind AUX)", (_S.WAIT_COND,)),
    Transition((_S.RUNNING,), "`(SND,n)`, rendezvous, n not in `(WAI,k)`", (_S.WAIT_SND,)),
    Transition((_S.RUNNING,), "`(SND,n)`: n external, n in `(WAI,k)`, or `nc.snd = "
               "\"latched\"` (a latch records a `hazard`)", (_S.RUNNING,)),
    Transition((_S.RUNNING,), "`(EXE,n,P)`, n busy", (_S.WAIT_EXE,)),
    Transition((_S.RUNNING,), "the interpolator starts a dwell", (_S.DWELL,)),
    Transition((_S.DWELL,), "the dwell time has passed", (_S.RUNNING,)),
    Transition((_S.WAIT_PROC,), "n executes `(SND,k)`; an external SND from n arrives; (ISG) "
               "every signal the wait needs has arrived", (_S.RUNNING,)),
    Transition((_S.WAIT_COND,), "a write makes the condition true (inside that write); "
               "(FLUSH) the interpolator has drained the buffer; (AUX) the PLC set the "
               "acknowledge, the NC dropped the strobe, the PLC dropped the acknowledge",
               (_S.RUNNING,)),
    Transition((_S.WAIT_SND,), "n executes `(WAI,k)`", (_S.RUNNING,)),
    Transition((_S.WAIT_EXE,), "n becomes free and k is first in line (P starts in n)",
               (_S.RUNNING,)),
    Transition((*_WAITS, _S.DWELL, _S.RUNNING), "one stage's wait or dwell ends or begins "
               "while the other stage waits: the state of the one the machine feels "
               "(STATE_RULES)", (*_WAITS, _S.DWELL, _S.RUNNING)),
    Transition((_S.RUNNING, _S.DWELL, *_WAITS), "single block (or a step): the block's last "
               "op is done and its motion has run", (_S.STEP,)),
    Transition((_S.STEP,), "cycle start or step: the next block", (_S.RUNNING,)),
    Transition((_S.RUNNING, _S.DWELL, *_WAITS, _S.STEP), "feed hold (command 2)", (_S.HOLD,)),
    Transition((_S.HOLD,), "cycle start (command 1): the state it would have without the "
               "hold", (_S.RUNNING, _S.DWELL, *_WAITS, _S.STEP)),
    Transition(_BUSY, "REL, M30, M02 or end of file, once its motion queue has drained",
               (_S.IDLE,)),
    Transition(_BUSY, "a runtime error in a block (its code); `(SND,n)` to an idle process "
               "or one in ALARM, or n ends while k waits in `(SND,n)` (AL111); `(EXE,n,P)` "
               "with n = k or external, or P not loadable (AL112, AL113, AL120, AL121); a "
               "wait that closes a cycle of waiting processes (AL140, every member); an "
               "orphan wait (AL141); `nc.wait_timeout_s` (AL143); `nc.runaway_blocks` "
               "(AL144); no acknowledge within `nc.aux.timeout_s` (AL145)", (_S.ALARM,)),
    Transition((*_BUSY, _S.ALARM), "reset (command 3): queues, waits and tokens discarded",
               (_S.IDLE,)),
)

# Every change of state the table allows: (from, to), from != to.
ALLOWED: Final = frozenset((a, b) for t in TRANSITIONS for a in t.from_ for b in t.to if a != b)


def state_table_markdown() -> str:
    """The two tables as ARCHITECTURE.md prints them."""
    def names(states: tuple[ProcessState, ...]) -> str:
        if set(states) == set(_BUSY):
            return "any with a program (not ALARM)"
        if set(states) == {*_BUSY, _S.ALARM}:
            return "any with a program"
        if set(states) == set(_WAITS):
            return "WAIT_* (by kind)"
        return ", ".join(s.name for s in states)

    lines = ["| order | state | when |", "|---|---|---|"]
    lines += [f"| {i} | {names(r.states)} | {r.when} |" for i, r in enumerate(STATE_RULES, 1)]
    lines += ["", "| state | cause | next state |", "|---|---|---|"]
    lines += [f"| {names(t.from_)} | {t.cause} | {names(t.to)} |" for t in TRANSITIONS]
    return "\n".join(lines) + "\n"

