"""What a front end's compiled blocks hand the engine: the result of a decoder step, and the
typed actions of a code (a SYVAR write, a WAI, an SND, an EXE, a message, a move).

A block without ``#`` performs its actions as the decoder reaches them; a ``#`` block is
evaluated by the decoder into a list of these actions and queued as one motion item, and the
interpolator performs them in motion order (spec 2.4).  A dialect adds its own action types
and registers a handler for each with :meth:`Engine.register_action` -- the engine dispatches
on the type, so a new kind of code is a new module, not an edit of the engine.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass

from ncgate.interpreter.motion import Move


class Step(enum.IntEnum):
    """What a decoder op tells the decoder loop."""

    NEXT = 0  # done: the next op of the block
    WAIT_NEXT = 1  # the process waits; afterwards, the next op
    WAIT_RETRY = 2  # the process waits; afterwards, this op again (a full motion queue)
    JUMP = 3  # the op moved the program counter
    END = 4  # the program's decoder is done


class ItemKind(enum.IntEnum):
    """A motion-queue item."""

    MOVE = 0
    TOOL = 1
    DWELL = 2
    SYNC = 3  # a # block: its actions, in motion order
    AUX = 4


@dataclass(frozen=True, slots=True)
class WriteSyvar:
    index: int
    value: int


@dataclass(frozen=True, slots=True)
class WaitProcess:
    """``(WAI,n)``: until process n sends this one an SND."""

    process: int
    code: str


@dataclass(frozen=True, slots=True)
class WaitCondition:
    """``(WAI,var op value)``: until ``test`` holds for the image variable."""

    area: str
    index: int
    view: str
    test: Callable[[int], bool]
    text: str  # the condition as shown: "SA10=1"


@dataclass(frozen=True, slots=True)
class Send:
    process: int
    code: str


@dataclass(frozen=True, slots=True)
class Execute:
    process: int
    program: str
    device: str | None
    code: str


@dataclass(frozen=True, slots=True)
class ShowText:
    """A message for the trace and the console (``(DIS,…)``)."""

    text: str


@dataclass(frozen=True, slots=True)
class Motion:
    """A move inside a # block (a dwell or tool change is a move of no length)."""

    move: Move


Action = WriteSyvar | WaitProcess | WaitCondition | Send | Execute | ShowText | Motion
