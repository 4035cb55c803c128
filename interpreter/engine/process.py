"""One process (channel): its program, decoder position, motion queue and interpolator."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ncgate.interpreter.cache import BlockCache
from ncgate.interpreter.engine.actions import Action, ItemKind, Step
from ncgate.interpreter.engine.states import (
    DecoderHold,
    ProcessState,
    Stats,
    WaitRecord,
    Where,
)
from ncgate.interpreter.engine.timers import Timer
from ncgate.interpreter.motion import Modal, Move

if TYPE_CHECKING:
    from ncgate.interpreter.engine.ports import ProgramText

Op = Callable[["Process"], Step]  # one step of a compiled block


@dataclass(slots=True)
class QueueItem:
    kind: ItemKind
    duration: float
    where: Where
    move: Move | None = None
    # SYNC: the evaluated codes of a # block -- an Action, or a dialect's own registered one
    actions: Sequence[Action | object] | None = None


@dataclass(slots=True)
class CompiledBlock:
    ops: tuple[Op, ...]
    where: Where
    counted: bool


@dataclass(slots=True)
class LoadedProgram:
    program: ProgramText
    file: str  # display name in messages and the trace
    blocks: list[CompiledBlock | None] | BlockCache[CompiledBlock]  # by line (cache.py)
    length: int  # its lines
    exe_targets: frozenset[int]  # the processes it may start (orphan-wait detection)
    dynamic_exe: bool  # it starts processes named by E parameters: any of them


class Process:
    """One process (channel): decoder + motion queue + interpolator."""

    def __init__(self, number: int, external: bool, e_params: int) -> None:
        self.number = number
        self.external = external
        self.e_params = e_params
        self.E: list[float] = [0.0] * e_params
        # A dialect's named variables of the channel (ISG's V.P.): kept like E, cleared by a
        # reset.
        self.vars: dict[str, float] = {}
        self.loaded: LoadedProgram | None = None
        self.modal = Modal()
        self.stats = Stats()
        self.state = ProcessState.IDLE
        self.state_since = 0.0
        self.alarm: tuple[int, str, Where | None] | None = None
        self.held = False
        # Who gave the feed hold in force (a command's source, "breakpoint N40", the feed
        # hold input) and since when: what a stall report says of a held process.
        self.held_by: str | None = None
        self.held_since = 0.0
        self.single_block = False  # stop after each block (a mode: kept over programs)
        # The overrides in percent (the operator's switches: kept over programs and resets).
        self.feed_override = 100
        self.rapid_override = 100
        # Its timed item stands at a 0 % override (RUNNING, not held): waiting time, as a
        # feed hold's is (Engine._stand keeps it, accounting the time at each change).
        self.standing = False
        self.actual: list[float] = list(self.modal.position)  # the interpolator's position
        self.queued = False  # in the engine's run queue
        self.clear()

    def clear(self) -> None:
        """Forget the running program (not E parameters, position or statistics)."""
        self.pc = 0
        self.op_i = 0
        self.block: CompiledBlock | None = None
        self.repeats: list[list[int]] = []  # [RPT's line index, repetitions left, ERP's]
        self.dec_block: DecoderHold | None = None  # None: the decoder may run
        self.dec_wait: WaitRecord | None = None
        self.end_how: str | None = None
        self.end_where: Where | None = None
        self.pending: list[QueueItem] | None = None
        self.queue: deque[QueueItem] = deque()
        self.int_item: QueueItem | None = None
        self.int_timer: Timer | None = None
        self.int_started = 0.0
        self.int_remaining: float | None = None  # a timed item paused by a feed hold
        # The item whose time runs (a move, dwell or tool change; a move of a # block), the
        # nominal seconds of it done when its timer was armed, and the rate since (its
        # override: 1.0 at 100 %).
        self.int_move: QueueItem | None = None
        self.int_done = 0.0
        self.int_rate = 1.0
        self.int_wait: WaitRecord | None = None
        # The interpolator would run but waits for the decoder to fill its buffer (ISG).
        self.starved = False
        self.sync_i = 0
        self.dec_timer: Timer | None = None  # nc.block_time_ms: the block's processing time
        self.step_once = False  # a step: stop after the next block, single block or not
        # Why the next stop after a block comes (with step_once): "step", "M00", "M01",
        # "break"; and why the process stands stopped after a block now (DecoderHold.STEP):
        # that, or "single_block".  Only a single block's stop ends when the mode goes off.
        self.stop_why: str | None = None
        self.stopped: str | None = None
        self.stop_told = False  # its stop event is in the trace
        # The last block the decoder finished: where the process stands between blocks (the
        # block N and line a single-block stop, a breakpoint or M00 show).
        self.last_where: Where | None = None
        self.break_passed = -1  # the line index a block breakpoint stopped before (passed once)
        # Runaway detection: blocks decoded since the engine last stood still (its epoch).
        self.spin = 0
        self.spin_epoch = -1
        self.loop: tuple[Where, int] | None = None  # the last jump: its block, its target

    @property
    def motion_active(self) -> bool:
        """A timed queue item under way (or paused by a feed hold): spec 2.4's flag."""
        return self.int_timer is not None or self.int_remaining is not None

    @property
    def where(self) -> Where:
        if self.block is not None:
            return self.block.where
        if self.loaded is not None:
            if self.last_where is not None:  # between blocks: the block it stopped after
                return self.last_where
            # not a block finished yet: the line the decoder is at
            return (self.loaded.file, min(self.pc + 1, self.loaded.length), None)
        return ("", 0, None)

    def waits(self) -> tuple[WaitRecord, ...]:
        """The waits the process is in (its interpolator's first, the one the machine feels)."""
        return tuple(w for w in (self.int_wait, self.dec_wait) if w is not None)
