"""The syntax tree of a Structured Text file: program organisation units (POUs), their
declarations, statements and expressions.  Frozen dataclasses; names are kept as written
(IEC names are case-insensitive: compare ``key``s, the upper-case forms)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # (diagnostics imports Span from here)
    from ncgate.plc.st.diagnostics import StDiagnostic


@dataclass(frozen=True, slots=True)
class Span:
    """Where a node starts: file, line and column, 1-based."""

    file: str
    line: int
    column: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"


# ---- types -----------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class NamedType:
    """A type by its name; ``size``: STRING[20] / STRING(20)'s length."""

    name: str
    span: Span
    size: Expr | None = None


@dataclass(frozen=True, slots=True)
class SubrangeType:
    """``INT(0..100)``: the base type and its (constant) limits."""

    name: str
    lo: Expr
    hi: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class ArrayType:
    """``ARRAY[lo..hi, lo..hi] OF element``: bounds are constant expressions; None for a
    dimension of ``ARRAY[*]`` (a VAR_IN_OUT of any length, 6.5.3).  ``dots``: written
    ``ARRAY[..]``, logi.CAD's spelling of ``ARRAY[*]`` (plc.strict = false only)."""

    dims: tuple[tuple[Expr, Expr] | None, ...]
    element: TypeRef
    span: Span
    dots: bool = False


TypeRef = NamedType | SubrangeType | ArrayType


# ---- expressions -------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Literal:
    """A constant.  ``type`` is None for an untyped number (``5``, ``16#FF``, ``1.5``)."""

    value: bool | int | float | str
    type: str | None
    span: Span


@dataclass(frozen=True, slots=True)
class EnumLit:
    """``E_State#RUN``: an enumeration value named with its type."""

    type_name: str
    name: str
    span: Span


@dataclass(frozen=True, slots=True)
class Field:
    name: str
    span: Span


@dataclass(frozen=True, slots=True)
class Index:
    expr: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class Bit:
    """``w.3``: one bit of an integer (6.5.1.2, Table 12); ``codesys``: written w.%X3."""

    bit: int
    span: Span
    codesys: bool = False


@dataclass(frozen=True, slots=True)
class Var:
    """A name with member and index selectors: ``x``, ``t1.Q``, ``arr[i]``, ``NC.P[2].STATE``."""

    name: str
    selectors: tuple[Field | Index | Bit, ...]
    span: Span


@dataclass(frozen=True, slots=True)
class Binary:
    op: str  # upper case: "+", "MOD", "AND", "<=", …  ("&" is read as "AND")
    left: Expr
    right: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class Unary:
    op: str  # "-", "+", "NOT"
    operand: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class Arg:
    """One argument: positional (``name`` None), input ``name := expr``, output ``name => var``."""

    name: str | None
    expr: Expr | None
    output: Var | None
    span: Span


@dataclass(frozen=True, slots=True)
class Call:
    name: str
    args: tuple[Arg, ...]
    span: Span


Expr = Literal | EnumLit | Var | Binary | Unary | Call


# ---- declarations --------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class ArrayInit:
    items: tuple[tuple[int, Initial | None], ...]  # (repeat count, value; None: default)
    span: Span


@dataclass(frozen=True, slots=True)
class StructInit:
    """``(x := 1, y := [1, 2])``: a structure's initial value, member by member."""

    items: tuple[tuple[str, Span, Initial], ...]
    span: Span


Initial = Expr | ArrayInit | StructInit


@dataclass(frozen=True, slots=True)
class VarDecl:
    name: str
    type: TypeRef
    initial: Initial | None
    section: str  # VAR, VAR_INPUT, VAR_OUTPUT, VAR_IN_OUT, VAR_TEMP, VAR_EXTERNAL, VAR_GLOBAL
    qualifier: str | None  # RETAIN, CONSTANT
    span: Span
    located: Span | None = None  # where ``AT %IX0.0`` starts (outside the subset: ST031)


@dataclass(frozen=True, slots=True)
class TypeDecl:
    """One data type of a TYPE … END_TYPE (6.4.4): ``kind`` STRUCT (``fields``), ENUM
    (``items``: name, value or None, span; ``initial``: the default's name) or ALIAS
    (``base``, ``initial``: a subrange, an array or another name, with a default)."""

    name: str
    kind: str
    fields: tuple[VarDecl, ...]
    items: tuple[tuple[str, Expr | None, Span], ...]
    base: TypeRef | None
    initial: Initial | str | None
    span: Span

    @property
    def key(self) -> str:
        return self.name.upper()


# ---- statements ----------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Assign:
    target: Var
    expr: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class CallStmt:
    target: Var
    args: tuple[Arg, ...]
    span: Span


@dataclass(frozen=True, slots=True)
class If:
    branches: tuple[tuple[Expr, tuple[Stmt, ...]], ...]
    otherwise: tuple[Stmt, ...] | None
    span: Span


@dataclass(frozen=True, slots=True)
class CaseLabel:
    """A value, a named constant or an enumeration value, or a range lo..hi of them."""

    lo: Literal | Var | EnumLit
    hi: Literal | Var | EnumLit | None
    span: Span


@dataclass(frozen=True, slots=True)
class Case:
    selector: Expr
    arms: tuple[tuple[tuple[CaseLabel, ...], tuple[Stmt, ...]], ...]
    otherwise: tuple[Stmt, ...] | None
    span: Span


@dataclass(frozen=True, slots=True)
class For:
    var: str
    var_span: Span
    start: Expr
    end: Expr
    step: Expr | None
    body: tuple[Stmt, ...]
    span: Span


@dataclass(frozen=True, slots=True)
class While:
    cond: Expr
    body: tuple[Stmt, ...]
    span: Span


@dataclass(frozen=True, slots=True)
class Repeat:
    body: tuple[Stmt, ...]
    cond: Expr
    span: Span


@dataclass(frozen=True, slots=True)
class Exit:
    span: Span


@dataclass(frozen=True, slots=True)
class Continue:
    span: Span


@dataclass(frozen=True, slots=True)
class Return:
    span: Span


Stmt = Assign | CallStmt | If | Case | For | While | Repeat | Exit | Continue | Return


@dataclass(frozen=True, slots=True)
class Pou:
    """A PROGRAM, FUNCTION_BLOCK or FUNCTION."""

    kind: str
    name: str
    result: TypeRef | None  # a FUNCTION's type (None: a FUNCTION without a result)
    decls: tuple[VarDecl, ...]
    body: tuple[Stmt, ...]
    span: Span

    @property
    def key(self) -> str:
        return self.name.upper()


@dataclass(frozen=True, slots=True)
class SourceFile:
    path: str
    text: str
    pous: tuple[Pou, ...]
    types: tuple[TypeDecl, ...] = ()
    globals: tuple[VarDecl, ...] = ()
    warnings: tuple[StDiagnostic, ...] = ()  # the parser's (SW004: an unknown pragma)

    def line(self, number: int) -> str:
        lines = self.text.splitlines()
        return lines[number - 1] if 0 < number <= len(lines) else ""
