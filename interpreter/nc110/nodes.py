"""The typed syntax tree of a part program (spec 1.2-1.5).

Every node is a frozen value object carrying its :class:`Span` (file, line, column, 1-based).
The parser builds these; the checker and the process runtime read them.  Nothing here knows
about execution.  Must not import ``plc`` or ``gateway``.
"""

from __future__ import annotations

import enum
import operator
from collections.abc import Callable
from dataclasses import MISSING, dataclass, fields
from typing import Any, Final, TypeVar, dataclass_transform

from ncgate.interpreter.diagnostics import Span as Span  # shared by every dialect

_T = TypeVar("_T")


@dataclass_transform(frozen_default=True)
def value_object(cls: type[_T]) -> type[_T]:
    """``@dataclass(frozen=True, slots=True)`` with a faster ``__init__``.

    The parser builds several nodes per line, and on CPython 3.11 a frozen dataclass's own
    ``__init__`` costs about twice a plain one (it looks up ``object.__setattr__`` for every
    field).  This one stores through the slot descriptors directly; instances stay frozen
    (assignment still raises ``FrozenInstanceError``) and compare and hash as dataclasses.
    """
    dc: Any = dataclass(frozen=True, slots=True)(cls)
    params, body, namespace = [], [], {}
    for i, f in enumerate(fields(dc)):
        if f.default is not MISSING:
            namespace[f"_d{i}"] = f.default
            params.append(f"{f.name}=_d{i}")
        else:
            params.append(f.name)
        namespace[f"_s{i}"] = dc.__dict__[f.name].__set__
        body.append(f"    _s{i}(self, {f.name})")
    source = f"def __init__(self, {', '.join(params)}):\n" + "\n".join(body) + "\n"
    exec(source, namespace)
    init = namespace["__init__"]
    init.__qualname__ = f"{dc.__qualname__}.__init__"
    dc.__init__ = init
    return dc  # type: ignore[no-any-return]


class VarKind(enum.Enum):
    E = "E"  # E parameter: real, per process
    SYVAR = "SYVAR"  # 16-bit signed, shared
    SA = "SA"  # the PLC's SA packet (bits)
    SK = "SK"  # the PLC's K packet (bytes)


class View(enum.Enum):
    """How a variable's storage is read (spec 1.3)."""

    REAL = "real"  # E parameters
    BIT = "bit"  # SA<n>
    BYTE = "BY"  # SA<n>.BY, SK<n>
    INT16 = "IN"  # SYVAR<n>, SA<n>.IN, SK<n>.IN (little-endian over two bytes)


# The relations, defined once: a WAI condition and a branch name them differently, by the same
# member names (EQ, NE, ...), and the image is handed a ready predicate (plc knows no operators).
RELATIONS: Final[dict[str, Callable[[float, float], bool]]] = {
    "EQ": operator.eq, "NE": operator.ne, "GT": operator.gt, "GE": operator.ge,
    "LT": operator.lt, "LE": operator.le,
}


class CompareOp(enum.Enum):
    """The comparison of ``(WAI,var op value)``: ``=``, ``#`` (not equal), ``>``, ``<``."""

    EQ = "="
    NE = "#"
    GT = ">"
    LT = "<"

    def holds(self, left: float, right: float) -> bool:
        return RELATIONS[self.name](left, right)

    def against(self, value: float) -> Callable[[float], bool]:
        """The predicate ``x op value`` (what the image evaluates on each write)."""
        relation = RELATIONS[self.name]
        return lambda x: relation(x, value)


class BranchOp(enum.Enum):
    """The conditional jumps ``(BEQ,a,b,L)`` ... ``(BLE,a,b,L)``."""

    EQ = "BEQ"
    NE = "BNE"
    GT = "BGT"
    GE = "BGE"
    LT = "BLT"
    LE = "BLE"

    def holds(self, left: float, right: float) -> bool:
        return RELATIONS[self.name](left, right)


# ---- expressions ----------------------------------------------------------------------


@value_object
class Num:
    value: float
    span: Span


