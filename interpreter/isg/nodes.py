"""The typed syntax tree of an ISG (TwinCAT CNC) program block (spec 5.2).

Frozen value objects with a :class:`Span` each; the parser builds them, the checker and the
front end read them.  Nothing here acts.  Must not import ``plc`` or ``gateway``.
"""

from __future__ import annotations

from dataclasses import dataclass

from ncgate.interpreter.diagnostics import Span

# ---- expressions ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Num:
    value: float
    span: Span


@dataclass(frozen=True, slots=True)
class Param:
    """``P<n>``: a real parameter of the channel."""

    index: int
    span: Span


@dataclass(frozen=True, slots=True)
class SelfVar:
    """``V.P.<NAME>``: a self-defined variable of the channel (upper case)."""

    name: str
    span: Span


@dataclass(frozen=True, slots=True)
class ExternalVar:
    """``V.E.<NAME>``: an external variable, mapped to the image by ``[nc.ve]``."""

    name: str
    span: Span


@dataclass(frozen=True, slots=True)
class Unary:
    op: str  # "-" or "NOT"
    operand: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class Binary:
    op: str  # + - * / == != < <= > >= AND OR
    left: Expr
    right: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class Call:
    function: str  # ABS SQRT SIN COS
    argument: Expr
    span: Span


Expr = Num | Param | SelfVar | ExternalVar | Unary | Binary | Call
Target = Param | SelfVar | ExternalVar

# ---- items of a block -----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Assign:
    target: Target
    expr: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class Word:
    """An address letter and its value: ``G01``, ``X250``, ``XP1``, ``X[P1*2]``."""

    letter: str
    value: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class Signal:
    """``#SIGNAL [SYN] [ID<n> [COUNT<c>] {P[i]=<expr>} {CH<k>}]`` (spec 5.3)."""

    syn: bool
    id: Expr
    count: Expr | None
    params: tuple[tuple[int, Expr], ...]
    channels: tuple[Expr, ...]  # none: a broadcast
    span: Span


@dataclass(frozen=True, slots=True)
class Remove:
    """``#SIGNAL REMOVE [ID<n> | IDMIN<a> [IDMAX<b>] {CH<k>}]``: ids in ``low..high``."""

    low: Expr | None  # None: every number
    high: Expr | None  # None: no upper bound (IDMIN alone); ID<n> gives low = high
    channels: tuple[Expr, ...]
    span: Span


@dataclass(frozen=True, slots=True)
class WaitSignal:
    """``#WAIT [SYN] [ID<n> {P[i]=<var>} {CH<k>} [AHEAD]]`` (spec 5.4)."""

    syn: bool
    id: Expr
    params: tuple[tuple[int, Target], ...]
    channels: tuple[Expr, ...]  # none: a broadcast wait
    ahead: bool
    span: Span


@dataclass(frozen=True, slots=True)
class Flush:
    """``#FLUSH`` or ``#FLUSH WAIT``: the decoder waits for its interpolator."""

    span: Span


@dataclass(frozen=True, slots=True)
class VarBlock:
    """``#VAR`` (``end=False``) or ``#ENDVAR``: declarations of V.P. variables between."""

    end: bool
    span: Span


@dataclass(frozen=True, slots=True)
class Declare:
    """A line inside ``#VAR … #ENDVAR``: ``V.P.NAME [= value]``."""

    name: str
    value: Expr | None
    span: Span


@dataclass(frozen=True, slots=True)
class Control:
    """``$IF c``, ``$ELSE``, ``$ENDIF``, ``$WHILE c``, ``$ENDWHILE``."""

    word: str  # IF ELSE ENDIF WHILE ENDWHILE
    condition: Expr | None
    span: Span


@dataclass(frozen=True, slots=True)
class Section:
    """``%<name>``: a program of a sectioned file starts here."""

    name: str
    span: Span


Command = Signal | Remove | WaitSignal | Flush | VarBlock | Control | Section | Declare
Item = Assign | Word | Command


@dataclass(frozen=True, slots=True)
class Block:
    number: int | None  # N
    items: tuple[Item, ...]
    span: Span

    @property
    def command(self) -> Command | None:
        for item in self.items:
            if not isinstance(item, Assign | Word):
                return item
        return None
