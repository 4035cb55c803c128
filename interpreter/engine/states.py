"""States and records: what a process is doing and why (spec 2.1, 2.2.6), as enums and
dataclasses.  Everything else in the engine speaks these types; nothing here acts."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

from ncgate.interpreter.diagnostics import fmt_number

if TYPE_CHECKING:
    from ncgate.interpreter.engine.ports import Cancellable
    from ncgate.interpreter.engine.timers import Timer

Where = tuple[str, int, int | None]  # program file, line, N


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
    FLUSH = 5  # the decoder waits for its interpolator (#FLUSH, a synchronous V.E. read)


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


STATE_OF_WAIT: Final = {WaitKind.PROC: ProcessState.WAIT_PROC,
                        WaitKind.COND: ProcessState.WAIT_COND,
                        WaitKind.SND: ProcessState.WAIT_SND,
                        WaitKind.EXE: ProcessState.WAIT_EXE,
                        WaitKind.FLUSH: ProcessState.WAIT_COND}
RUNNING_STATES: Final = frozenset({ProcessState.RUNNING, ProcessState.DWELL, ProcessState.HOLD})
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

    def describe(self, proc: int) -> str:
        file, line, n = self.where
        number = f" N{n}" if n is not None else ""
        return f"P{proc} {file}:{line}{number} {self.code}"

    def reason(self) -> str:
        if self.text is not None:
            return self.text if isinstance(self.text, str) else self.text()
        if self.kind is WaitKind.COND:
            value, writer = self.probe() if self.probe is not None else (self.value, self.writer)
            by = f", last written by {writer}" if writer else ""
            return f"waits for {self.cond} (now {fmt_number(value)}{by})"
        return {WaitKind.PROC: f"waits for an SND from P{self.target}",
                WaitKind.SND: f"waits for P{self.target} to take its SND",
                WaitKind.EXE: f"waits for P{self.target} to be free",
                WaitKind.FLUSH: "waits for its interpolator to run every block before it",
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