@value_object
class VarRef:
    """A variable: ``E8``, ``SYVAR2``, ``SA10``, ``SA10.BY``, ``SK2.IN`` …"""

    kind: VarKind
    index: int
    view: View
    span: Span
    implicit_index: bool = False  # ``SYVAR`` written without a number (reads SYVAR0)

    @property
    def name(self) -> str:
        if self.kind is VarKind.E:
            return f"E{self.index}"
        if self.kind is VarKind.SYVAR:
            return f"SYVAR{self.index}"
        if self.kind is VarKind.SA and self.view is View.BIT:
            return f"SA{self.index}"
        if self.kind is VarKind.SK and self.view is View.BYTE:
            return f"SK{self.index}"
        return f"{self.kind.value}{self.index}.{self.view.value}"


@value_object
class Unary:
    op: str  # "-" or "+"
    operand: Expr
    span: Span


@value_object
class Binary:
    op: str  # + - * /
    left: Expr
    right: Expr
    span: Span


@value_object
class Call:
    func: str  # SIN COS TAN ATN SQR ABS INT (upper case)
    arg: Expr
    span: Span


Expr = Num | VarRef | Unary | Binary | Call


# ---- items of a block -----------------------------------------------------------------


@value_object
class Word:
    """An address word: ``G1``, ``X-3.5``, ``XE1``, ``T1.1``."""

    letter: str  # upper case
    value: float | VarRef
    text: str  # the value as written ("1.1" for T1.1)
    span: Span


@value_object
class Assign:
    target: VarRef
    expr: Expr
    span: Span


@value_object
class Exe:
    process: Expr
    program: str
    device: str | None
    span: Span


@value_object
class Rel:
    span: Span


@value_object
class WaitProc:
    process: Expr
    span: Span


@value_object
class WaitCond:
    var: VarRef
    op: CompareOp
    value: Expr
    span: Span

    @property
    def text(self) -> str:
        value = self.value
        shown = _show_number(value.value) if isinstance(value, Num) else _expr_text(value)
        return f"{self.var.name}{self.op.value}{shown}"


@value_object
class Snd:
    process: Expr
    span: Span


@value_object
class Jump:
    label: str
    span: Span


@value_object
class Branch:
    op: BranchOp
    left: Expr
    right: Expr
    label: str
    span: Span


@value_object
class Repeat:
    count: Expr
    span: Span


@value_object
class EndRepeat:
    span: Span


@value_object
class Dwell:
    seconds: Expr
    span: Span


@value_object
class Display:
    text: str
    args: tuple[Expr, ...]
    span: Span


@value_object
class InertCode:
    """An NC-110 code the simulator does not model (UAO, MIR, …): kept, never executed."""

    code: str
    args: tuple[str, ...]
    span: Span


Item = (
    Word | Assign | Exe | Rel | WaitProc | WaitCond | Snd | Jump | Branch | Repeat | EndRepeat
    | Dwell | Display | InertCode
)
SyncCode = Exe | Rel | WaitProc | WaitCond | Snd


@value_object
class Block:
    """One line of a program."""

    span: Span  # column 1 of the line
    deleted: bool  # "/" block delete
    label: str | None
    number: int | None  # the N number
    synced: bool  # "#": acts in motion order (spec 2.4)
    items: tuple[Item, ...]
    comment: str | None

    @property
    def is_empty(self) -> bool:
        return not self.items


def _show_number(value: float) -> str:
    return str(int(value)) if value == int(value) else repr(value)


def _expr_text(expr: Expr) -> str:
    if isinstance(expr, Num):
        return _show_number(expr.value)
    if isinstance(expr, VarRef):
        return expr.name
    if isinstance(expr, Unary):
        return f"{expr.op}{_expr_text(expr.operand)}"
    if isinstance(expr, Binary):
        return f"({_expr_text(expr.left)}{expr.op}{_expr_text(expr.right)})"
    return f"{expr.func}({_expr_text(expr.arg)})"


def expr_text(expr: Expr) -> str:
    """A compact source-like rendering of an expression (for messages and the trace)."""
    return _expr_text(expr)
