"""Structured Text -> checked, compiled Python: the soft PLC's logic.

Every POU of every file is checked first (names, types, constant indices, writes to inputs;
all diagnostics of a load are reported together), then compiled to Python source, once, with
``compile()``: a PROGRAM or FUNCTION_BLOCK becomes a class whose ``__call__`` runs its body, a
FUNCTION a Python function.  A scan then costs what the statements cost -- no tree is walked
(``bench/plc.py`` measures it against :mod:`ncgate.plc.st.walk`).

Semantics where IEC 61131-3 leaves a choice (docs/plc.md):
- integer intermediate results are exact, and a value wraps to its type when it is stored
  (in a variable, an input, the image), as CODESYS and TwinCAT compute in a wider register;
- integer ``/`` truncates toward zero, ``MOD`` takes the dividend's sign (as C);
- a division by zero, an index outside its array or the image, and a loop that runs past
  the per-scan iteration guard raise :class:`PlcFault` at the statement's file:line:col.

Generated names: ``self.v_X`` (a variable X of a program or FB), ``v_X`` (of a function),
``_G.v_X`` (a VAR_GLOBAL), ``S_T`` (the class of a structure type T, members ``v_M``),
``_SA``/``_SK``/``_SY`` (the scan's copy of the image), ``_NC*`` (the NC's status and
outputs), ``_NOW`` (the scan's time in ms), ``_LEFT`` (iterations left this scan).
Enumeration values are their integers; STRINGs Python str; a VAR_IN_OUT is copied in before
a call and back after it.

This module checks and generates (``Compiler``, ``Scope``, ``compile_logic``); what it builds
on lives beside it: ``signatures`` (the declarations' model), ``intrinsics`` (the image's and
the NC's names and slots), ``runtime`` (what the generated code calls) and ``logic`` (the
compiled :class:`~ncgate.plc.st.logic.Logic`).
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, replace
from typing import Any

from ncgate.plc.st import nodes as n
from ncgate.plc.st import stdlib
from ncgate.plc.st.diagnostics import LogicError, StCode, StDiagnostic, did_you_mean
from ncgate.plc.st.intrinsics import (
    IMAGE_NAMES,
    NC_LAST_SND,
    NC_OUTPUTS,
    NC_PROCESS,
    NC_PROCESS_OUTPUTS,
    NC_VALUE_OUTPUTS,
)
from ncgate.plc.st.logic import COMPILED_KEPT, KEPT_SOURCE_MAX, Logic
from ncgate.plc.st.runtime import TOD_MS, _code_char, _f32, _f64, _idiv, _mod
from ncgate.plc.st.signatures import (
    EnumInfo,
    PouInfo,
    StructInfo,
    VarInfo,
    _leaf,
    _leaf_count,
    _reshape,
)
from ncgate.plc.st.types import (
    ANY_INT,
    ANY_REAL,
    BITS,
    CHARS,
    DATE_NAMES,
    DATES,
    DURATIONS,
    ELEMENTARY,
    INTS,
    REALS,
    SIGNED,
    STRING_DEFAULT,
    UNSIGNED,
    AnyLength,
    ArrayOf,
    EnumOf,
    FbOf,
    Ranged,
    StringOf,
    StructOf,
    Type,
    common,
    default_value,
    is_int,
    is_num,
    is_real,
    limits,
    widens,
)

RESERVED = (*IMAGE_NAMES, "NC")
# The standard function blocks: member -> (direction, type).
STD_FBS: dict[str, dict[str, tuple[str, str]]] = {
    **{t: {"IN": ("in", "BOOL"), "PT": ("in", "TIME"), "Q": ("out", "BOOL"),
           "ET": ("out", "TIME")} for t in ("TON", "TOF", "TP")},
    **{t: {"CLK": ("in", "BOOL"), "Q": ("out", "BOOL")} for t in ("R_TRIG", "F_TRIG")},
    "CTU": {"CU": ("in", "BOOL"), "R": ("in", "BOOL"), "PV": ("in", "INT"),
            "Q": ("out", "BOOL"), "CV": ("out", "INT")},
    "CTD": {"CD": ("in", "BOOL"), "LD": ("in", "BOOL"), "PV": ("in", "INT"),
            "Q": ("out", "BOOL"), "CV": ("out", "INT")},
    "CTUD": {"CU": ("in", "BOOL"), "CD": ("in", "BOOL"), "R": ("in", "BOOL"),
             "LD": ("in", "BOOL"), "PV": ("in", "INT"), "QU": ("out", "BOOL"),
             "QD": ("out", "BOOL"), "CV": ("out", "INT")},
    "SR": {"S1": ("in", "BOOL"), "R": ("in", "BOOL"), "Q1": ("out", "BOOL")},
    "RS": {"S": ("in", "BOOL"), "R1": ("in", "BOOL"), "Q1": ("out", "BOOL")},
}
MATH_FUNCTIONS = ("EXP", "LN", "LOG", "SIN", "COS", "TAN", "ASIN", "ACOS", "ATAN")
# The character string functions (6.6.2.5.11, Table 43).
STRING_FUNCTIONS = ("LEN", "LEFT", "RIGHT", "MID", "CONCAT", "INSERT", "DELETE", "REPLACE",
                    "FIND")
# MUL_TIME and DIV_TIME (Table 30), and their 2nd-edition names: TIME * or / a number.
TIME_FUNCTIONS = {"MUL_TIME": "*", "DIV_TIME": "/", "MULTIME": "*", "DIVTIME": "/"}
STD_FUNCTIONS = ("ABS", "MIN", "MAX", "LIMIT", "SEL", "MUX", "SHL", "SHR", "ROL", "ROR",
                 "SQRT", "EXPT", "TRUNC", "MOVE", "CONCAT_DATE_TOD", "LOWER_BOUND",
                 "UPPER_BOUND", *MATH_FUNCTIONS,
                 *STRING_FUNCTIONS, *TIME_FUNCTIONS)
# The formal names of the standard functions' inputs (IEC 61131-3, Tables 22 to 31), for a
# call that names them: SEL(G := g, IN0 := a, IN1 := b).  A name ending in "*" numbers the
# inputs from there on: MAX(IN1 := a, IN2 := b, IN3 := c), MUX(K := k, IN0 := a, IN1 := b).
FORMAL_INPUTS: dict[str, tuple[str, ...]] = {
    **{name: ("IN",) for name in ("ABS", "SQRT", "TRUNC", "MOVE", *MATH_FUNCTIONS)},
    "EXPT": ("IN1", "IN2"), "SHL": ("IN", "N"), "SHR": ("IN", "N"), "ROL": ("IN", "N"),
    "ROR": ("IN", "N"), "SEL": ("G", "IN0", "IN1"), "LIMIT": ("MN", "IN", "MX"),
    "MIN": ("IN1*",), "MAX": ("IN1*",), "MUX": ("K", "IN0*"),
    "CONCAT_DATE_TOD": ("IN1", "IN2"), **{name: ("IN1", "IN2") for name in TIME_FUNCTIONS},
}
# IEC 61131-3 types and standard functions outside the subset: ST031, not "unknown".
UNSUPPORTED_TYPES = ("LDATE", "LTOD", "LDT", "LDATE_AND_TIME", "LTIME_OF_DAY")
UNSUPPORTED_FUNCTIONS: tuple[str, ...] = ()
# logi.CAD's functions for an ARRAY[..]'s bounds, and IEC's (plc.strict = false reads them).
_LOGICAD_BOUNDS = {"_FIRSTINDEXOF": "LOWER_BOUND", "_LASTINDEXOF": "UPPER_BOUND"}
# Each type's pure-integer carrier: what its value wraps as where it is stored.
CARRIER = {"TIME": "DINT", "LTIME": "LINT", "DATE": "UDINT", "DT": "UDINT", "TOD": "UDINT"}

# Limits of the Python the logic compiles to (CPython 3.11): 100 levels of indentation, 20
# nested loops in one function, 200 nested parentheses, an `elif` chain of a few thousand
# branches (10,000 run the parser out of memory), an operator chain of ~3,000 terms (the
# compiler's recursion limit).  The generated code stays far inside them: a block nested
# deeper than HOIST_INDENT levels, or inside HOIST_LOOPS loops, of one Python function is
# moved into a helper function of its own; an IF or CASE chain is split every CHAIN_BRANCHES
# branches; an operator chain is cut every CHAIN_OPS operators into a temporary.  Below
# those sizes the code is what it always was (bench/plc.py: no cost).
HOIST_INDENT = 24
# A reload compiles in a thread, but Python's compile() holds the interpreter for the whole
# call (~0.35 us a character of generated code, CPython 3.11): one compile of 1.9 MB stopped
# the loop ~0.8 s.  So Logic compiles the module in pieces of whole top-level definitions of
# about PIECE_CHARS characters (ncgate.plc.st.logic), and a PROGRAM's or FB's body past
# PIECE_LINES lines of Python goes into helper functions of about that size (bench/plc.py's
# body is cut into 7: no change in its scan time).
PIECE_LINES = 250
HOIST_LOOPS = 8
CHAIN_BRANCHES = 64
CHAIN_OPS = 16
# What the language itself allows (ST031 beyond): statements nested this deep, and
# expressions nested this deep not counting a chain of operators (a + b + c ... is depth 1).
MAX_NESTING = 512
MAX_EXPR_DEPTH = 64
# Loop and return codes a helper function hands back to the Python function that called it.
EXIT_CODE, RETURN_CODE, CONTINUE_CODE = 1, 2, 3


@dataclass(frozen=True, slots=True)
class Context:
    """What the logic is checked against: the image's sizes and the NC's processes; the
    config's I/O names ([symbols]: name -> "SA10", "SA2.BY", "SK3", "SK4.IN", "SYVAR5"),
    globals of the logic bound to their image variable; ``strict``: IEC 61131-3 as written
    (False: CODESYS's leniencies load, each with a warning)."""

    sa_bits: int = 1024
    k_bytes: int = 512
    syvars: int = 256
    processes: int = 5
    external: frozenset[int] = frozenset()
    symbols: tuple[tuple[str, str], ...] = ()
    strict: bool = True


# An I/O name's image variable as the config writes it; its area in ST and its type.
_SYMBOL_VAR = re.compile(r"(SYVAR|SA|SK|K)(\d+)(?:\.(BY|IN))?$", re.IGNORECASE)


# The string functions of IEC 61131-3 (6.6.2.5.11, Table 43), positions 1-based.  A negative
# length, or a position before the first character, is an error of the standard's (the
# logic faults); a length or position past the end takes what is there (docs/plc.md).


_BIT_TYPE = {8: "BYTE", 16: "WORD", 32: "DWORD", 64: "LWORD"}
VOID = "VOID"  # the type of a call of a FUNCTION without a result: a statement only
_TIMED = (*DURATIONS, *DATES)
_ORDERED = (*_TIMED, *CHARS)  # besides numbers, strings and enumerations: MIN, MAX, LIMIT
# CODESYS and logi.CAD have no CHAR: a string's character is a BYTE there (a WSTRING's a WORD).
_AS_CODE = {"CHAR": "CODESYS and logi.CAD read a STRING's character as a BYTE",
            "WCHAR": "CODESYS reads a WSTRING's character as a WORD"}
# Integers a REAL holds exactly (24-bit mantissa): their conversion needs no rounding.
_EXACT_IN_REAL = ("SINT", "INT", "USINT", "UINT", "BYTE", "WORD")


# ---- expressions and places ---------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class E:
    """A compiled expression: its Python code, type, constant value (or None), and whether
    its value is already inside its type (False after integer arithmetic: wrap on store)."""

    code: str
    type: Type
    const: Any = None
    exact: bool = True


def nc_where(span: n.Span) -> str:
    """``FILE:LINE`` of a statement acting on the NC, as its commands are attributed."""
    return f"{span.file.replace(chr(92), '/').rsplit('/', 1)[-1]}:{span.line}"


@dataclass(frozen=True, slots=True)
class Place:
    """Something that can be read and perhaps written."""

    read: str
    type: Type
    store: Callable[[str], str] | None  # value code -> statement; None: read-only
    why_read_only: str = ""
    lower: str = ""  # given to an ARRAY[*] VAR_IN_OUT: the code of its lower bound


def _writing(c: Compiler, place: Place, keys: tuple[tuple[str, int], ...],
             span: n.Span) -> Place:
    """``place``, its writes noted as writes of ``keys`` at ``span`` (the first of each)."""
    store = place.store
    if store is None:
        return place

    def noted(value: str) -> str:
        for key in keys:
            c.image_writes.setdefault(c.pou_key, {}).setdefault(key, span)
        return store(value)

    return replace(place, store=noted)


def wrap_code(code: str, t: Type) -> str:
    if t == "TOD":
        return f"(({code}) % {TOD_MS})"
    if isinstance(t, str):
        t = CARRIER.get(t, t)
    if t in SIGNED:
        half = 1 << (stdlib.INTEGER_TYPES[str(t)][0] - 1)
        return f"((({code}) + {half}) & {2 * half - 1}) - {half}"
    if t in UNSIGNED or t in BITS:
        return f"(({code}) & {(1 << stdlib.INTEGER_TYPES[str(t)][0]) - 1})"
    return code


def const_code(value: Any, t: Type) -> str:
    if isinstance(t, StringOf) or t in CHARS:
        return repr(str(value))
    if t == "REAL":
        return repr(_f32(value))
    if t in REALS or t == ANY_REAL:
        return repr(float(value))
    if t == "BOOL":
        return "True" if value else "False"
    return repr(int(value))


def wrap_value(value: int, t: Type) -> int:
    if t == "TOD":
        return value % TOD_MS
    return stdlib.wrap(value, CARRIER.get(str(t), str(t)))


def copy_code(code: str, t: Type, depth: int = 0) -> str:
    """A copy of an aggregate value (an assignment copies, IEC 61131-3, 7.3.3.2.2)."""
    if isinstance(t, StructOf):
        return f"{code}._copy()"
    if isinstance(t, ArrayOf):
        if isinstance(t.element, StructOf | ArrayOf):
            e = f"_e{depth}"
            return f"[{copy_code(e, t.element, depth + 1)} for {e} in {code}]"
        return f"list({code})"
    return code


def is_aggregate(t: Type) -> bool:
    return isinstance(t, ArrayOf | StructOf)


def real_code(code: str, t: Type) -> str:
    """The code of an arithmetic result of type ``t``: rounded to single for REAL, checked
    for overflow for LREAL, as it is for an integer type (wrapped where stored).  The REAL
    rounding is _f32 inlined, two C calls and no Python frame: 88 ns a result where the
    call took 116 (timeit, CPython 3.11); its OverflowError is worded by the scan."""
    return (f"_F32U(_F32P({code}))[0]" if t == "REAL" else f"_f64({code})" if t == "LREAL"
            else code)


class Problems(Exception):
    """Stops checking one statement; the diagnostic is already recorded."""


# ---- the compiler ------------------------------------------------------------------------------

class _Emitter:
    def __init__(self, indent: int = 0) -> None:
        self.lines: list[str] = []
        self.spans: list[n.Span | None] = []
        self.indent = indent

    def emit(self, text: str, span: n.Span | None) -> None:
        self.lines.append("    " * self.indent + text)
        self.spans.append(span)


class Compiler:
    def __init__(self, files: Sequence[n.SourceFile], context: Context) -> None:
        self.files = list(files)
        self.ctx = context
        self.diagnostics: list[StDiagnostic] = []
        self.warnings: list[StDiagnostic] = [w for f in self.files for w in f.warnings]
        self.pous: dict[str, PouInfo] = {}
        self.type_decls: dict[str, tuple[n.TypeDecl, n.SourceFile]] = {}
        self.resolved: dict[str, Type] = {}
        self._resolving: set[str] = set()
        self.structs: dict[str, StructInfo] = {}
        self.enums: dict[str, EnumInfo] = {}
        self.enum_values: dict[str, list[str]] = {}  # value name -> the enumerations with it
        self.type_defaults: dict[str, Any] = {}  # a TYPE's declared initial value
        self.globals: dict[str, VarInfo] = {}
        self._prelude_call: n.Call | None = None  # a call that may write before its statement
        self._statement_call: n.Call | None = None  # a call that is a whole statement
        self.out = _Emitter()
        self._temp = 0
        self._depth = 0  # expression nesting, not counting operator chains
        self._frames = 0  # helper functions made so far (frame 0: a POU's own function)
        self.helpers: list[_Emitter] = []  # of PROGRAMs and FBs: module-level functions
        self._local_helpers: list[_Emitter] = []  # of the FUNCTION being compiled: closures
        self.reads_nc = False  # a scan takes the NC's status only for logic that reads it
        # A timer's ET is read (sim leaps over the scans whose only change is a running
        # timer's ET only when nothing does: plc/scan.py, a timed still scan)
        self.reads_et = False
        # What of the image the logic reads or writes: ("SA", byte), ("SK", byte), ("SYVAR",
        # n) at a constant index, the whole area at one it computes (a still scan's inputs)
        self.image_keys: set[tuple[str, int]] = set()
        self.image_areas: set[str] = set()
        # What of the image the logic writes at a constant place, and where it first does:
        # ("SA", bit), ("SK", byte), ("SYVAR", n) -> the write's span (SW006: another writer
        # of the cell writes it too, gateway/plc.py's shared_writes); a write at a place it
        # computes is not known here.  Each by the POU whose code does it (pou_key: the one
        # being compiled), so that what no PROGRAM run reaches is not counted (Logic.reached:
        # uses).  Likewise what it reads (ncgate map).
        self.image_writes: dict[str, dict[tuple[str, int], n.Span]] = {}
        self.image_reads: dict[str, set[tuple[str, int]]] = {}
        self.computed_reads: dict[str, set[str]] = {}  # the areas it reads, writes at a place
        self.computed_writes: dict[str, set[str]] = {}  # it computes (ncgate map)
        self.pou_key = ""
        self.uses: dict[str, set[str]] = {}  # a POU -> the FBs it has instances of, calls

    def note_reads(self, keys: Iterable[tuple[str, int]]) -> None:
        """The POU being compiled reads these places of the image (image_reads)."""
        self.image_reads.setdefault(self.pou_key, set()).update(keys)

    # -- reporting --------------------------------------------------------------------------

    def _source(self, span: n.Span) -> str:
        for f in self.files:
            if f.path == span.file:
                return f.line(span.line)
        return ""

    def error(self, code: StCode, message: str, span: n.Span) -> Problems:
        self.diagnostics.append(StDiagnostic(code, message, span, self._source(span)))
        return Problems()

    def lenient(self, code: StCode, warning: StCode, message: str, span: n.Span) -> None:
        """A construct strict IEC refuses (``code``) and CODESYS accepts: with plc.strict
        = false, a warning (``warning``) and the construct loads; else the error."""
        if self.ctx.strict:
            raise self.error(code, message + " (plc.strict = false accepts it, as CODESYS "
                             "does)", span)
        self.warnings.append(StDiagnostic(warning, message, span, self._source(span)))

    # -- pass 1: data types, globals, POUs and their declarations ------------------------------

    def collect(self) -> None:
        for f in self.files:
            for decl in f.types:
                if decl.key in self.type_decls or decl.key in ELEMENTARY or \
                        decl.key in STD_FBS:
                    first = self.type_decls.get(decl.key)
                    where = f" (first at {first[0].span})" if first else ""
                    self.error(StCode.DUPLICATE_NAME, f"the type {decl.name} is defined "
                               f"twice{where}", decl.span)
                    continue
                self.type_decls[decl.key] = (decl, f)
        for f in self.files:
            for pou in f.pous:
                if pou.key in self.pous:
                    other = self.pous[pou.key].pou.span
                    self.error(StCode.DUPLICATE_POU, f"{pou.name} is already defined at "
                               f"{other}", pou.span)
                    continue
                if pou.key in STD_FBS or ((pou.key in STD_FUNCTIONS or _conversion(pou.key))
                                          and pou.kind != "FUNCTION"):
                    self.error(StCode.DUPLICATE_POU, f"{pou.name} is a standard "
                               "function or function block", pou.span)
                    continue
                if pou.key in STD_FUNCTIONS or _conversion(pou.key):
                    try:  # a library's own INT_TO_STRING: CODESYS lets it replace the standard's
                        self.lenient(StCode.DUPLICATE_POU, StCode.VENDOR_EXTENSION,
                                     f"{pou.name} is a standard function: this FUNCTION "
                                     "replaces it (IEC reserves the name)", pou.span)
                    except Problems:
                        continue
                if pou.key in self.type_decls:
                    self.error(StCode.DUPLICATE_POU, f"{pou.name} is also a data type "
                               f"(at {self.type_decls[pou.key][0].span})", pou.span)
                    continue
                self.pous[pou.key] = PouInfo(pou, f)
        # Enumerations first: their values may be named in any declaration; then the
        # globals (resolving the types they use, which may use the global constants before
        # them), then the other types.
        enums_first = sorted(self.type_decls, key=lambda k: self.type_decls[k][0].kind != "ENUM")
        for key in enums_first[:sum(d.kind == "ENUM" for d, _ in self.type_decls.values())]:
            try:
                self.user_type(key)
            except Problems:
                continue
        self._declare_globals()
        for key, v in self.globals.items():
            if v.image is None:
                continue
            clash: n.Pou | n.TypeDecl | None = self.pous[key].pou if key in self.pous else (
                self.type_decls[key][0] if key in self.type_decls else None)
            if clash is not None:
                self.error(StCode.DUPLICATE_NAME, f"{clash.name} is {_symbol_clash(v)}",
                           clash.span)
        for key in self.type_decls:
            try:
                self.user_type(key)
            except Problems:
                continue
        for info in self.pous.values():
            self._declare(info)
        self._check_recursion()

    def _declare_globals(self) -> None:
        """VAR_GLOBAL of every file, in file order (a global's initial value may use the
        constants before it), and the config's I/O names ([symbols])."""
        scope = Scope(self, None, "")
        for name, var in self.ctx.symbols:
            found = _SYMBOL_VAR.match(var)
            if found is None:  # the config's loader checks the form: not reached from it
                continue
            area, index, view = found.group(1).upper(), int(found.group(2)), (
                found.group(3) or "").upper()
            image = {("SA", ""): ("SA", "BOOL"), ("SA", "BY"): ("SAB", "BYTE"),
                     ("SK", ""): ("SK", "BYTE"), ("K", ""): ("SK", "BYTE"),
                     ("SK", "BY"): ("SK", "BYTE"), ("K", "BY"): ("SK", "BYTE"),
                     ("SK", "IN"): ("SKIN", "INT"), ("K", "IN"): ("SKIN", "INT"),
                     ("SYVAR", ""): ("SYVAR", "INT")}.get((area, view))
            if image is None:
                continue
            self.globals[name.upper()] = VarInfo(name, image[1], "SYMBOL", None,
                                                 n.Span("[symbols]", 1, 1), None,
                                                 (image[0], index))
        for f in self.files:
            for decl in f.globals:
                key = decl.name.upper()
                try:
                    if key in RESERVED:
                        raise self.error(StCode.DUPLICATE_NAME, f"{decl.name} is reserved "
                                         "(the image and the NC)", decl.span)
                    if key in self.globals:
                        first = self.globals[key]
                        raise self.error(StCode.DUPLICATE_NAME, f"the global {decl.name} is "
                                         + (f"declared twice (first at {first.span})"
                                            if first.image is None else _symbol_clash(first)),
                                         decl.span)
                    self.located(decl)
                    t = self.resolve_type(decl.type, False)
                    initial = self._initial(decl, t, scope)
                    self.globals[key] = VarInfo(decl.name, t, "VAR_GLOBAL", decl.qualifier,
                                                decl.span, initial)
                except Problems:
                    continue

    # -- types -------------------------------------------------------------------------------

    def const_int(self, expr: n.Expr, scope: Scope, what: str) -> int:
        """A constant integer expression (an array bound, a length, an enumeration value,
        a subrange limit): literals, named constants, enumeration values."""
        e = self.expr(expr, scope)
        if e.const is None or isinstance(e.const, bool | float | str):
            raise self.error(StCode.NOT_CONSTANT, f"{what} is a constant integer",
                             _span_of(expr))
        return int(e.const)

    def resolve_type(self, ref: n.TypeRef, in_function: bool,
                     scope: Scope | None = None, in_out: bool = False) -> Type:
        scope = scope or Scope(self, None, "")
        if isinstance(ref, n.ArrayType):
            element = self.resolve_type(ref.element, in_function, scope)
            if ref.dots:  # logi.CAD writes IEC's ARRAY[*] (6.5.3) as ARRAY[..]
                said = "ARRAY[..] is logi.CAD's spelling: IEC 61131-3 (6.5.3) writes ARRAY[*]"
                if self.ctx.strict:  # reported, then read as ARRAY[*]: no errors that follow
                    self.error(StCode.UNSUPPORTED, f"{said} (plc.strict = false accepts "
                               "ARRAY[..])", ref.span)
                else:
                    self.warnings.append(StDiagnostic(StCode.VENDOR_EXTENSION, said,
                                                      ref.span, self._source(ref.span)))
            if any(d is None for d in ref.dims):
                if len(ref.dims) != 1 or not in_out:
                    raise self.error(StCode.UNSUPPORTED, "ARRAY[*] (any length) is a "
                                     "VAR_IN_OUT's or a FUNCTION input's type, of one "
                                     "dimension", ref.span)
                return AnyLength(element)
            dims = [(self.const_int(d[0], scope, "an array bound"),
                     self.const_int(d[1], scope, "an array bound")) for d in ref.dims
                    if d is not None]
            size = 1
            for lo, hi in dims:
                if hi < lo:
                    raise self.error(StCode.UNSUPPORTED, f"ARRAY[{lo}..{hi}] is empty",
                                     ref.span)
                size *= hi - lo + 1
            if size > 65536:
                raise self.error(StCode.UNSUPPORTED, "an array of more than 65536 elements",
                                 ref.span)
            t: Type = element
            for lo, hi in reversed(dims):  # ARRAY[a, b] OF T is ARRAY[a] OF ARRAY[b] OF T
                t = ArrayOf(lo, hi, t)
            return t
        key = ref.name.upper()
        key = DATE_NAMES.get(key, key)
        if isinstance(ref, n.SubrangeType):
            if key not in INTS:
                raise self.error(StCode.TYPE_MISMATCH, f"a subrange is of an integer type, not "
                                 f"{ref.name}", ref.span)
            lo = self.const_int(ref.lo, scope, "a subrange limit")
            hi = self.const_int(ref.hi, scope, "a subrange limit")
            base_lo, base_hi = limits(key)
            if not base_lo <= lo <= hi <= base_hi:
                raise self.error(StCode.CONSTANT_RANGE, f"{key}({lo}..{hi}) is not a subrange "
                                 f"of {key} ({base_lo}..{base_hi})", ref.span)
            return Ranged(key, lo, hi)
        if key in ("STRING", "WSTRING"):
            length = STRING_DEFAULT
            if ref.size is not None:
                length = self.const_int(ref.size, scope, "a string's length")
                if not 1 <= length <= 65535:
                    raise self.error(StCode.CONSTANT_RANGE, f"a {key} holds 1..65535 "
                                     f"characters, not {length}", _span_of(ref.size))
            return StringOf(length, key == "WSTRING")
        if ref.size is not None:
            raise self.error(StCode.TYPE_MISMATCH, f"only STRING and WSTRING take a length, "
                             f"not {ref.name}", ref.span)
        if key in ELEMENTARY:
            return key
        if key in self.type_decls:
            return self.user_type(key)
        if key in STD_FBS or (key in self.pous and self.pous[key].pou.kind == "FUNCTION_BLOCK"):
            if in_function:
                raise self.error(StCode.UNSUPPORTED, "a FUNCTION keeps no state: declare "
                                 f"the {ref.name} instance in a FUNCTION_BLOCK or PROGRAM",
                                 ref.span)
            return FbOf(key, key in STD_FBS)
        if key in UNSUPPORTED_TYPES:
            raise self.error(StCode.UNSUPPORTED, f"{ref.name}: a type outside ncgate's "
                             "subset (docs/plc.md)", ref.span)
        hint = did_you_mean(key, [*ELEMENTARY, *STD_FBS, *self.type_decls, *(
            k for k, p in self.pous.items() if p.pou.kind == "FUNCTION_BLOCK")])
        raise self.error(StCode.UNKNOWN_TYPE, f"unknown type {ref.name}{hint}", ref.span)

    def user_type(self, key: str) -> Type:
        """A TYPE's type, resolved once (in any order; a type that contains itself is
        ST030)."""
        if key in self.resolved:
            return self.resolved[key]
        decl, _ = self.type_decls[key]
        if key in self._resolving:
            raise self.error(StCode.RECURSION, f"the type {decl.name} contains itself",
                             decl.span)
        self._resolving.add(key)
        try:
            t = self._define(decl)
        finally:
            self._resolving.discard(key)
        self.resolved[key] = t
        return t

    def _define(self, decl: n.TypeDecl) -> Type:
        key = decl.key
        scope = Scope(self, None, "")
        if decl.kind == "ENUM":
            values: dict[str, int] = {}
            display: dict[str, str] = {}
            nxt = 0
            for name, expr, span in decl.items:
                vkey = name.upper()
                if vkey in values:
                    raise self.error(StCode.DUPLICATE_NAME, f"{name} is listed twice in "
                                     f"{decl.name}", span)
                if expr is not None:
                    nxt = self.const_int(expr, scope, "an enumeration value")
                values[vkey], display[vkey] = nxt, name
                nxt += 1
                self.enum_values.setdefault(vkey, []).append(key)
            default = next(iter(values.values()))
            if isinstance(decl.initial, str):
                if decl.initial.upper() not in values:
                    raise self.error(StCode.UNKNOWN_NAME, f"{decl.initial} is not a value of "
                                     f"{decl.name}", decl.span)
                default = values[decl.initial.upper()]
            self.enums[key] = EnumInfo(decl.name, values, display, default)
            return EnumOf(key, tuple((number, display[vkey])
                                     for vkey, number in values.items()))
        if decl.kind == "STRUCT":
            info = StructInfo(decl, {})
            for f in decl.fields:
                fkey = f.name.upper()
                try:
                    if fkey in info.fields:
                        raise self.error(StCode.DUPLICATE_NAME, f"{f.name} is declared twice "
                                         f"in {decl.name}", f.span)
                    ft = self.resolve_type(f.type, False, scope)
                    if _holds_fb(ft):
                        raise self.error(StCode.UNSUPPORTED, "a function block instance in a "
                                         "STRUCT: declare it in the FUNCTION_BLOCK or PROGRAM",
                                         f.span)
                    info.fields[fkey] = VarInfo(f.name, ft, "VAR", None, f.span,
                                                self._initial(f, ft, scope))
                except Problems:
                    continue
            self.structs[key] = info
            return StructOf(key)
        assert decl.base is not None
        t = self.resolve_type(decl.base, False, scope)
        if decl.initial is not None and not isinstance(decl.initial, str):
            self.type_defaults[key] = self.initial_value(decl.initial, t, decl.span, scope)
        return t

    def default(self, t: Type, ref: n.TypeRef | None = None) -> Any:
        """A variable's initial value when it declares none: its type's (a TYPE may give
        one), else IEC's (default_value)."""
        if isinstance(ref, n.NamedType) and ref.name.upper() in self.type_defaults:
            return self.type_defaults[ref.name.upper()]
        if isinstance(t, EnumOf):
            return self.enums[t.name].default
        if isinstance(t, StructOf | FbOf):
            return None
        if isinstance(t, ArrayOf):
            if isinstance(t.element, str | StringOf):
                return default_value(t)
            return [self.default(t.element) for _ in range(t.length)]
        return default_value(t)

    def _declare(self, info: PouInfo) -> None:
        pou = info.pou
        in_function = pou.kind == "FUNCTION"
        scope = Scope(self, info, "")
        scope.constants_only = True
        if isinstance(pou.result, n.NamedType) and pou.result.name.upper() == "VOID":
            with suppress(Problems):  # CODESYS's and logi.CAD's FUNCTION without a result
                self.lenient(StCode.UNKNOWN_TYPE, StCode.VENDOR_EXTENSION, f"{pou.name} : "
                             f"VOID (IEC: FUNCTION {pou.name} without a type)",
                             pou.result.span)
        elif pou.result is not None:
            try:
                result = self.resolve_type(pou.result, True, scope)
                if isinstance(result, FbOf):
                    raise self.error(StCode.UNSUPPORTED, "a FUNCTION returns a value, not a "
                                     "function block", pou.result.span)
                info.result = result
                info.vars[pou.key] = VarInfo(pou.name, result, "RESULT", None, pou.span,
                                             self.default(result, pou.result))
            except Problems:
                pass
        for decl in pou.decls:
            key = decl.name.upper()
            try:
                if key in RESERVED:
                    raise self.error(StCode.DUPLICATE_NAME, f"{decl.name} is reserved "
                                     "(the image and the NC)", decl.span)
                if key in info.vars:
                    raise self.error(StCode.DUPLICATE_NAME, f"{decl.name} is declared twice "
                                     f"(first at {info.vars[key].span})", decl.span)
                symbol = self.globals.get(key)
                if symbol is not None and symbol.image is not None:
                    raise self.error(StCode.DUPLICATE_NAME, f"{decl.name} is "
                                     + _symbol_clash(symbol), decl.span)
                self.located(decl)
                t = self.resolve_type(decl.type, in_function, scope,
                                      decl.section == "VAR_IN_OUT" or (
                                          in_function and decl.section == "VAR_INPUT"))
                if decl.section == "VAR_EXTERNAL":
                    found = self.globals.get(key)
                    if found is None:
                        raise self.error(StCode.UNKNOWN_NAME, f"VAR_EXTERNAL {decl.name}: no "
                                         "VAR_GLOBAL of that name", decl.span)
                    if found.type != t:
                        raise self.error(StCode.TYPE_MISMATCH, f"VAR_EXTERNAL {decl.name} is "
                                         f"{t}, the global is {found.type}", decl.span)
                    info.externals.add(key)
                    continue
                if decl.qualifier == "RETAIN" and pou.kind == "FUNCTION":
                    raise self.error(StCode.UNSUPPORTED, "a FUNCTION keeps nothing from one "
                                     "call to the next: no RETAIN variables", decl.span)
                if decl.section == "VAR_IN_OUT" and (decl.initial is not None or _holds_fb(t)):
                    raise self.error(StCode.UNSUPPORTED, "a VAR_IN_OUT is a reference to the "
                                     "caller's variable: no initial value, no function block",
                                     decl.span)
                if decl.section == "VAR_IN_OUT" and pou.kind == "PROGRAM":
                    raise self.error(StCode.UNSUPPORTED, "a PROGRAM has no caller: no "
                                     "VAR_IN_OUT", decl.span)
                initial = self._initial(decl, t, scope)
                info.vars[key] = VarInfo(decl.name, t, decl.section, decl.qualifier,
                                         decl.span, initial)
            except Problems:
                continue

    def located(self, decl: n.VarDecl) -> None:
        """``x AT %IX0.0 : BOOL``: ST031 at AT, and the variable declared all the same, so
        that the rest of the load is checked and every error of it reported."""
        if decl.located is not None:
            self.error(StCode.UNSUPPORTED, "located variables (AT %I…): not supported by "
                       "ncgate's Structured Text; the image is SA[n], SAB[n], SK[n], SYVAR[n] "
                       "or a [symbols] name (docs/plc.md)", decl.located)

    def _initial(self, decl: n.VarDecl, t: Type, scope: Scope) -> Any:
        if decl.initial is None:
            if decl.qualifier == "CONSTANT" and decl.section not in ("VAR_INPUT",
                                                                     "VAR_IN_OUT"):
                raise self.error(StCode.NOT_CONSTANT, f"the CONSTANT {decl.name} needs a "
                                 "value", decl.span)
            return None if isinstance(t, FbOf) or _holds_fb(t) else self.default(t, decl.type)
        return self.initial_value(decl.initial, t, decl.span, scope)

    def initial_value(self, init: n.Initial, t: Type, span: n.Span, scope: Scope) -> Any:
        """A declared initial value (6.5.1.3): a constant, an array's list (``[1, 2(0)]``,
        flat over every dimension, row by row), a structure's ``(x := 1, y := 2)``."""
        if isinstance(t, FbOf) or _holds_fb(t):
            raise self.error(StCode.UNSUPPORTED, "a function block instance takes no initial "
                             "value", span)
        if isinstance(init, n.ArrayInit):
            if not isinstance(t, ArrayOf):
                raise self.error(StCode.TYPE_MISMATCH, f"{t} is not an array", init.span)
            nested = isinstance(t.element, ArrayOf) and all(
                isinstance(v, n.ArrayInit) for _, v in init.items)
            leaf: Type = t
            count = 1
            if not nested:
                while isinstance(leaf, ArrayOf):
                    count *= leaf.length
                    leaf = leaf.element
            else:
                leaf, count = t.element, t.length
            values: list[Any] = []
            for repeat, item in init.items:
                one = self.default(leaf) if item is None else self.initial_value(
                    item, leaf, span, scope)
                values += [one] * repeat
            if len(values) > count:
                raise self.error(StCode.INDEX_RANGE, f"{len(values)} initial values for "
                                 f"{count} elements", init.span)
            values += [self.default(leaf) for _ in range(count - len(values))]
            return values if nested else _reshape(values, t)
        if isinstance(init, n.StructInit):
            if not isinstance(t, StructOf):
                raise self.error(StCode.TYPE_MISMATCH, f"{t} is not a structure", init.span)
            fields = self.structs[t.name].fields
            out: dict[str, Any] = {}
            for name, fspan, sub in init.items:
                fkey = name.upper()
                member = fields.get(fkey)
                if member is None:
                    raise self.error(StCode.UNKNOWN_MEMBER, f"{t.name} has no {name}"
                                     + did_you_mean(fkey, fields), fspan)
                out[fkey] = self.initial_value(sub, member.type, fspan, scope)
            return out
        if isinstance(t, StructOf):
            raise self.error(StCode.TYPE_MISMATCH, f"a {t.name}'s initial value is "
                             "(member := value, …)", _span_of(init))
        if isinstance(t, ArrayOf):
            return _reshape([self._const(init, _leaf(t), scope)] * _leaf_count(t), t)
        return self._const(init, t, scope)

    def _const(self, expr: n.Expr, t: Type, scope: Scope | None = None) -> Any:
        e = self.expr(expr, scope or Scope(self, None, ""))
        if e.const is None:
            raise self.error(StCode.NOT_CONSTANT, "an initial value is a constant",
                             _span_of(expr))
        self.coerce(e, t, _span_of(expr))
        if t == "REAL":
            return _f32(e.const)
        if t in REALS:
            return float(e.const)
        if t == "BOOL":
            return bool(e.const)
        if isinstance(t, StringOf):
            return str(e.const)[:t.length]
        if t in CHARS:
            return e.const if isinstance(e.const, str) else _code_char(e.const, t)
        if isinstance(t, EnumOf):
            return int(e.const)
        if isinstance(t, Ranged):
            return int(e.const)
        return wrap_value(e.const, t) if isinstance(t, str) and t != "BOOL" else e.const

    def _check_recursion(self) -> None:
        uses: dict[str, set[str]] = {}
        for key, info in self.pous.items():
            found: set[str] = set()
            for v in info.vars.values():
                t = v.type
                while isinstance(t, ArrayOf):
                    t = t.element
                if isinstance(t, FbOf) and not t.std:
                    found.add(t.name)
            for call in _calls(info.pou.body):
                if call in self.pous:
                    found.add(call)
            uses[key] = found
        self.uses = uses
        for start in uses:
            stack, seen = [start], set()
            while stack:
                for nxt in uses.get(stack.pop(), ()):
                    if nxt == start:
                        pou = self.pous[start].pou
                        self.error(StCode.RECURSION, f"{pou.name} calls or contains itself "
                                   "(IEC 61131-3 allows no recursion)", pou.span)
                        stack = []
                        break
                    if nxt not in seen:
                        seen.add(nxt)
                        stack.append(nxt)

    # -- pass 2: code -------------------------------------------------------------------------

    def compile(self) -> tuple[str, list[n.Span | None]]:
        self.collect()
        out = self.out
        for key, declared in self.structs.items():
            self._struct_class(key, declared)
        out.emit("class _Globals:", None)
        out.indent += 1
        names = [f"v_{k}" for k, g in self.globals.items() if g.image is None]
        out.emit(f"__slots__ = {tuple(names)!r}", None)
        out.emit("def __init__(self):", None)
        out.indent += 1
        for k, g in self.globals.items():
            if g.image is None:
                out.emit(f"self.v_{k} = {self.init_code(g.type, g.initial)}", g.span)
        out.emit("pass", None)
        out.indent -= 2
        out.emit("_G = _Globals()", None)
        for key, info in self.pous.items():
            self.pou_key = key
            if info.pou.kind == "FUNCTION":
                self._function(key, info)
            else:
                self._class(key, info)
        self.pou_key = ""
        for helper in self.helpers:
            out.lines += helper.lines
            out.spans += helper.spans
        return "\n".join(out.lines) + "\n", out.spans

    def _struct_class(self, key: str, struct: StructInfo) -> None:
        """A structure type as a class: its members, and _copy (an assignment copies)."""
        out = self.out
        out.emit(f"class S_{key}:", struct.decl.span)
        out.indent += 1
        out.emit(f"__slots__ = {tuple(f'v_{k}' for k in struct.fields)!r}", None)
        out.emit("def __init__(self):", None)
        out.indent += 1
        for k, v in struct.fields.items():
            out.emit(f"self.v_{k} = {self.init_code(v.type, v.initial)}", v.span)
        out.emit("pass", None)
        out.indent -= 1
        out.emit("def _copy(self):", None)
        out.indent += 1
        out.emit(f"o = S_{key}.__new__(S_{key})", None)
        for k, v in struct.fields.items():
            out.emit(f"o.v_{k} = {copy_code(f'self.v_{k}', v.type)}", None)
        out.emit("return o", None)
        out.indent -= 2

    def _class(self, key: str, info: PouInfo) -> None:
        out = self.out
        prefix = "P_" if info.pou.kind == "PROGRAM" else "FB_"
        names = info.names
        out.emit(f"class {prefix}{key}:", info.pou.span)
        out.indent += 1
        out.emit(f"__slots__ = {tuple(names)!r}", None)
        out.emit("def __init__(self):", None)
        out.indent += 1
        for k, v in info.vars.items():
            out.emit(f"self.v_{k} = {self.init_code(v.type, v.initial)}", v.span)
            if isinstance(v.type, AnyLength):
                out.emit(f"self.v_{k}__LO = 0", v.span)
        out.emit("pass", None)
        out.indent -= 1
        out.emit("def __call__(self, _now=0):", info.pou.span)
        out.indent += 1
        self._body(info, Scope(self, info, "self."))
        out.indent -= 2

    def _function(self, key: str, info: PouInfo) -> None:
        out = self.out
        # An aggregate's default is made at each call (a Python default is made once).
        params = ", ".join(f"v_{k}=None" if is_aggregate(v.type) or v.section == "VAR_IN_OUT"
                           else f"v_{k}={self.init_code(v.type, v.initial)}"
                           for k, v in info.inputs)
        params += "".join(f", v_{k}__LO=0" for k, v in info.inputs
                          if isinstance(v.type, AnyLength))
        out.emit(f"def F_{key}({params}):", info.pou.span)
        out.indent += 1
        helpers_at = len(out.lines)
        for k, v in info.inputs:
            if is_aggregate(v.type) and v.section == "VAR_INPUT":
                out.emit(f"if v_{k} is None: v_{k} = {self.init_code(v.type, v.initial)}",
                         v.span)
        for k, v in info.vars.items():
            if v.section not in ("VAR_INPUT", "VAR_IN_OUT"):
                out.emit(f"v_{k} = {self.init_code(v.type, v.initial)}", v.span)
        self._local_helpers = []
        self._body(info, Scope(self, info, ""))
        out.emit(self.function_return(info), None)
        out.indent -= 1
        for helper in reversed(self._local_helpers):  # defined first, called later
            out.lines[helpers_at:helpers_at] = helper.lines
            out.spans[helpers_at:helpers_at] = helper.spans

    def function_return(self, info: PouInfo) -> str:
        """A FUNCTION's return: its result, and the values of its VAR_IN_OUTs, which the
        caller stores back into the variables it gave (copy in, copy out)."""
        value = f"v_{info.pou.key}" if info.result is not None else "None"
        if not info.returned:
            return f"return {value}"
        return "return (" + ", ".join([value, *(f"v_{k}" for k in info.returned)]) + ",)"

    def _body(self, info: PouInfo, scope: Scope) -> None:
        out = self.out
        scope.frame_base = out.indent
        guard_at = len(out.lines)
        out.emit("global _LEFT", None)
        for k, v in info.vars.items():
            if v.section == "VAR_TEMP":
                out.emit(f"{scope.prefix}v_{k} = {self.init_code(v.type, v.initial)}", v.span)
        start = len(out.lines)
        if info.pou.kind == "FUNCTION":  # (its helpers are closures: no pieces of their own)
            self.stmts(info.pou.body, scope)
        else:
            self._pieces(info.pou.body, scope)
        if len(out.lines) == start:
            out.emit("pass", None)
        if not scope.loops_used:
            del out.lines[guard_at], out.spans[guard_at]

    def _pieces(self, body: Sequence[n.Stmt], scope: Scope) -> None:
        """A PROGRAM's or FB's statements: inline up to PIECE_LINES lines of Python, past
        that in helper functions of about PIECE_LINES lines each, which Logic compiles one
        at a time."""
        done = 0

        def piece() -> None:
            nonlocal done
            begin = len(self.out.lines)
            while done < len(body) and len(self.out.lines) - begin < PIECE_LINES:
                self.stmts(body[done:done + 1], scope)
                done += 1

        piece()
        while done < len(body):
            self.hoist(piece, scope)

    def init_code(self, t: Type, initial: Any) -> str:
        """The code of a variable's initial value (a new object for an aggregate)."""
        if isinstance(t, AnyLength):
            return "None"  # the caller's array, given at each call
        if isinstance(t, FbOf):
            return f"_STD_{t.name}()" if t.std else f"FB_{t.name}()"
        if isinstance(t, StructOf):
            if not initial:
                return f"S_{t.name}()"
            fields = self.structs[t.name].fields
            members = ", ".join(f"'v_{k}': {self.init_code(fields[k].type, v)}"
                                for k, v in initial.items())
            return f"_struct(S_{t.name}(), {{{members}}})"
        if isinstance(t, ArrayOf):
            if isinstance(t.element, FbOf | StructOf | ArrayOf) and (
                    initial is None or _holds_fb(t)):
                return f"[{self.init_code(t.element, None)} for _ in range({t.length})]"
            if isinstance(t.element, StructOf | ArrayOf):
                return "[" + ", ".join(self.init_code(t.element, v) for v in initial) + "]"
            return repr(list(initial))
        return repr(initial)

    def temp(self) -> str:
        self._temp += 1
        return f"_t{self._temp}"

    # -- statements ----------------------------------------------------------------------------

    def stmts(self, body: Iterable[n.Stmt], scope: Scope) -> None:
        for stmt in body:
            try:
                self.stmt(stmt, scope)
            except Problems:
                continue

    def block(self, body: Sequence[n.Stmt], scope: Scope, span: n.Span) -> None:
        """The statements of an IF, ELSE or CASE arm, one level in."""
        self.nested(lambda: self.stmts(body, scope), scope, span)

    def nested(self, emit: Callable[[], None], scope: Scope, span: n.Span) -> None:
        out = self.out
        out.indent += 1
        try:
            self.content(emit, scope, span)
        finally:
            out.indent -= 1

    def content(self, emit: Callable[[], None], scope: Scope, span: n.Span) -> None:
        """Emit a block's lines at the current indent -- or, deep in the function, a call of
        a helper function that holds them (HOIST_INDENT)."""
        out = self.out
        if scope.nesting >= MAX_NESTING:
            raise self.error(StCode.UNSUPPORTED, f"statements nested more than {MAX_NESTING} "
                             "deep", span)
        scope.nesting += 1
        try:
            if out.indent - scope.frame_base >= HOIST_INDENT or scope.frame_loops >= HOIST_LOOPS:
                self.hoist(emit, scope)
                return
            start = len(out.lines)
            emit()
            if len(out.lines) == start:
                out.emit("pass", None)
        finally:
            scope.nesting -= 1

    def hoist(self, emit: Callable[[], None], scope: Scope) -> None:
        """The block as a helper function: a module-level function of ``self`` for a PROGRAM
        or FB, a closure (``nonlocal`` variables) in a FUNCTION.  EXIT, CONTINUE and RETURN
        inside it return a code that the caller acts on (``flow``)."""
        caller = self.out
        info = scope.info
        local = info is not None and info.pou.kind == "FUNCTION"
        self._frames += 1
        name = f"_B{self._frames}"
        params = ", ".join(([] if local else ["self"]) + scope.live)
        helper = _Emitter(1 if local else 0)
        helper.emit(f"def {name}({params}):", None)
        helper.indent += 1
        helper.emit("global _LEFT", None)
        if local and info is not None:
            helper.emit("nonlocal " + ", ".join(info.names), None)
        saved = (scope.frame, scope.frame_base, scope.frame_loops, scope.codes)
        scope.frame, scope.frame_base, scope.frame_loops = self._frames, helper.indent, 0
        scope.codes = set()
        self.out = helper
        try:
            start = len(helper.lines)
            emit()
            if len(helper.lines) == start:
                helper.emit("pass", None)
            codes = scope.codes
        finally:
            self.out = caller
            scope.frame, scope.frame_base, scope.frame_loops, scope.codes = saved
        (self._local_helpers if local else self.helpers).append(helper)
        if not codes:
            caller.emit(f"{name}({params})", None)
            return
        caller.emit(f"_r = {name}({params})", None)
        for code in sorted(codes):
            caller.emit(f"if _r == {code}:", None)
            caller.indent += 1
            for line in self.flow(code, scope):
                caller.emit(line, None)
            caller.indent -= 1

    def flow(self, code: int, scope: Scope) -> list[str]:
        """The lines of an EXIT, CONTINUE or RETURN in the current Python function."""
        if code != RETURN_CODE and scope.loops and scope.loops[-1][0] == scope.frame:
            return ["break"] if code == EXIT_CODE else [*scope.loops[-1][1], "continue"]
        if code == RETURN_CODE and scope.frame == 0:
            info = scope.info
            return [self.function_return(info) if info is not None and
                    info.pou.kind == "FUNCTION" else "return"]
        scope.codes.add(code)
        return [f"return {code}"]

    def stmt(self, s: n.Stmt, scope: Scope) -> None:
        out = self.out
        span = s.span
        if isinstance(s, n.Assign):
            place = scope.place(s.target, write=True)
            if isinstance(s.expr, n.Call):
                self._prelude_call = s.expr
            try:
                value = self.coerce(self.typed_expr(s.expr, scope, place.type), place.type,
                                    _span_of(s.expr))
            finally:
                self._prelude_call = None
            assert place.store is not None
            out.emit(place.store(value), span)
        elif isinstance(s, n.CallStmt):
            self.call_stmt(s, scope)
        elif isinstance(s, n.If):
            chain, rest = s.branches[:CHAIN_BRANCHES], s.branches[CHAIN_BRANCHES:]
            for i, (cond, body) in enumerate(chain):
                c = self.condition(cond, scope)
                out.emit(f"{'if' if i == 0 else 'elif'} {c}:", _span_of(cond))
                self.block(body, scope, span)
            if rest:  # the next CHAIN_BRANCHES ELSIFs, one level in
                out.emit("else:", span)
                self.block((n.If(rest, s.otherwise, rest[0][0].span),), scope, span)
            elif s.otherwise is not None:
                out.emit("else:", span)
                self.block(s.otherwise, scope, span)
        elif isinstance(s, n.Case):
            self.case(s, scope)
        elif isinstance(s, n.For):
            self.for_loop(s, scope)
        elif isinstance(s, n.While):
            c = self.condition(s.cond, scope)
            out.emit(f"while {c}:", span)
            self.loop_body(s.body, scope, span)
        elif isinstance(s, n.Repeat):
            out.emit("while True:", span)
            self.loop_body(s.body, scope, span, until=s.cond)
        elif isinstance(s, n.Exit):
            if not scope.loops:
                raise self.error(StCode.EXIT_OUTSIDE_LOOP, "EXIT outside a loop", span)
            for line in self.flow(EXIT_CODE, scope):
                out.emit(line, span)
        elif isinstance(s, n.Continue):
            if not scope.loops:
                raise self.error(StCode.EXIT_OUTSIDE_LOOP, "CONTINUE outside a loop", span)
            for line in self.flow(CONTINUE_CODE, scope):
                out.emit(line, span)
        elif isinstance(s, n.Return):
            for line in self.flow(RETURN_CODE, scope):
                out.emit(line, span)

    def loop_body(self, body: Sequence[n.Stmt], scope: Scope, span: n.Span,
                  until: n.Expr | None = None, step: str | None = None) -> None:
        out = self.out
        scope.loops_used = True
        out.indent += 1
        out.emit("_LEFT -= 1", span)
        out.emit("if _LEFT < 0: _guard()", span)
        test = self.condition(until, scope) if until is not None else None
        # What CONTINUE does before it goes back to the top: a FOR steps, a REPEAT tests.
        scope.loops.append((scope.frame, [step] if step is not None else
                            [f"if {test}: break"] if test is not None else []))
        scope.frame_loops += 1
        try:
            self.content(lambda: self.stmts(body, scope), scope, span)
        finally:
            scope.loops.pop()
            scope.frame_loops -= 1
        if until is not None:
            out.emit(f"if {test}: break", _span_of(until))
        if step is not None:
            out.emit(step, span)
        out.indent -= 1

    def condition(self, expr: n.Expr, scope: Scope) -> str:
        e = self.expr(expr, scope)
        if e.type != "BOOL":
            raise self.error(StCode.TYPE_MISMATCH, f"a condition is BOOL, not {e.type}",
                             _span_of(expr))
        return e.code

    def case(self, s: n.Case, scope: Scope) -> None:
        out = self.out
        sel = self.expr(s.selector, scope)
        if not is_int(sel.type) and not isinstance(sel.type, EnumOf):
            raise self.error(StCode.TYPE_MISMATCH, f"CASE selects on an integer or an "
                             f"enumeration, not {sel.type}", _span_of(s.selector))
        t = self.temp()
        out.emit(f"{t} = {sel.code}", s.span)
        scope.live.append(t)  # a helper function holding later arms takes it as a parameter
        try:
            self._arms(s, s.arms, t, sel.type, set(), scope)
        finally:
            scope.live.pop()

    def _arms(self, s: n.Case, arms: Sequence[tuple[tuple[n.CaseLabel, ...], tuple[n.Stmt, ...]]],
              t: str, selector: Type, seen: set[int], scope: Scope) -> None:
        out = self.out
        first = True
        for labels, body in arms[:CHAIN_BRANCHES]:
            tests = []
            for label in labels:
                try:
                    lo = self._label(label.lo, selector, scope)
                    hi = self._label(label.hi, selector, scope) if label.hi is not None \
                        else None
                except Problems:
                    continue
                values = {lo} if hi is None else set(range(lo, hi + 1)) if hi - lo < 4096 \
                    else set()
                if values & seen:
                    self.error(StCode.DUPLICATE_LABEL, f"CASE value {min(values & seen)} "
                               "is listed twice", label.span)
                seen |= values
                tests.append(f"{t} == {lo}" if hi is None else f"{lo} <= {t} <= {hi}")
            out.emit(f"{'if' if first else 'elif'} {' or '.join(tests) or 'False'}:",
                     labels[0].span if labels else s.span)
            first = False
            self.block(body, scope, s.span)
        rest = arms[CHAIN_BRANCHES:]
        if rest:  # the next CHAIN_BRANCHES arms, one level in
            out.emit("else:", s.span)
            self.nested(lambda: self._arms(s, rest, t, selector, seen, scope), scope, s.span)
        elif s.otherwise is not None:
            out.emit("if True:" if first else "else:", s.span)
            self.block(s.otherwise, scope, s.span)

    def _label(self, label: n.Literal | n.Var | n.EnumLit, selector: Type, scope: Scope
               ) -> int:
        """A CASE label: an integer literal, a named constant or an enumeration value
        (7.3.3.3.3: constants of the selector's type)."""
        saved = scope.constants_only
        scope.constants_only = True
        try:
            e = self.typed_expr(label, scope, selector)
        finally:
            scope.constants_only = saved
        if e.const is None or isinstance(e.const, bool | float | str):
            raise self.error(StCode.NOT_CONSTANT, "a CASE label is a constant integer or "
                             "enumeration value", label.span)
        if isinstance(selector, EnumOf) or isinstance(e.type, EnumOf):
            if e.type != selector:
                raise self.error(StCode.TYPE_MISMATCH, f"a CASE label of {_tname(e.type)} "
                                 f"where the selector is {selector}", label.span)
            return int(e.const)
        if e.type not in INTS and e.type != ANY_INT:
            raise self.error(StCode.TYPE_MISMATCH, f"a CASE label is an integer, not "
                             f"{_tname(e.type)}", label.span)
        self.coerce(E(repr(e.const), e.type, e.const), selector, label.span)
        return int(e.const)

    def for_loop(self, s: n.For, scope: Scope) -> None:
        out = self.out
        var = scope.place(n.Var(s.var, (), s.var_span), write=True)
        if not is_int(var.type) or var.type == "TIME":
            raise self.error(StCode.TYPE_MISMATCH, f"a FOR variable is an integer, not "
                             f"{var.type}", s.var_span)
        assert var.store is not None
        start = self.coerce(self.expr(s.start, scope), var.type, _span_of(s.start))
        end = self.coerce(self.expr(s.end, scope), var.type, _span_of(s.end))
        step_e = self.expr(s.step, scope) if s.step is not None else E("1", ANY_INT, 1)
        step = self.coerce(step_e, var.type, _span_of(s.step) if s.step else s.span)
        out.emit(var.store(start), s.span)
        end_t = self.temp()
        out.emit(f"{end_t} = {end}", s.span)
        if step_e.const is None:
            step_t = self.temp()
            out.emit(f"{step_t} = {step}", s.span)
            test = f"(({var.read} <= {end_t}) if {step_t} >= 0 else ({var.read} >= {end_t}))"
        else:
            step_t = step
            test = f"{var.read} {'>=' if step_e.const < 0 else '<='} {end_t}"
        out.emit(f"while {test}:", s.span)
        key = s.var.upper()
        scope.loop_vars.append(key)
        try:
            self.loop_body(s.body, scope, s.span,
                           step=var.store(wrap_code(f"{var.read} + {step_t}", var.type)))
        finally:
            scope.loop_vars.pop()

    def call_stmt(self, s: n.CallStmt, scope: Scope) -> None:
        out = self.out
        target = s.target
        if target.name.upper() == "NC" and len(target.selectors) == 1 and isinstance(
                target.selectors[0], n.Field) and target.selectors[0].name.upper() == "SEND":
            self.nc_send(s, scope)
            return
        key = target.name.upper()
        if not target.selectors and scope.lookup(key) is None and (
                key in STD_FUNCTIONS or key in UNSUPPORTED_FUNCTIONS or _conversion(key) or (
                    key in self.pous and self.pous[key].pou.kind == "FUNCTION")):
            # A FUNCTION called as a statement (IEC 61131-3, 7.3.3.2): its result is dropped.
            call = n.Call(target.name, s.args, s.span)
            self._prelude_call = self._statement_call = call
            try:
                e = self.expr(call, scope)
            finally:
                self._prelude_call = self._statement_call = None
            out.emit(e.code, s.span)
            return
        place = scope.place(target, write=False)
        fb = place.type
        if not isinstance(fb, FbOf):
            raise self.error(StCode.NOT_CALLABLE, f"{_show(target)} is {fb}, not a function "
                             "block instance", s.span)
        members = self.members(fb)
        en, eno = _en_eno(s.args, members)
        if en is not None or eno is not None:
            # EN FALSE: the instance is not called, its outputs stay as they are, nothing
            # is bound (IEC 61131-3, 6.6.1.6); ENO is EN.
            enabled = self.temp()
            condition = "True"
            if en is not None:
                assert en.expr is not None
                condition = self.coerce(self.typed_expr(en.expr, scope, "BOOL"), "BOOL",
                                        _span_of(en.expr))
            out.emit(f"{enabled} = {condition}", s.span)
            out.emit(f"if {enabled}:", s.span)
            out.indent += 1
            try:
                self.call_stmt(n.CallStmt(target, tuple(
                    a for a in s.args if a is not en and a is not eno), s.span), scope)
            finally:
                out.indent -= 1
            if eno is not None:
                self.bind_eno(eno, enabled, scope)
            return
        f = self.temp()
        out.emit(f"{f} = {place.read}", s.span)
        given: set[str] = set()
        outputs: list[str] = []
        for arg in s.args:
            if arg.name is None:
                raise self.error(StCode.BAD_ARGUMENTS, f"name the inputs of {fb.name} "
                                 "(IN := …)", arg.span)
            if members.get(arg.name.upper(), ("",))[0] == "inout":
                # VAR_IN_OUT (6.5.2.2): the caller's variable itself -- copied in before
                # the call and back after it.
                assert arg.expr is not None
                ref = self.reference(arg.expr, members[arg.name.upper()][1], fb.name,
                                     arg.name, scope)
                given.add(arg.name.upper())
                out.emit(f"{f}.v_{arg.name.upper()} = {ref.read}", s.span)
                if ref.lower:
                    out.emit(f"{f}.v_{arg.name.upper()}__LO = {ref.lower}", s.span)
                assert ref.store is not None
                outputs.append(ref.store(f"{f}.v_{arg.name.upper()}"))
                continue
            key = arg.name.upper()
            member = members.get(key)
            if member is None:
                raise self.error(StCode.UNKNOWN_MEMBER, f"{fb.name} has no {arg.name}"
                                 + did_you_mean(key, members), arg.span)
            if key in given:
                raise self.error(StCode.BAD_ARGUMENTS, f"{arg.name} is given twice", arg.span)
            given.add(key)
            direction, mtype = member
            attr = key if fb.std else f"v_{key}"
            if fb.std and key == "ET":
                self.reads_et = True
            if arg.output is None:
                if direction != "in":
                    raise self.error(StCode.BAD_ARGUMENTS, f"{arg.name} is an output of "
                                     f"{fb.name}: bind it with =>", arg.span)
                assert arg.expr is not None
                value = self.coerce(self.typed_expr(arg.expr, scope, mtype), mtype,
                                    _span_of(arg.expr))
                out.emit(f"{f}.{attr} = {value}", s.span)
            else:
                if direction != "out":
                    raise self.error(StCode.BAD_ARGUMENTS, f"{arg.name} is an input of "
                                     f"{fb.name}: give it with :=", arg.span)
                dest = scope.place(arg.output, write=True)
                assert dest.store is not None
                outputs.append(dest.store(self.coerce(E(f"{f}.{attr}", mtype), dest.type,
                                                      arg.output.span)))
        missing = [k for k, (d, _) in members.items() if d == "inout" and k not in given]
        if missing:
            raise self.error(StCode.BAD_ARGUMENTS, f"{fb.name}'s VAR_IN_OUT {missing[0]} is "
                             "given at every call (name := variable)", s.span)
        out.emit(f"{f}(_NOW)", s.span)
        for line in outputs:
            out.emit(line, s.span)

    def reference(self, expr: n.Expr, t: Type, pou: str, name: str, scope: Scope,
                  write: bool = True) -> Place:
        """The variable given to a VAR_IN_OUT (``write``; else an ARRAY[*] VAR_INPUT): a
        writable place of exactly its type (for ARRAY[*] OF T, an array of T of any
        bounds: its lower bound is ``lower``)."""
        if not isinstance(expr, n.Var):
            raise self.error(StCode.BAD_ARGUMENTS, f"{pou}'s {name} is a VAR_IN_OUT or an "
                             "ARRAY[*]: give it a variable, not an expression", _span_of(expr))
        place = scope.place(expr, write=write)
        if isinstance(t, AnyLength):
            if isinstance(place.type, ArrayOf) and place.type.element == t.element:
                return Place(place.read, place.type, place.store, lower=str(place.type.lo))
            if isinstance(place.type, AnyLength) and place.type.element == t.element:
                return Place(place.read, place.type, place.store,
                             lower=f"{place.read}__LO")
        same = place.type == t or (isinstance(place.type, StringOf) and isinstance(
            t, StringOf) and place.type.wide == t.wide)
        if not same:
            raise self.error(StCode.TYPE_MISMATCH, f"{pou}'s VAR_IN_OUT {name} is {t}, not "
                             f"{place.type}", expr.span)
        if isinstance(t, StringOf) and isinstance(place.type, StringOf) and \
                place.type.length < t.length:
            store = place.store
            assert store is not None
            length = place.type.length
            return Place(place.read, place.type, lambda v: store(f"{v}[:{length}]"))
        return place
    def nc_send(self, s: n.CallStmt, scope: Scope) -> None:
        if len(s.args) != 2 or any(a.name is not None for a in s.args):
            raise self.error(StCode.BAD_ARGUMENTS, "NC.SEND(sender, target) takes two "
                             "numbers", s.span)
        codes = []
        for arg, what in zip(s.args, ("sender", "target"), strict=True):
            assert arg.expr is not None
            e = self.expr(arg.expr, scope)
            codes.append(self.coerce(e, "INT", arg.span))
            if e.const is not None:
                if not 1 <= e.const <= self.ctx.processes:
                    raise self.error(StCode.INDEX_RANGE, f"process {e.const} is not "
                                     f"configured (1..{self.ctx.processes})", arg.span)
                if what == "sender" and e.const not in self.ctx.external:
                    raise self.error(StCode.EXTERNAL_SENDER, f"process {e.const} is not "
                                     "external: the PLC sends only in the name of an external "
                                     "process ([[nc.process]] external = true)", arg.span)
        self.out.emit(f"_NC_SEND({codes[0]}, {codes[1]}, {nc_where(s.span)!r})", s.span)

    def retains(self, t: Type) -> bool:
        """Whether a variable of type ``t`` holds an instance of a FUNCTION_BLOCK that
        declares RETAIN (or PERSISTENT) variables: as CODESYS does, the whole instance is
        then retained (docs/plc.md)."""
        while isinstance(t, ArrayOf):
            t = t.element
        if not isinstance(t, FbOf) or t.std:
            return False
        info = self.pous.get(t.name)
        return info is not None and any(v.qualifier == "RETAIN" or (
            v.type != t and self.retains(v.type)) for v in info.vars.values())

    def members(self, fb: FbOf) -> dict[str, tuple[str, Type]]:
        if fb.std:
            return dict(STD_FBS[fb.name])
        info = self.pous[fb.name]
        out: dict[str, tuple[str, Type]] = {}
        for k, v in info.vars.items():
            direction = {"VAR_INPUT": "in", "VAR_OUTPUT": "out", "VAR_IN_OUT": "inout"}.get(
                v.section, "internal")
            out[k] = (direction, v.type)
        return out

    # -- expressions ---------------------------------------------------------------------------

    def coerce(self, e: E, t: Type, span: n.Span) -> str:
        """The code storing ``e`` in a place of type ``t`` (wrapped, truncated, copied,
        checked against a subrange), or a diagnostic."""
        if t in CHARS or e.type in CHARS:
            return self._coerce_char(e, t, span)
        if isinstance(t, StringOf) and isinstance(e.type, StringOf) and t.wide == e.type.wide:
            # IEC 61131-3, 6.4.2: a longer value is truncated to the variable's length.
            if e.const is not None:
                return repr(str(e.const)[:t.length])
            return e.code if e.type.length <= t.length else f"{e.code}[:{t.length}]"
        if isinstance(t, StringOf | EnumOf | StructOf) or isinstance(
                e.type, StringOf | EnumOf | StructOf):
            if e.type == t:
                return copy_code(e.code, t)
            if (isinstance(t, EnumOf) and is_int(e.type)) or (
                    isinstance(e.type, EnumOf) and isinstance(t, str) and t in INTS):
                self.lenient(StCode.TYPE_MISMATCH, StCode.ENUM_AS_INTEGER,
                             f"{_tname(e.type)} where {t} is expected (IEC: an enumeration "
                             "is no integer; name its value)", span)
                return e.code if isinstance(t, EnumOf) else wrap_code(e.code, t)
            hint = ""
            if isinstance(t, StringOf) and isinstance(e.type, StringOf):
                hint = (f" (convert it: {'WSTRING' if e.type.wide else 'STRING'}_TO_"
                        f"{'WSTRING' if t.wide else 'STRING'})")
            raise self.error(StCode.TYPE_MISMATCH, f"{_tname(e.type)} where {t} is expected"
                             + hint, span)
        code = self._coerce(e, t, span)
        if isinstance(t, Ranged):
            if e.const is not None:
                if not t.lo <= e.const <= t.hi:
                    raise self.error(StCode.CONSTANT_RANGE, f"{e.const} is outside the "
                                     f"subrange {t.lo}..{t.hi}", span)
                return code
            return f"_ranged({code}, {t.lo}, {t.hi})"
        return code

    def _coerce_char(self, e: E, t: Type, span: n.Span) -> str:
        """A CHAR or WCHAR stored or taken: a character of its kind, or a STRING literal of
        one character (6.3.3: 'A' is a CHAR where one is due); a CHAR goes into a STRING
        (6.4.2, Figure 11).  CODESYS and logi.CAD read a string's character as a BYTE
        (WORD): with plc.strict = false a character and an integer mix, with a warning."""
        if e.type == t:
            return e.code
        one = _one_char(e, t)
        if one is not None:
            return one.code
        if isinstance(t, StringOf) and widens(e.type, t):
            return e.code
        char = str(t if t in CHARS else e.type)
        code_type = "BYTE" if char == "CHAR" else "WORD"
        if t in CHARS and is_int(e.type):
            self.lenient(StCode.TYPE_MISMATCH, StCode.VENDOR_EXTENSION, f"{_tname(e.type)} "
                         f"where {t} is expected: {_AS_CODE[char]} (IEC: {code_type}_TO_{t})",
                         span)
            if e.const is not None:
                return repr(_code_char(e.const, str(t)))
            return f"_code_char({e.code}, {t!r})"
        if e.type in CHARS and isinstance(t, str) and t in INTS:
            self.lenient(StCode.TYPE_MISMATCH, StCode.VENDOR_EXTENSION, f"{e.type} where {t} "
                         f"is expected: {_AS_CODE[char]} (IEC: {e.type}_TO_{code_type})", span)
            code = f"ord({e.code})"
            return code if limits(t)[1] >= (255 if e.type == "CHAR" else 65535) else \
                wrap_code(code, t)
        hint = ""
        if t == "CHAR" and isinstance(e.type, StringOf):
            hint = " (one character: s[i], or STRING_TO_CHAR)"
        elif isinstance(t, StringOf) and e.type in CHARS:
            hint = f" (convert it: {e.type}_TO_{'WSTRING' if t.wide else 'STRING'})"
        raise self.error(StCode.TYPE_MISMATCH, f"{_tname(e.type)} where {t} is expected"
                         + hint, span)

    def _coerce(self, e: E, t: Type, span: n.Span) -> str:
        if isinstance(t, AnyLength) or isinstance(e.type, AnyLength):
            raise self.error(StCode.UNSUPPORTED, "an ARRAY[*] is read and written element "
                             "by element (LOWER_BOUND .. UPPER_BOUND)", span)
        if e.type == t:
            if isinstance(t, ArrayOf):
                return copy_code(e.code, t)
            if isinstance(t, str) and (is_int(t) or t in CARRIER) and not e.exact:
                return wrap_code(e.code, t)
            return e.code
        if e.type in (ANY_INT, ANY_REAL) and e.const is not None and isinstance(t, str):
            if t == "BOOL" and e.type == ANY_INT and e.exact and e.const in (0, 1):
                # the literals 0 and 1 are BOOL's too (IEC 61131-3, 6.3.2: boolean_literal
                # ::= ['BOOL#'] ('1' | '0') | TRUE | FALSE), where a BOOL is due
                return repr(e.const == 1)
            if t in INTS and e.type == ANY_INT:
                lo, hi = limits(t)
                if not e.exact:  # a constant expression: computed exactly, wrapped here
                    return repr(wrap_value(e.const, t))
                if not lo <= e.const <= hi:
                    raise self.error(StCode.CONSTANT_RANGE, f"{e.const} does not fit in {t} "
                                     f"({lo}..{hi})", span)
                return repr(int(e.const))
            if t in REALS:
                return self._real_const(e.const, t, span)
        if widens(e.type, t):
            if t in REALS and not is_real(e.type):
                return (f"float({e.code})" if t == "LREAL" or e.type in _EXACT_IN_REAL
                        else f"_f32({e.code})")
            return wrap_code(e.code, t) if not e.exact else e.code
        if isinstance(e.type, str) and isinstance(t, str) and (
                (is_int(e.type) and t in INTS) or (e.type == "LREAL" and t == "REAL")):
            self.lenient(StCode.TYPE_MISMATCH, StCode.IMPLICIT_NARROWING,
                         f"{_tname(e.type)} where {t} is expected: an implicit narrowing "
                         f"(IEC: {'DINT' if e.type == ANY_INT else e.type}_TO_{t})", span)
            return real_code(e.code, t) if t == "REAL" else wrap_code(e.code, t)
        hint = ""
        if isinstance(e.type, str) and isinstance(t, str) and e.type in ELEMENTARY \
                and t in ELEMENTARY:
            hint = f" (convert it: {e.type}_TO_{t})"
        elif e.type == ANY_INT and t in DURATIONS:
            hint = " (write a duration: T#100ms)"
        raise self.error(StCode.TYPE_MISMATCH, f"{_tname(e.type)} where {t} is expected"
                         + hint, span)

    def _real_const(self, value: Any, t: Type, span: n.Span) -> str:
        """A constant where a REAL or LREAL is expected: rounded to the type (a REAL
        literal 0.1 is single precision's 0.100000001490116...), or ST021 beyond its range."""
        try:
            return repr(_f32(value) if t == "REAL" else _f64(float(value)))
        except OverflowError:
            raise self.error(StCode.CONSTANT_RANGE, f"{value} does not fit in {t}",
                             span) from None

    def real_operand(self, e: E, t: Type, span: n.Span) -> str:
        """An operand of an operator computing in REAL or LREAL, converted to it."""
        if t not in REALS or e.type == t:
            return e.code
        if e.const is not None and e.type in (ANY_INT, ANY_REAL):
            return self._real_const(e.const, t, span)
        if t == "REAL" and e.type not in _EXACT_IN_REAL and e.type != "REAL":
            return f"_f32({e.code})"
        return e.code

    def named_value(self, x: n.Var, scope: Scope) -> E | None:
        """A name that is a value, not a place: a scalar CONSTANT (folded where it is
        used), or an enumeration's value -- ``RUN``, or CODESYS's ``E_State.RUN``."""
        key = x.name.upper()
        if key in RESERVED:
            return None
        found = scope.lookup(key)
        if found is not None:
            v = found[0]
            if v.qualifier == "CONSTANT" and not x.selectors and isinstance(
                    v.initial, bool | int | float | str) and v.image is None and \
                    v.section not in ("VAR_INPUT", "VAR_IN_OUT"):
                return E(const_code(v.initial, v.type), v.type, v.initial)
            return None
        if key in self.enums and len(x.selectors) == 1 and isinstance(x.selectors[0],
                                                                       n.Field):
            member = x.selectors[0].name
            self.lenient(StCode.TYPE_MISMATCH, StCode.VENDOR_EXTENSION,
                         f"{x.name}.{member}: CODESYS's spelling of an enumeration value "
                         f"(IEC: {x.name}#{member})", x.span)
            return self.enum_lit(n.EnumLit(x.name, member, x.span))
        if not x.selectors and key in self.enum_values:
            owners = self.enum_values[key]
            if len(owners) > 1:
                raise self.error(StCode.TYPE_MISMATCH, f"{x.name} is a value of " + " and "
                                 .join(self.enums[o].display for o in owners if o in self.enums)
                                 + f": name its type ({self.enums[owners[0]].display}#{x.name})",
                                 x.span)
            return self.enum_lit(n.EnumLit(owners[0], x.name, x.span))
        return None

    def typed_expr(self, x: n.Expr, scope: Scope, expected: Type) -> E:
        """An expression where a value of ``expected`` is due: a bare name that is a value
        of several enumerations is that of ``expected`` (IEC 61131-3, 6.4.4.2: the type of
        an enumeration value is given by its context)."""
        if isinstance(x, n.Var) and not x.selectors and isinstance(expected, EnumOf):
            key = x.name.upper()
            if scope.lookup(key) is None and expected.name in self.enum_values.get(key, ()):
                return self.enum_lit(n.EnumLit(expected.name, x.name, x.span))
        return self.expr(x, scope)

    def enum_lit(self, x: n.EnumLit) -> E:
        key = x.type_name.upper()
        if key in self.type_decls and key not in self.enums:
            with suppress(Problems):
                self.user_type(key)
        info = self.enums.get(key)
        if info is None:
            raise self.error(StCode.UNKNOWN_TYPE, f"{x.type_name} is not an enumeration type"
                             + did_you_mean(key, self.enums), x.span)
        value = info.values.get(x.name.upper())
        if value is None:
            raise self.error(StCode.UNKNOWN_NAME, f"{info.display} has no value {x.name}"
                             + did_you_mean(x.name, info.names.values()), x.span)
        return E(repr(value), EnumOf(key), value)

    def expr(self, x: n.Expr, scope: Scope) -> E:
        if isinstance(x, n.Literal):
            return self.literal(x)
        if isinstance(x, n.EnumLit):
            return self.enum_lit(x)
        if isinstance(x, n.Var):
            known = self.named_value(x, scope)
            if known is not None:
                return known
            place = scope.place(x, write=False)
            if isinstance(place.type, FbOf):
                raise self.error(StCode.TYPE_MISMATCH, f"{_show(x)} is a {place.type} "
                                 "instance, not a value (read a member: .Q)", x.span)
            return E(place.read, place.type)
        if self._depth >= MAX_EXPR_DEPTH:
            raise self.error(StCode.UNSUPPORTED, f"an expression nested more than "
                             f"{MAX_EXPR_DEPTH} deep (a chain of operators counts once): "
                             "split it with a variable", _span_of(x))
        self._depth += 1
        try:
            if isinstance(x, n.Unary):
                return self.unary(x, scope)
            if isinstance(x, n.Binary):
                return self.chain(x, scope)
            return self.call(x, scope)
        finally:
            self._depth -= 1

    def chain(self, x: n.Binary, scope: Scope) -> E:
        """A chain of binary operators, left to right, without recursion along it: the
        parser makes ``a + b + c`` ``(a + b) + c``, a tree as deep as the chain is long.
        Every CHAIN_OPS operators the value so far goes into a temporary, in a tuple
        evaluated in order -- ``(_t1 := a + ... + p, _t1 + q ...)[-1]`` -- so the Python stays
        shallow, and AND/OR still skip what they skipped (the left operand comes first)."""
        spine = []
        node: n.Expr = x
        while isinstance(node, n.Binary):
            spine.append(node)
            node = node.left
        acc = self.expr(node, scope)
        done: list[str] = []
        ops = 0
        for op in reversed(spine):
            right = self.typed_expr(op.right, scope, acc.type) if op.op in (
                "=", "<>", "<", ">", "<=", ">=") else self.expr(op.right, scope)
            acc = self.binary(op, acc, right)
            ops += 1
            if ops >= CHAIN_OPS and acc.const is None:
                t = self.temp()
                done.append(f"{t} := {acc.code}")
                acc = E(t, acc.type, None, acc.exact)
                ops = 0
        if done:
            acc = E(f"({', '.join(done)}, {acc.code})[-1]", acc.type, None, acc.exact)
        return acc

    def literal(self, x: n.Literal) -> E:
        t = x.type
        if isinstance(x.value, str) and t in CHARS:
            return E(repr(x.value), t, x.value)
        if isinstance(x.value, str):
            return E(repr(x.value), StringOf(max(len(x.value), 1), t == "WSTRING"), x.value)
        if t is None:
            kind: Type = ANY_REAL if isinstance(x.value, float) else ANY_INT
            if kind == ANY_INT and abs(int(x.value)) >= 1 << 64:
                raise self.error(StCode.CONSTANT_RANGE, f"{x.value} is too large (at most "
                                 "64 bits)", x.span)
            if kind == ANY_REAL and math.isinf(x.value):
                raise self.error(StCode.CONSTANT_RANGE, "a real literal beyond LREAL's range",
                                 x.span)
            return E(repr(x.value), kind, x.value)
        if t in INTS or t == "TIME" or t == "LTIME" or t in DATES:
            lo, hi = limits(CARRIER.get(t, t))
            if not lo <= x.value <= hi:
                shown = f"{x.value} ms" if t == "TIME" else x.value
                limit = (f"{lo}..{hi}" if t != "TIME" else
                         "32-bit ms: T#-24d20h31m23s648ms..T#24d20h31m23s647ms")
                raise self.error(StCode.CONSTANT_RANGE, f"{shown} does not fit in {t} "
                                 f"({limit})", x.span)
        if t in REALS:
            return E(self._real_const(x.value, t, x.span), t, x.value)
        return E(const_code(x.value, t), t, x.value)

    def unary(self, x: n.Unary, scope: Scope) -> E:
        e = self.expr(x.operand, scope)
        if x.op == "NOT":
            if e.type == "BOOL":
                return E(f"(not {e.code})", "BOOL", None if e.const is None else not e.const)
            if e.type in INTS:
                if e.type in SIGNED:
                    return E(f"(~{e.code})", e.type)
                return E(f"(~{e.code} & {limits(str(e.type))[1]})", e.type)
            raise self.error(StCode.TYPE_MISMATCH, f"NOT takes a BOOL or a bit string, not "
                             f"{_tname(e.type)}" + (" (type it: WORD#5)" if e.type == ANY_INT
                                                    else ""), x.span)
        if not is_num(e.type) and e.type not in DURATIONS:
            raise self.error(StCode.TYPE_MISMATCH, f"{x.op} takes a number, not "
                             f"{_tname(e.type)}", x.span)
        if x.op == "+":
            return e
        if e.const is not None:
            if e.type in (ANY_INT, ANY_REAL):
                return E(repr(-e.const), e.type, -e.const, e.exact)
            return E(const_code(-e.const, e.type), e.type, -e.const, not is_int(e.type) or
                     limits(str(e.type))[0] <= -e.const <= limits(str(e.type))[1])
        return E(f"(-{e.code})", e.type, None, not is_int(e.type) and e.type not in DURATIONS)

    def binary(self, x: n.Binary, a: E, b: E) -> E:
        op = x.op
        if op in ("AND_THEN", "OR_ELSE"):
            plain = op.split("_")[0]
            self.lenient(StCode.UNSUPPORTED, StCode.VENDOR_EXTENSION, f"{op}: CODESYS's "
                         f"short-circuit {plain} (IEC: {plain}, which ncgate evaluates "
                         "left to right and stops as soon as the result is known)", x.span)
            op = plain
        if isinstance(a.type, EnumOf) != isinstance(b.type, EnumOf) and (
                is_int(a.type) or is_int(b.type)):
            # CODESYS computes with an enumeration as the integer it is.
            self.lenient(StCode.TYPE_MISMATCH, StCode.ENUM_AS_INTEGER, f"{op} of "
                         f"{_tname(a.type)} and {_tname(b.type)} (IEC: an enumeration is no "
                         "integer; compare it with its values)", x.span)
            a, b = (E(e.code, "INT", e.const) if isinstance(e.type, EnumOf) else e
                    for e in (a, b))
        if op in ("AND", "OR", "XOR"):
            if a.type == "BOOL" and b.type == "BOOL":
                py = {"AND": "and", "OR": "or", "XOR": "!="}[op]
                return E(f"({a.code} {py} {b.code})", "BOOL")
            t = common(a.type, b.type)
            if t is None or not is_int(t):
                raise self.error(StCode.TYPE_MISMATCH, f"{op} of {_tname(a.type)} and "
                                 f"{_tname(b.type)}", x.span)
            py = {"AND": "&", "OR": "|", "XOR": "^"}[op]
            if t == ANY_INT and a.const is not None and b.const is not None:
                value = {"AND": a.const & b.const, "OR": a.const | b.const,
                         "XOR": a.const ^ b.const}[op]
                return E(repr(value), t, value)
            return E(f"({a.code} {py} {b.code})", t)
        if op in ("=", "<>", "<", ">", "<=", ">="):
            a, b = self._char_operands(x, a, b)
            same = (a.type == b.type and isinstance(a.type, str | EnumOf)) or (
                isinstance(a.type, StringOf) and isinstance(b.type, StringOf)
                and a.type.wide == b.type.wide)
            ok = (is_num(a.type) and is_num(b.type)) or (same and (
                a.type != "BOOL" or op in ("=", "<>")))
            if not ok:
                raise self.error(StCode.TYPE_MISMATCH, f"{op} between {_tname(a.type)} and "
                                 f"{_tname(b.type)}", x.span)
            py = {"=": "==", "<>": "!="}.get(op, op)
            t = common(a.type, b.type) if is_num(a.type) and is_num(b.type) else None
            if t in REALS:  # compared as that type: REAL 0.1 = 0.1 is TRUE
                return E(f"({self.real_operand(a, t, x.span)} {py} "
                         f"{self.real_operand(b, t, x.span)})", "BOOL")
            return E(f"({a.code} {py} {b.code})", "BOOL")
        if op == "**":
            if not (is_num(a.type) and is_num(b.type)):
                raise self.error(StCode.TYPE_MISMATCH, f"** of {_tname(a.type)} and "
                                 f"{_tname(b.type)}", x.span)
            t = "LREAL" if "LREAL" in (a.type, b.type) else "REAL"
            return E(real_code(f"_pow({self.real_operand(a, t, x.span)}, "
                               f"{self.real_operand(b, t, x.span)})", t), t)
        # + - * / MOD
        if a.type in _TIMED or b.type in _TIMED:
            return self._time_arith(x, a, b)
        t = common(a.type, b.type)
        if t is None or not is_num(t):
            raise self.error(StCode.TYPE_MISMATCH, f"{op} of {_tname(a.type)} and "
                             f"{_tname(b.type)}", x.span)
        if op in ("/", "MOD") and b.const is not None and b.const == 0:
            raise self.error(StCode.DIVISION_BY_ZERO, f"{op} by zero", _span_of(x.right))
        real = is_real(t)
        if op == "MOD" and real:
            raise self.error(StCode.TYPE_MISMATCH, "MOD takes integers", x.span)
        if a.const is not None and b.const is not None and t in (ANY_INT, ANY_REAL):
            value = _fold(op, a.const, b.const, real)
            if real and math.isinf(value):
                raise self.error(StCode.CONSTANT_RANGE, f"{op} of {a.const} and {b.const} "
                                 "is beyond LREAL's range", x.span)
            # A folded integer is computed exactly and wraps where it is stored, as the
            # same expression of variables does: i := 32767 + 1 stores -32768.
            return E(repr(value), t, value, real)
        if a.const is not None and b.const is not None and isinstance(t, str) and (
                t in INTS or t in REALS) and not isinstance(a.const, bool | str) and \
                not isinstance(b.const, bool | str):
            # Typed constants (named constants: N * 2) fold too -- a declaration needs the
            # value; the result is the type's, computed as at run time.
            value = _fold(op, a.const, b.const, real)
            try:
                value = _f32(value) if t == "REAL" else _f64(float(value)) if real else value
            except OverflowError:
                raise self.error(StCode.CONSTANT_RANGE, f"{op} of {a.const} and {b.const} "
                                 f"is beyond {t}'s range", x.span) from None
            return E(const_code(value, t), t, value, real or (
                limits(t)[0] <= value <= limits(t)[1]))
        ac, bc = (self.real_operand(a, t, x.span), self.real_operand(b, t, x.span)) if real \
            else (a.code, b.code)
        divisor = b.const if isinstance(b.const, int) and not isinstance(b.const, bool) \
            and not real and b.const > 0 else None
        if divisor is not None and op in ("/", "MOD"):
            # By a positive constant: IEC truncates towards zero, spelled inline (the dividend
            # read once, into a temporary) -- a call of _idiv or _mod for each cost bench/plc.py
            # a fifth of its scan.
            q, py = self.temp(), "//" if op == "/" else "%"
            code = f"({q} {py} {divisor} if ({q} := {ac}) >= 0 else -(-{q} {py} {divisor}))"
        elif op == "/":
            code = f"_fdiv({ac}, {bc})" if real else f"_idiv({ac}, {bc})"
            if b.const is not None and real:
                code = f"({ac} / {bc})"
        elif op == "MOD":
            code = f"_mod({ac}, {bc})"
        else:
            code = f"({ac} {op} {bc})"
        return E(real_code(code, t), t, None, real)

    def _char_operands(self, x: n.Binary, a: E, b: E) -> tuple[E, E]:
        """A character compared with a one-character literal (``c = 'A'``) or, with
        plc.strict = false, with an integer (``s[i] >= 53``: compared as its code)."""
        if (a.type in CHARS) == (b.type in CHARS):
            return a, b
        char, other = (a, b) if a.type in CHARS else (b, a)
        one = _one_char(other, char.type)
        if one is not None:
            return (char, one) if char is a else (one, char)
        if not is_int(other.type):
            return a, b
        code_type = "BYTE" if char.type == "CHAR" else "WORD"
        self.lenient(StCode.TYPE_MISMATCH, StCode.VENDOR_EXTENSION, f"{x.op} of "
                     f"{_tname(a.type)} and {_tname(b.type)}: {_AS_CODE[str(char.type)]} "
                     f"(IEC: {char.type}_TO_{code_type})", x.span)
        code = E(f"ord({char.code})", code_type)
        return (code, other) if char is a else (other, code)

    def _time_arith(self, x: n.Binary, a: E, b: E) -> E:
        """Durations, times of day and dates (IEC 61131-3, 6.6.2.5.7, Table 30)."""
        op = x.op
        ta, tb = a.type, b.type
        if op in ("+", "-") and ta == tb and ta in DURATIONS:
            return E(f"({a.code} {op} {b.code})", ta, None, False)
        if (ta in DURATIONS and op in ("*", "/") and is_num(tb)) or (
                tb in DURATIONS and op == "*" and is_num(ta)):
            d, k = (a, b) if ta in DURATIONS else (b, a)
            if op == "/" and k.const == 0:
                raise self.error(StCode.DIVISION_BY_ZERO, "/ by zero", _span_of(x.right))
            if is_real(k.type):  # TIME * REAL: rounded to the unit
                return E(f"_time_real({d.code}, {k.code}, {op == '/'})", d.type, None, False)
            code = f"({d.code} * {k.code})" if op == "*" else f"_idiv({d.code}, {k.code})"
            return E(code, d.type, None, False)
        if ta == "TOD" and tb == "TIME" and op in ("+", "-"):
            return E(f"({a.code} {op} {b.code})", "TOD", None, False)
        if ta == "DT" and tb == "TIME" and op in ("+", "-"):
            return E(f"({a.code} {op} _idiv({b.code}, 1000))", "DT", None, False)
        if op == "-" and ta == tb and ta in DATES:
            scale = "" if ta == "TOD" else " * 1000"
            return E(f"(({a.code} - {b.code}){scale})", "TIME", None, False)
        raise self.error(StCode.TYPE_MISMATCH, f"{op} of {_tname(ta)} and {_tname(tb)} (a "
                         "duration adds to a duration, a TOD or a DT, and multiplies or "
                         "divides by a number; two dates subtract to a TIME)", x.span)

    def call(self, x: n.Call, scope: Scope) -> E:
        key = x.name.upper()
        info = self.pous.get(key)
        en, eno = _en_eno(x.args, info.vars if info is not None else {})
        if en is not None or eno is not None:
            return self.en_call(x, en, eno, scope)
        if info is None or info.pou.kind != "FUNCTION":  # (a user FUNCTION may replace one)
            conv = _conversion(key)
            if conv is not None:
                return self.convert(self.formal(x, ("IN",)), *conv, scope)
            target = DATE_NAMES.get(key[3:], key[3:]) if key.startswith("TO_") else ""
            if target in (*ELEMENTARY, "STRING", "WSTRING"):
                return self.convert_any(self.formal(x, ("IN",)), target, scope)
            if key in STD_FUNCTIONS:
                return self.std_call(x, key, scope)
        if info is None and key in _LOGICAD_BOUNDS:
            return self.logicad_bound(x, _LOGICAD_BOUNDS[key], scope)
        if info is None and key in UNSUPPORTED_FUNCTIONS:
            raise self.error(StCode.UNSUPPORTED, f"{x.name}: a standard function outside "
                             "ncgate's subset (docs/plc.md)", x.span)
        if info is None or info.pou.kind != "FUNCTION":
            what = ("a function block: declare an instance and call it as a statement"
                    if key in STD_FBS or info is not None else "not a function")
            hint = did_you_mean(key, [*STD_FUNCTIONS, *(k for k, p in self.pous.items()
                                                        if p.pou.kind == "FUNCTION")])
            raise self.error(StCode.UNKNOWN_CALL, f"{x.name} is {what}{hint}", x.span)
        inputs = info.inputs
        values: dict[str, str] = {}
        stores: dict[str, Callable[[str], str]] = {}
        for i, arg in enumerate(x.args):
            if arg.output is not None:
                assert arg.name is not None
                k = arg.name.upper()
                out_var = info.vars.get(k)
                if out_var is None or out_var.section != "VAR_OUTPUT":
                    raise self.error(StCode.BAD_ARGUMENTS, f"{x.name} has no output "
                                     f"{arg.name}", arg.span)
                if k in stores:
                    raise self.error(StCode.BAD_ARGUMENTS, f"{arg.name} is given twice",
                                     arg.span)
                dest = scope.place(arg.output, write=True)
                assert dest.store is not None
                stored = self.coerce(E("_VALUE_", out_var.type), dest.type, arg.output.span)
                stores[k] = _bound_store(dest.store, stored)
                continue
            if arg.name is None:
                if i >= len(inputs) or any(a.name is not None for a in x.args[:i]):
                    raise self.error(StCode.BAD_ARGUMENTS, f"{x.name} takes {len(inputs)} "
                                     "input(s); positional ones come first", arg.span)
                k, v = inputs[i]
            else:
                k = arg.name.upper()
                found = dict(inputs).get(k)
                if found is None:
                    raise self.error(StCode.BAD_ARGUMENTS, f"{x.name} has no input "
                                     f"{arg.name}" + did_you_mean(k, dict(inputs)), arg.span)
                v = found
            if k in values:
                raise self.error(StCode.BAD_ARGUMENTS, f"{v.display} is given twice",
                                 arg.span)
            assert arg.expr is not None
            if v.section == "VAR_IN_OUT" or isinstance(v.type, AnyLength):
                ref = self.reference(arg.expr, v.type, x.name, v.display, scope,
                                     v.section == "VAR_IN_OUT")
                values[k] = ref.read if v.section == "VAR_IN_OUT" else copy_code(
                    ref.read, ArrayOf(0, 0, v.type.element) if isinstance(
                        v.type, AnyLength) else v.type)
                if ref.store is not None:
                    stores[k] = ref.store
                if ref.lower:
                    values[f"{k}__LO"] = ref.lower
                continue
            values[k] = self.coerce(self.typed_expr(arg.expr, scope, v.type), v.type,
                                    _span_of(arg.expr))
        args = ", ".join(f"v_{k}={code}" for k, code in values.items())
        if info.result is None and self._statement_call is not x:
            raise self.error(StCode.TYPE_MISMATCH, f"{x.name} has no result (a FUNCTION "
                             "without a type): call it as a statement", x.span)
        result = info.result if info.result is not None else VOID
        missing = [k for k, v in inputs if k not in values and (
            v.section == "VAR_IN_OUT" or isinstance(v.type, AnyLength))]
        if missing:
            raise self.error(StCode.BAD_ARGUMENTS, f"{x.name}'s "
                             f"{info.vars[missing[0]].display} (a VAR_IN_OUT or ARRAY[*]) "
                             "is given at every call", x.span)
        if not info.returned:
            return E(f"F_{key}({args})", result)
        if not any(k in stores for k in info.returned):  # outputs left unbound
            return E(f"F_{key}({args})[0]", result)
        if self._prelude_call is not x:
            raise self.error(StCode.UNSUPPORTED, f"{x.name} writes back (an elementary or "
                             "STRING VAR_IN_OUT, an output bound with =>): call it as a "
                             "statement or alone on the right of := (not inside an "
                             "expression)", x.span)
        t = self.temp()
        self.out.emit(f"{t} = F_{key}({args})", x.span)
        for i, k in enumerate(info.returned):
            if k in stores:
                self.out.emit(stores[k](f"{t}[{i + 1}]"), x.span)
        return E(f"{t}[0]", result)

    def en_call(self, x: n.Call, en: n.Arg | None, eno: n.Arg | None, scope: Scope) -> E:
        """A call with EN and ENO (IEC 61131-3, 6.6.1.6): EN FALSE, the function is not
        executed and its result is its type's default; ENO is EN (a runtime error faults
        the PLC, so there is no executed call whose ENO is FALSE).  Inside an expression a
        call takes EN only: binding ENO writes back, as an output does."""
        inner = n.Call(x.name, tuple(a for a in x.args if a is not en and a is not eno),
                       x.span)
        condition = "True"
        if en is not None:
            assert en.expr is not None
            condition = self.coerce(self.typed_expr(en.expr, scope, "BOOL"), "BOOL",
                                    _span_of(en.expr))
        statement = self._statement_call is x
        if self._prelude_call is not x:  # inside an expression: EN alone
            if eno is not None:
                raise self.error(StCode.UNSUPPORTED, f"{x.name} binds ENO (it writes back): "
                                 "call it as a statement or alone on the right of := (not "
                                 "inside an expression)", eno.span)
            e = self.expr(inner, scope)
            return E(f"({e.code} if {condition} else {self._default_code(e.type)})", e.type)
        out = self.out
        enabled, result = self.temp(), self.temp()
        out.emit(f"{enabled} = {condition}", x.span)
        out.emit(f"if {enabled}:", x.span)
        out.indent += 1
        self._prelude_call = inner
        if statement:
            self._statement_call = inner
        try:
            e = self.expr(inner, scope)
        finally:
            out.indent -= 1
            self._prelude_call = x
            if statement:
                self._statement_call = x
        out.indent += 1
        out.emit(f"{result} = {e.code}", x.span)
        out.indent -= 1
        out.emit("else:", x.span)
        out.indent += 1
        out.emit(f"{result} = {self._default_code(e.type)}", x.span)
        out.indent -= 1
        if eno is not None:
            self.bind_eno(eno, enabled, scope)
        return E(result, e.type)

    def bind_eno(self, eno: n.Arg, enabled: str, scope: Scope) -> None:
        if eno.output is None:
            raise self.error(StCode.BAD_ARGUMENTS, "ENO is an output: bind it with =>",
                             eno.span)
        dest = scope.place(eno.output, write=True)
        assert dest.store is not None
        self.out.emit(dest.store(self.coerce(E(enabled, "BOOL"), dest.type,
                                             eno.output.span)), eno.span)

    def _default_code(self, t: Type) -> str:
        if t == VOID:
            return "None"
        if t == ANY_INT:
            return "0"
        if t == ANY_REAL:
            return "0.0"
        return self.init_code(t, self.default(t))

    def _args(self, x: n.Call, scope: Scope, count: int | None, least: int = 1) -> list[E]:
        if any(a.name is not None or a.output is not None for a in x.args):
            raise self.error(StCode.BAD_ARGUMENTS, f"{x.name} takes its inputs in order, "
                             "unnamed", x.span)
        if (count is not None and len(x.args) != count) or len(x.args) < least:
            want = count if count is not None else f"at least {least}"
            raise self.error(StCode.BAD_ARGUMENTS, f"{x.name} takes {want} input(s), got "
                             f"{len(x.args)}", x.span)
        return [self.expr(a.expr, scope) for a in x.args if a.expr is not None]

    def _same(self, x: n.Call, values: Sequence[E]) -> Type:
        char = next((v.type for v in values if v.type in CHARS), None)
        if char is not None:  # MAX(c, 'A'): the literal is a character there
            values = [_one_char(v, char) or v for v in values]
        t: Type | None = values[0].type
        for v in values[1:]:
            t = common(t, v.type) if t is not None else None
        if t is None:
            raise self.error(StCode.TYPE_MISMATCH, f"{x.name} of " + ", ".join(
                _tname(v.type) for v in values), x.span)
        return t

    def formal(self, x: n.Call, formal: tuple[str, ...]) -> n.Call:
        """A standard function's call with its inputs named (``LIMIT(MN := 0, IN := v, MX :=
        9)``) as the same call with them in order; given in order, the call as it is."""
        if not any(a.name is not None for a in x.args):
            return x
        given: dict[str, n.Arg] = {}
        for arg in x.args:
            if arg.name is None or arg.output is not None:
                raise self.error(StCode.BAD_ARGUMENTS, f"{x.name} takes its inputs all in "
                                 "order or all by name (" + ", ".join(formal) + ")", arg.span)
            if arg.name.upper() in given:
                raise self.error(StCode.BAD_ARGUMENTS, f"{arg.name} is given twice", arg.span)
            given[arg.name.upper()] = arg
        names = [f for f in formal if not f.endswith("*")]
        if formal[-1].endswith("*"):  # IN1, IN2, ... or IN0, IN1, ...: as many as given
            stem, first = formal[-1][:-2], int(formal[-1][-2])
            names += [f"{stem}{first + i}" for i in range(len(given) - len(names))]
        for key, arg in given.items():
            if key not in names:
                raise self.error(StCode.BAD_ARGUMENTS, f"{x.name} has no input {arg.name}"
                                 + did_you_mean(key, names), arg.span)
        missing = [name for name in names if name not in given]
        if missing:
            raise self.error(StCode.BAD_ARGUMENTS, f"{x.name}'s input {missing[0]} is not "
                             "given (its inputs: " + ", ".join(formal) + ")", x.span)
        return n.Call(x.name, tuple(n.Arg(None, given[name].expr, None, given[name].span)
                                    for name in names), x.span)

    def std_call(self, x: n.Call, key: str, scope: Scope) -> E:
        if key in STRING_FUNCTIONS:
            return self.string_call(x, key, scope)
        if key in ("LOWER_BOUND", "UPPER_BOUND"):
            return self.bound(x, key, scope)
        if key in FORMAL_INPUTS:
            x = self.formal(x, FORMAL_INPUTS[key])
        if key in TIME_FUNCTIONS:
            a, b = self._args(x, scope, 2)
            if a.type not in DURATIONS or not is_num(b.type):
                raise self.error(StCode.TYPE_MISMATCH, f"{x.name} takes a TIME and a "
                                 f"number, not {_tname(a.type)} and {_tname(b.type)}", x.span)
            return self.binary(n.Binary(TIME_FUNCTIONS[key], x.args[0].expr or x,
                                        x.args[1].expr or x, x.span), a, b)
        if key == "MOVE":
            (a,) = self._args(x, scope, 1)
            return E(copy_code(a.code, a.type), a.type, a.const, a.exact)
        if key == "CONCAT_DATE_TOD":
            d, tod = self._args(x, scope, 2)
            if d.type != "DATE" or tod.type != "TOD":
                raise self.error(StCode.TYPE_MISMATCH, "CONCAT_DATE_TOD takes a DATE and a TOD",
                                 x.span)
            return E(f"({d.code} + {tod.code} // 1000)", "DT", None, False)
        if key in MATH_FUNCTIONS:
            (a,) = self._args(x, scope, 1)
            if not is_num(a.type):
                raise self.error(StCode.TYPE_MISMATCH, f"{key} takes a number, not "
                                 f"{_tname(a.type)}", x.span)
            mt: Type = "LREAL" if a.type == "LREAL" else "REAL"
            return E(real_code(f"_{key}({self.real_operand(a, mt, x.span)})", mt), mt)
        if key in ("ABS", "SQRT", "TRUNC"):
            (a,) = self._args(x, scope, 1)
            if not is_num(a.type):
                raise self.error(StCode.TYPE_MISMATCH, f"{key} takes a number, not "
                                 f"{_tname(a.type)}", x.span)
            if key == "ABS":
                return E(f"abs({a.code})", a.type, None, not is_int(a.type))
            if key == "TRUNC":
                return E(f"_trunc({a.code})", "DINT")
            rt: Type = "LREAL" if a.type == "LREAL" else "REAL"
            return E(real_code(f"_sqrt({self.real_operand(a, rt, x.span)})", rt), rt)
        if key == "EXPT":
            a, b = self._args(x, scope, 2)
            if not (is_num(a.type) and is_num(b.type)):
                raise self.error(StCode.TYPE_MISMATCH, f"EXPT of {_tname(a.type)} and "
                                 f"{_tname(b.type)}", x.span)
            rt = "LREAL" if "LREAL" in (a.type, b.type) else "REAL"
            return E(real_code(f"_pow({self.real_operand(a, rt, x.span)}, "
                               f"{self.real_operand(b, rt, x.span)})", rt), rt)
        if key in ("MIN", "MAX"):
            values = self._args(x, scope, None, 2)
            t = self._same(x, values)
            if not is_num(t) and t not in _ORDERED and not isinstance(t, StringOf | EnumOf):
                raise self.error(StCode.TYPE_MISMATCH, f"{key} of {t}", x.span)
            codes = ", ".join(self._as(v, t, x) for v in values)
            return E(f"{key.lower()}({codes})", t, None, _exact(values))
        if key == "LIMIT":
            values = self._args(x, scope, 3)
            t = self._same(x, values)
            if not is_num(t) and t not in _ORDERED and not isinstance(t, StringOf | EnumOf):
                raise self.error(StCode.TYPE_MISMATCH, f"LIMIT of {t}", x.span)
            mn, v, mx = (self._as(e, t, x) for e in values)
            return E(f"min(max({v}, {mn}), {mx})", t, None, _exact(values))
        if key == "SEL":
            g, a, b = self._args(x, scope, 3)
            if g.type != "BOOL":
                raise self.error(StCode.TYPE_MISMATCH, f"SEL selects with a BOOL, not "
                                 f"{_tname(g.type)}", x.args[0].span)
            t = self._same(x, [a, b])
            return E(f"({self._as(b, t, x)} if {g.code} else {self._as(a, t, x)})", t, None,
                     _exact([a, b]))
        if key == "MUX":
            values = self._args(x, scope, None, 2)
            k, rest = values[0], values[1:]
            if not is_int(k.type):
                raise self.error(StCode.TYPE_MISMATCH, f"MUX selects with an integer, not "
                                 f"{_tname(k.type)}", x.span)
            t = self._same(x, rest)
            items = ", ".join(self._as(v, t, x) for v in rest)
            return E(f"_mux({k.code}, ({items},))", t, None, _exact(rest))
        # SHL SHR ROL ROR
        a, b = self._args(x, scope, 2)
        if a.type not in BITS and a.type not in UNSIGNED:
            raise self.error(StCode.TYPE_MISMATCH, f"{key} shifts a bit string (BYTE, WORD, "
                             f"DWORD), not {_tname(a.type)}" + (
                                 " (type it: WORD#16#F)" if a.type == ANY_INT else ""), x.span)
        if not is_int(b.type):
            raise self.error(StCode.TYPE_MISMATCH, f"{key} shifts by an integer", x.span)
        size = stdlib.INTEGER_TYPES[str(a.type)][0]
        return E(f"_{key.lower()}({a.code}, {b.code}, {_BIT_TYPE[size]!r})", a.type)

    def logicad_bound(self, x: n.Call, key: str, scope: Scope) -> E:
        """``_firstIndexOf(a)`` / ``_lastIndexOf(a)``: logi.CAD's own functions for the bounds
        of an ARRAY[..]; IEC 61131-3 (6.5.3) writes LOWER_BOUND(a, 1) / UPPER_BOUND(a, 1).
        plc.strict = false reads them so, with a warning; strict, ST012 says the IEC name."""
        said = f"{x.name} is logi.CAD's: IEC 61131-3 (6.5.3) writes {key}(array, 1)"
        if self.ctx.strict:
            raise self.error(StCode.UNKNOWN_CALL, f"{said} (plc.strict = false accepts "
                             f"{x.name})", x.span)
        self.warnings.append(StDiagnostic(StCode.VENDOR_EXTENSION, said, x.span,
                                          self._source(x.span)))
        if len(x.args) != 1 or x.args[0].name is not None or x.args[0].expr is None:
            raise self.error(StCode.BAD_ARGUMENTS, f"{x.name}(array)", x.span)
        one = n.Literal(1, None, x.span)
        return self.bound(n.Call(key, (x.args[0], n.Arg(None, one, None, x.span)), x.span),
                          key, scope)

    def bound(self, x: n.Call, key: str, scope: Scope) -> E:
        """LOWER_BOUND(arr, dim) and UPPER_BOUND(arr, dim) (IEC 61131-3, 6.5.3): of a fixed
        array, constants; of an ARRAY[*] VAR_IN_OUT, what the caller's array has."""
        names = {a.name.upper() for a in x.args if a.name is not None}
        if len(x.args) != 2 or (names and names != {"ARR", "DIM"}) or any(
                a.output is not None or a.expr is None for a in x.args):
            raise self.error(StCode.BAD_ARGUMENTS, f"{x.name}(array, dimension)", x.span)
        args = sorted(x.args, key=lambda a: (a.name or "").upper() == "DIM") if names \
            else list(x.args)
        array, dim = args[0].expr, args[1].expr
        assert array is not None and dim is not None
        number = self.const_int(dim, scope, "a dimension")
        if not isinstance(array, n.Var):
            raise self.error(StCode.TYPE_MISMATCH, f"{x.name} takes an array variable",
                             _span_of(array))
        place = scope.place(array, write=False)
        t: Type = place.type
        for _ in range(number - 1):
            t = t.element if isinstance(t, ArrayOf) else t
        if number < 1 or not isinstance(t, ArrayOf | AnyLength) or (
                isinstance(t, AnyLength) and number != 1):
            raise self.error(StCode.INDEX_RANGE, f"{_show(array)} has no dimension {number}",
                             _span_of(dim))
        if isinstance(t, ArrayOf):
            value = t.lo if key == "LOWER_BOUND" else t.hi
            return E(repr(value), "DINT", value)
        lower = f"{place.read}__LO"
        return E(lower if key == "LOWER_BOUND" else f"({lower} + len({place.read}) - 1)",
                 "DINT")

    def string_call(self, x: n.Call, key: str, scope: Scope) -> E:
        """LEN, LEFT, RIGHT, MID, CONCAT, INSERT, DELETE, REPLACE, FIND (IEC 61131-3,
        Table 43), called with their inputs in order or by their names (IN, L, P, IN1…)."""
        formal = {"LEN": ("IN",), "LEFT": ("IN", "L"), "RIGHT": ("IN", "L"),
                  "MID": ("IN", "L", "P"), "INSERT": ("IN1", "IN2", "P"),
                  "DELETE": ("IN", "L", "P"), "REPLACE": ("IN1", "IN2", "L", "P"),
                  "FIND": ("IN1", "IN2")}
        if key == "CONCAT":
            names = tuple(f"IN{i + 1}" for i in range(len(x.args)))
            if len(x.args) < 2:
                raise self.error(StCode.BAD_ARGUMENTS, "CONCAT takes at least 2 inputs",
                                 x.span)
        else:
            names = formal[key]
        args = list(x.args)
        if any(a.name is not None for a in args):
            given = {a.name.upper(): a for a in args if a.name is not None}
            if len(given) != len(args) or set(given) != set(names):
                raise self.error(StCode.BAD_ARGUMENTS, f"{x.name} takes "
                                 + ", ".join(names) + ", all in order or all by name",
                                 x.span)
            args = [given[name] for name in names]
        if len(args) != len(names) or any(a.output is not None for a in args):
            raise self.error(StCode.BAD_ARGUMENTS, f"{x.name} takes {len(names)} input(s) ("
                             + ", ".join(names) + f"), got {len(args)}", x.span)
        values = []
        for name, arg in zip(names, args, strict=True):
            assert arg.expr is not None
            e = self.expr(arg.expr, scope)
            if e.type in CHARS and (key == "CONCAT" or (
                    name == "IN2" and key in ("INSERT", "REPLACE", "FIND"))):
                e = E(e.code, StringOf(1, e.type == "WCHAR"), e.const)  # ANY_CHARS there
            if name.startswith("IN") and not isinstance(e.type, StringOf):
                raise self.error(StCode.TYPE_MISMATCH, f"{x.name}'s {name} is a STRING or "
                                 f"WSTRING, not {_tname(e.type)}", arg.span)
            if name in ("L", "P") and not is_int(e.type):
                raise self.error(StCode.TYPE_MISMATCH, f"{x.name}'s {name} is an integer, "
                                 f"not {_tname(e.type)}", arg.span)
            values.append(e)
        texts = [v.type for v in values if isinstance(v.type, StringOf)]
        if any(t.wide != texts[0].wide for t in texts):
            raise self.error(StCode.TYPE_MISMATCH, f"{x.name} of a STRING and a WSTRING "
                             "(convert one: STRING_TO_WSTRING)", x.span)
        c = [v.code for v in values]
        first = texts[0]
        if key == "LEN":
            return E(f"len({c[0]})", "INT")
        if key == "FIND":
            return E(f"_find({c[0]}, {c[1]})", "INT")
        joined = StringOf(min(sum(t.length for t in texts), 65535), first.wide)
        if key == "CONCAT":
            if all(v.const is not None for v in values):
                text = "".join(str(v.const) for v in values)
                return E(repr(text), joined, text)
            return E("(" + " + ".join(c) + ")", joined)
        call = {"LEFT": "_left", "RIGHT": "_right", "MID": "_midstr", "INSERT": "_insert",
                "DELETE": "_delete", "REPLACE": "_replace"}[key]
        return E(f"{call}({', '.join(c)})", joined if key in ("INSERT", "REPLACE") else first)

    def _as(self, e: E, t: Type, x: n.Call) -> str:
        """An argument of a standard function: checked against the common type, but not
        wrapped -- the functions compute on exact values, like the operators; the result
        wraps where it is stored."""
        if t in (ANY_INT, ANY_REAL):
            return e.code
        return self.coerce(E(e.code, e.type, e.const, True), t, x.span)

    def convert_any(self, x: n.Call, dst: str, scope: Scope) -> E:
        """TO_INT(x), TO_REAL(x), ... (IEC 61131-3, 6.6.2.5.2, Table 22): the conversion
        from the argument's own type (an untyped literal is a DINT or an LREAL)."""
        (a,) = self._args(x, scope, 1)
        src: Type = {ANY_INT: "DINT", ANY_REAL: "LREAL"}.get(str(a.type), a.type)
        if isinstance(src, StringOf):
            src = "WSTRING" if src.wide else "STRING"
        if isinstance(src, Ranged):
            src = str(src)
        if not isinstance(src, str) or src not in (*ELEMENTARY, "STRING", "WSTRING"):
            raise self.error(StCode.TYPE_MISMATCH, f"{x.name} converts an elementary value, "
                             f"not {_tname(a.type)}", x.span)
        if src == dst:
            return E(a.code, a.type, a.const, a.exact)
        return self.convert(x, src, dst, scope, a)

    def convert(self, x: n.Call, src: str, dst: str, scope: Scope, given: E | None = None
                ) -> E:
        (a,) = self._args(x, scope, 1) if given is None else (given,)
        texts = ("STRING", "WSTRING")
        if src in CHARS or dst in CHARS:
            return self._convert_char(x, src, dst, a)
        if a.type in CHARS and src in INTS:  # BYTE_TO_INT(s[i]), plc.strict = false
            a = E(self._coerce_char(a, src, x.span), src)
        if src in texts:
            if not (isinstance(a.type, StringOf) and a.type.wide == (src == "WSTRING")):
                raise self.error(StCode.TYPE_MISMATCH, f"{x.name} takes a {src}, not "
                                 f"{_tname(a.type)}", x.span)
            if dst in texts:  # a character beyond one byte becomes '?'
                return E(f"{a.code}.encode('latin-1', 'replace').decode('latin-1')"
                         if dst == "STRING" else a.code, StringOf(a.type.length, dst != "STRING"))
            if dst == "BOOL" or dst in INTS or dst in REALS:
                value = f"_strto({a.code}, {dst!r})"
                return E(real_code(value, dst) if dst in REALS else value, dst, None,
                         dst in REALS or dst == "BOOL")
            raise self.error(StCode.UNSUPPORTED, f"{x.name}: a text converts to BOOL, an "
                             "integer or a real (docs/plc.md)", x.span)
        if dst in texts:
            if not (a.type == src or widens(a.type, src)) or not (
                    src == "BOOL" or src in INTS or src in REALS):
                raise self.error(StCode.UNSUPPORTED if a.type == src else
                                 StCode.TYPE_MISMATCH, f"{x.name}: BOOL, integers and reals "
                                 f"convert to text, not {_tname(a.type)}", x.span)
            return E(f"_tostr({a.code}, {src!r})", StringOf(STRING_DEFAULT, dst == "WSTRING"))
        if not (a.type == src or widens(a.type, src)):
            raise self.error(StCode.TYPE_MISMATCH, f"{x.name} takes a {src}, not "
                             f"{_tname(a.type)}", x.span)
        code = a.code
        if a.const is not None and a.type in (ANY_INT, ANY_REAL) and src in REALS:
            code = self._real_const(a.const, src, x.span)
        special = {("TIME", "LTIME"): f"({code} * 1000000)",
                   ("LTIME", "TIME"): f"_idiv({code}, 1000000)",
                   ("DT", "DATE"): f"({code} - {code} % 86400)",
                   ("DT", "TOD"): f"({code} % 86400 * 1000)",
                   ("DATE", "DT"): code}
        if (src, dst) in special:
            return E(special[src, dst], dst, None, False)
        if (src in _TIMED and dst in _TIMED) or (src in DATES and dst in REALS) or (
                dst in DATES and (src in REALS or src == "BOOL")):
            raise self.error(StCode.UNSUPPORTED, f"{x.name}: not a conversion of IEC "
                             "61131-3's (docs/plc.md lists them)", x.span)
        if dst in REALS:
            exact = dst == "LREAL" or src in _EXACT_IN_REAL or src == "REAL" or src == "BOOL"
            return E(f"float({code})" if exact else f"_f32({code})", dst)
        if dst == "BOOL":
            return E(f"({code} != 0)", "BOOL")
        if src in REALS or a.type == ANY_REAL:
            lo, hi = limits(CARRIER.get(dst, dst))
            return E(f"_r2i({code}, {lo}, {hi}, {dst!r})", dst)
        if src == "BOOL":
            return E(f"int({code})", dst)
        return E(code, dst, None, False)

    def _convert_char(self, x: n.Call, src: str, dst: str, a: E) -> E:
        """CHAR and WCHAR (IEC 61131-3 3rd ed., 6.6.2.5): to and from a bit string (the
        character's code, cut or zero-extended as bit strings are), to their STRING and
        back (its first character; '$00' of an empty one), and to each other (a WCHAR
        beyond Latin-1 becomes '?', as WSTRING_TO_STRING does)."""
        wide = {"STRING": False, "WSTRING": True}
        if src in CHARS:
            a = _one_char(a, src) or a
            if a.type != src:
                raise self.error(StCode.TYPE_MISMATCH, f"{x.name} takes a {src}, not "
                                 f"{_tname(a.type)}", x.span)
        elif src in wide:
            if not (isinstance(a.type, StringOf) and a.type.wide == wide[src]):
                raise self.error(StCode.TYPE_MISMATCH, f"{x.name} takes a {src}, not "
                                 f"{_tname(a.type)}", x.span)
        elif not (a.type == src or widens(a.type, src)):
            raise self.error(StCode.TYPE_MISMATCH, f"{x.name} takes a {src}, not "
                             f"{_tname(a.type)}", x.span)
        if src in CHARS and dst in BITS:
            code = f"ord({a.code})"
            fits = limits(dst)[1] >= (255 if src == "CHAR" else 65535)
            return E(code if fits else wrap_code(code, dst), dst)
        if src in BITS and dst in CHARS:
            return E(f"_code_char({a.code}, {dst!r})", dst)
        if (src, dst) in (("CHAR", "STRING"), ("WCHAR", "WSTRING")):
            return E(a.code, StringOf(1, dst == "WSTRING"), a.const)
        if (src, dst) in (("STRING", "CHAR"), ("WSTRING", "WCHAR")):
            return E(f"({a.code}[:1] or '\\0')", dst)
        if (src, dst) == ("CHAR", "WCHAR"):
            return E(a.code, dst, a.const)
        if (src, dst) == ("WCHAR", "CHAR"):
            return E(f"{a.code}.encode('latin-1', 'replace').decode('latin-1')", dst)
        raise self.error(StCode.UNSUPPORTED, f"{x.name}: not a conversion of IEC 61131-3's "
                         "(a CHAR converts to a bit string, its STRING and a WCHAR: "
                         "CHAR_TO_BYTE; docs/plc.md)", x.span)


class Scope:
    """The names a POU body sees, and how to reach them."""

    def __init__(self, compiler: Compiler, info: PouInfo | None, prefix: str) -> None:
        self.c = compiler
        self.info = info
        self.prefix = prefix
        self.loop_vars: list[str] = []
        self.loops_used = False
        # The enclosing loops: the Python function each is in, and what its CONTINUE runs.
        self.loops: list[tuple[int, list[str]]] = []
        # The Python function being written (0: the POU's own, else a helper's number),
        # the indent its body starts at, the loops open in it, the codes it may return.
        self.frame = 0
        self.frame_base = 1
        self.frame_loops = 0
        self.codes: set[int] = set()
        self.nesting = 0
        self.live: list[str] = []  # temporaries a helper function must be given
        self.constants_only = False  # a declaration: only constants may be named

    def lookup(self, key: str) -> tuple[VarInfo, str] | None:
        """A name's variable and the code of it: the POU's own, else a global."""
        info = self.info
        v = info.vars.get(key) if info is not None else None
        if v is not None:
            return v, f"{self.prefix}v_{key}"
        g = self.c.globals.get(key)
        if g is not None:
            return g, f"_G.v_{key}"
        return None

    def place(self, var: n.Var, write: bool) -> Place:
        c = self.c
        key = var.name.upper()
        if key in IMAGE_NAMES:
            return self._image(var, key, write)
        if key == "NC":
            return self._nc(var, write)
        info = self.info
        found = self.lookup(key)
        if found is None or (self.constants_only and found[0].qualifier != "CONSTANT"):
            names = [x.display for x in info.vars.values()] if info is not None else []
            names += [g.display for g in c.globals.values()]
            hint = did_you_mean(key, [*names, *IMAGE_NAMES, "NC"])
            if found is not None:
                raise c.error(StCode.NOT_CONSTANT, f"{var.name}: a declaration or CASE label "
                              "takes constants (literals, VAR CONSTANT, enumeration values)",
                              var.span)
            raise c.error(StCode.UNKNOWN_NAME, f"unknown variable {var.name}{hint}", var.span)
        v, code = found
        if v.image is not None:
            return self._symbol(var, v, write)
        t: Type = v.type
        why = ""
        if v.qualifier == "CONSTANT":
            why = f"{v.display} is CONSTANT"
        elif key in self.loop_vars and not var.selectors:
            why = f"{v.display} is the FOR loop's variable"
        place = self._select(var, code, t, why, write)
        if v.section == "VAR_IN_OUT" and not var.selectors and place.store is not None and \
                isinstance(t, ArrayOf | StructOf):
            # The caller's own array or structure: an assignment writes into it.
            return Place(place.read, t, (lambda value: f"{code}[:] = {value}") if isinstance(
                t, ArrayOf) else (lambda value: f"_fill({code}, {value})"))
        return place

    def _select(self, var: n.Var, code: str, t: Type, why: str, write: bool) -> Place:
        c = self.c
        for sel in var.selectors:
            if isinstance(sel, n.Index) and isinstance(t, AnyLength):
                i = c.expr(sel.expr, self)
                if not is_int(i.type):
                    raise c.error(StCode.TYPE_MISMATCH, f"an index is an integer, not "
                                  f"{_tname(i.type)}", sel.span)
                code = f"{code}[_ix({i.code}, {code}__LO, len({code}))]"
                t = t.element
            elif isinstance(sel, n.Index) and isinstance(t, StringOf):
                return self._character(var, sel, code, t, why, write)
            elif isinstance(sel, n.Index):
                if not isinstance(t, ArrayOf):
                    raise c.error(StCode.TYPE_MISMATCH, f"{var.name} is {t}, not an array",
                                  sel.span)
                i = c.expr(sel.expr, self)
                if not is_int(i.type):
                    raise c.error(StCode.TYPE_MISMATCH, f"an index is an integer, not "
                                  f"{_tname(i.type)}", sel.span)
                if i.const is not None:
                    if not t.lo <= i.const <= t.hi:
                        raise c.error(StCode.INDEX_RANGE, f"index {i.const} outside "
                                      f"{t.lo}..{t.hi}", sel.span)
                    code = f"{code}[{i.const - t.lo}]"
                else:
                    code = f"{code}[_ix({i.code}, {t.lo}, {t.length})]"
                t = t.element
            elif isinstance(sel, n.Bit):
                if sel.codesys:
                    c.lenient(StCode.UNSUPPORTED, StCode.VENDOR_EXTENSION, f"{var.name}"
                              f".%X{sel.bit}: CODESYS's bit access (IEC: {var.name}."
                              f"{sel.bit})", sel.span)
                if sel is not var.selectors[-1] or not isinstance(t, str) or t not in INTS:
                    raise c.error(StCode.TYPE_MISMATCH, f"{_show(var)}: bit access is the last "
                                  f"selector, of an integer or bit string, not {t}", sel.span)
                width = stdlib.INTEGER_TYPES[t][0]
                if sel.bit >= width:
                    raise c.error(StCode.INDEX_RANGE, f"bit {sel.bit} of a {width}-bit {t} "
                                  f"(0..{width - 1})", sel.span)
                if write and why:
                    raise c.error(StCode.READ_ONLY, f"cannot write {_show(var)}: {why}",
                                  var.span)
                return Place(f"(({code} >> {sel.bit}) & 1 == 1)", "BOOL",
                             _bit_store(code, sel.bit, t) if not why else None, why)
            elif isinstance(t, StructOf):
                fields = c.structs[t.name].fields
                mkey = sel.name.upper()
                member = fields.get(mkey)
                if member is None:
                    raise c.error(StCode.UNKNOWN_MEMBER, f"{t.name} has no {sel.name}"
                                  + did_you_mean(mkey, fields), sel.span)
                code = f"{code}.v_{mkey}"
                t = member.type
            else:
                if not isinstance(t, FbOf):
                    raise c.error(StCode.UNKNOWN_MEMBER, f"{_show(var)}: {t} has no members",
                                  sel.span)
                members = c.members(t)
                mkey = sel.name.upper()
                member_fb = members.get(mkey)
                if member_fb is None:
                    raise c.error(StCode.UNKNOWN_MEMBER, f"{t.name} has no {sel.name}"
                                  + did_you_mean(mkey, members), sel.span)
                direction, mtype = member_fb
                if direction in ("internal", "inout"):
                    raise c.error(StCode.UNKNOWN_MEMBER, f"{sel.name} is internal to "
                                  f"{t.name} (only VAR_INPUT and VAR_OUTPUT are seen outside)",
                                  sel.span)
                if direction == "out":
                    why = f"{sel.name} is an output of {t.name}"
                if t.std and mkey == "ET":
                    c.reads_et = True
                code = f"{code}.{mkey if t.std else 'v_' + mkey}"
                t = mtype
        if write and why:
            raise c.error(StCode.READ_ONLY, f"cannot write {_show(var)}: {why}", var.span)
        if write and isinstance(t, FbOf):
            raise c.error(StCode.TYPE_MISMATCH, f"cannot assign to the {t.name} instance "
                          f"{_show(var)}", var.span)
        final = code
        return Place(final, t, (lambda value: f"{final} = {value}") if not why else None, why)

    def _character(self, var: n.Var, sel: n.Index, code: str, t: StringOf, why: str,
                   write: bool) -> Place:
        """``s[i]``: one character of a STRING (a CHAR) or a WSTRING (a WCHAR), the first
        at 1 (IEC 61131-3, 3rd ed.).  An index outside the string faults, as outside an
        array; ``s[LEN(s) + 1] := c`` adds the character (docs/decisions.md)."""
        c = self.c
        after = var.selectors[var.selectors.index(sel) + 1:]
        if after:
            raise c.error(StCode.TYPE_MISMATCH, f"{_show(var)}: a character has no members, "
                          "bits or indices", after[0].span)
        i = c.expr(sel.expr, self)
        if not is_int(i.type):
            raise c.error(StCode.TYPE_MISMATCH, f"an index is an integer, not "
                          f"{_tname(i.type)}", sel.span)
        if i.const is not None and not 1 <= i.const <= t.length:
            raise c.error(StCode.INDEX_RANGE, f"character {i.const} of a {t} "
                          f"(1..{t.length})", sel.span)
        if write and why:
            raise c.error(StCode.READ_ONLY, f"cannot write {_show(var)}: {why}", var.span)
        index, length = i.code, t.length
        return Place(f"_char_at({code}, {index})", "WCHAR" if t.wide else "CHAR",
                     (lambda v: f"{code} = _set_char({code}, {index}, {v}, {length})")
                     if not why else None, why)

    def _symbol(self, var: n.Var, v: VarInfo, write: bool = False) -> Place:
        """An I/O name of [symbols]: its image variable, read and written as SA[i], SAB[i],
        SK[i] or SYVAR[i] are (SKn.IN: the two bytes n, n+1 as an INT, low byte first)."""
        c = self.c
        assert v.image is not None
        area, index = v.image
        if area == "SKIN":
            c.image_keys.update((("SK", index), ("SK", index + 1)))
            if not write:
                c.note_reads((("SK", index), ("SK", index + 1)))
            place = _writing(c, Place(
                f"((((_SK[{index}] | _SK[{index + 1}] << 8)) ^ 32768) - 32768)", "INT",
                lambda val: f"_SK[{index}:{index + 2}] = (({val}) & 65535).to_bytes(2, "
                            "'little')"), (("SK", index), ("SK", index + 1)), var.span)
        else:
            place = self._image(n.Var(area, (n.Index(n.Literal(index, None, var.span),
                                                     var.span),), var.span), area,
                                write and not var.selectors, noted=not var.selectors)
        if not var.selectors:
            return place
        sel = var.selectors[0]
        if isinstance(sel, n.Bit) and sel.codesys:
            c.lenient(StCode.UNSUPPORTED, StCode.VENDOR_EXTENSION, f"{var.name}.%X{sel.bit}: "
                      f"CODESYS's bit access (IEC: {var.name}.{sel.bit})", sel.span)
        if len(var.selectors) > 1 or not isinstance(sel, n.Bit) or place.type == "BOOL":
            raise c.error(StCode.TYPE_MISMATCH, f"{v.display} is the {place.type} "
                          f"{area}{index}: no members or indices (bit access: .0)", sel.span)
        width = 8 if place.type == "BYTE" else 16
        if sel.bit >= width:
            raise c.error(StCode.INDEX_RANGE, f"bit {sel.bit} of a {width}-bit "
                          f"{place.type} (0..{width - 1})", sel.span)
        mask, read, store = 1 << sel.bit, place.read, place.store
        assert store is not None
        # The one bit of an SA byte the logic writes; of an SK byte or a SYVAR, the variable.
        written = ("SA", index * 8 + sel.bit) if area == "SAB" else (
            ("SK", index) if area == "SK" else ("SYVAR", index))
        if not write:
            c.note_reads((written,))
        return _writing(c, Place(f"(({read} >> {sel.bit}) & 1 == 1)", "BOOL", lambda val: store(
            wrap_code(f"({read} | {mask}) if {val} else ({read} & {~mask})", place.type))),
            (written,), var.span)

    def _image(self, var: n.Var, key: str, write: bool, noted: bool = True) -> Place:
        """``noted``: its writes at a constant index are noted (Compiler.image_writes) --
        not by a symbol's bit access, which notes the one bit it writes."""
        c = self.c
        ctx = c.ctx
        if len(var.selectors) != 1 or not isinstance(var.selectors[0], n.Index):
            raise c.error(StCode.TYPE_MISMATCH, f"{var.name} is indexed: {var.name}[n]",
                          var.span)
        sel = var.selectors[0]
        size = {"SA": ctx.sa_bits, "SAB": ctx.sa_bits // 8, "SK": ctx.k_bytes,
                "SYVAR": ctx.syvars}[key]
        i = c.expr(sel.expr, self)
        if not is_int(i.type):
            raise c.error(StCode.TYPE_MISMATCH, f"an index is an integer, not "
                          f"{_tname(i.type)}", sel.span)
        if i.const is not None and not 0 <= i.const < size:
            raise c.error(StCode.INDEX_RANGE, f"{var.name}[{i.const}] is outside the image "
                          f"({var.name}[0..{size - 1}], [plc] in the config)", sel.span)
        area = "SYVAR" if key == "SYVAR" else "SK" if key == "SK" else "SA"
        const = i.const
        if const is None:
            c.image_areas.add(area)
            (c.computed_writes if write else c.computed_reads).setdefault(
                c.pou_key, set()).add(area)
        else:
            c.image_keys.add((area, const >> 3 if key == "SA" else const))
            keys: tuple[tuple[str, int], ...] = (
                (("SA", const),) if key == "SA" else
                tuple(("SA", const * 8 + bit) for bit in range(8)) if key == "SAB" else
                ((area, const),))
            if not write and noted:
                c.note_reads(keys)
            if noted:
                return _writing(c, self._image_at(key, i, size), keys, var.span)
        return self._image_at(key, i, size)

    def _image_at(self, key: str, i: E, size: int) -> Place:
        """SA[i], SAB[i], SK[i] or SYVAR[i] (``i`` checked: an integer, in range if known)."""
        const = i.const
        if key == "SA":
            if const is not None:
                byte, mask = const >> 3, 1 << (const & 7)
                return Place(f"((_SA[{byte}] & {mask}) != 0)", "BOOL",
                             lambda v: f"_SA[{byte}] = (_SA[{byte}] | {mask}) if {v} else "
                                       f"(_SA[{byte}] & {255 ^ mask})")
            t = self.c.temp()
            idx = f"_ix({i.code}, 0, {size})"
            return Place(f"((_SA[({t} := {idx}) >> 3] >> ({t} & 7)) & 1 == 1)", "BOOL",
                         lambda v: f"{t} = {idx}; _SA[{t} >> 3] = (_SA[{t} >> 3] | "
                                   f"(1 << ({t} & 7))) if {v} else (_SA[{t} >> 3] & "
                                   f"(255 ^ (1 << ({t} & 7))))")
        array = {"SAB": "_SA", "SK": "_SK", "SYVAR": "_SY"}[key]
        t_img = "INT" if key == "SYVAR" else "BYTE"
        code = f"{array}[{i.const}]" if i.const is not None else \
            f"{array}[_ix({i.code}, 0, {size})]"
        return Place(code, t_img, lambda v: f"{code} = {v}")

    def _nc(self, var: n.Var, write: bool) -> Place:
        c = self.c
        sels = var.selectors
        first = sels[0] if sels else None
        if not isinstance(first, n.Field):
            raise c.error(StCode.UNKNOWN_MEMBER, "NC has P[k], EVENTS, LAST_SND, START, HOLD, "
                          "RESET and SEND", var.span)
        name = first.name.upper()
        if name in NC_OUTPUTS and len(sels) == 1:
            slot = NC_OUTPUTS[name]
            code, at = f"_NCO[{slot}]", nc_where(var.span)
            # The output's value, and where the logic set it: the command it gives is
            # attributed "plc FILE:LINE".
            return Place(code, "BOOL", lambda v: f"{code} = {v}; _NCW[{slot}] = {at!r}")
        if name == "FEED_OVERRIDE" and len(sels) == 1:
            at = nc_where(var.span)
            return Place("_NCV[0]", "INT", lambda v: f"_NCV[0] = {v}; _NCVW[0] = {at!r}")
        place: Place | None = None
        if name == "EVENTS" and len(sels) == 1:
            place = Place("_NCE", "UDINT", None, "NC.EVENTS is an input")
        elif name == "LAST_SND" and len(sels) == 2 and isinstance(sels[1], n.Field):
            found = NC_LAST_SND.get(sels[1].name.upper())
            if found is None:
                raise c.error(StCode.UNKNOWN_MEMBER, f"NC.LAST_SND has no {sels[1].name}"
                              + did_you_mean(sels[1].name, NC_LAST_SND), sels[1].span)
            place = Place(f"_NCL[{found[0]}]", found[1], None, "NC.LAST_SND is an input")
        elif name == "P" and len(sels) == 3 and isinstance(sels[1], n.Index) and isinstance(
                sels[2], n.Field):
            i = c.expr(sels[1].expr, self)
            if not is_int(i.type):
                raise c.error(StCode.TYPE_MISMATCH, "a process number is an integer",
                              sels[1].span)
            count = c.ctx.processes
            if i.const is not None and not 1 <= i.const <= count:
                raise c.error(StCode.INDEX_RANGE, f"process {i.const} is not configured "
                              f"(1..{count})", sels[1].span)
            k = str(i.const - 1) if i.const is not None else f"_ix({i.code}, 1, {count})"
            out_name = sels[2].name.upper()
            if out_name in NC_PROCESS_OUTPUTS:
                slot = NC_PROCESS_OUTPUTS[out_name]
                code, at = f"_NCP[{k}][{slot}]", nc_where(var.span)
                return Place(code, "BOOL",
                             lambda v: f"{code} = {v}; _NCPW[{k}][{slot}] = {at!r}")
            if out_name in NC_VALUE_OUTPUTS:
                code, at = f"_NCPV[{k}]", nc_where(var.span)
                return Place(code, "INT", lambda v: f"{code} = {v}; _NCPVW[{k}] = {at!r}")
            member = NC_PROCESS.get(out_name)
            if member is None:
                raise c.error(StCode.UNKNOWN_MEMBER, f"NC.P[k] has no {sels[2].name}"
                              + did_you_mean(sels[2].name, [*NC_PROCESS, *NC_PROCESS_OUTPUTS,
                                                            *NC_VALUE_OUTPUTS]),
                              sels[2].span)
            place = Place(f"_NCS[{k}][{member[0]}]", member[1], None,
                          f"NC.P[k].{sels[2].name.upper()} is an input")
        if place is None:
            raise c.error(StCode.UNKNOWN_MEMBER, f"{_show(var)}: NC has P[k].STATE/N/LINE/"
                          "WAITING/ALARM/ALARM_CODE/IDLE/HELD/START/HOLD/RESET/"
                          "FEED_OVERRIDE/M/MSTROBE/MACK (S, T, H likewise), EVENTS, "
                          "LAST_SND.SENDER/TARGET/SEQ, START, HOLD, "
                          "RESET, OPT_STOP, BLOCK_SKIP, HOLD_LEVEL, FEED_OVERRIDE and "
                          "SEND(sender, target)"
                          + did_you_mean(name, ["P", "EVENTS", "LAST_SND", *NC_OUTPUTS,
                                                *NC_VALUE_OUTPUTS]),
                          first.span)
        if write:
            raise c.error(StCode.READ_ONLY, f"cannot write {_show(var)}: "
                          f"{place.why_read_only}", var.span)
        c.reads_nc = True
        return place


def _fold(op: str, a: Any, b: Any, real: bool) -> Any:
    if op == "+":
        return a + b
    if op == "-":
        return a - b
    if op == "*":
        return a * b
    if op == "/":
        return a / b if real else _idiv(a, b)
    return _mod(a, b)


def _one_char(e: E, t: Type) -> E | None:
    """A STRING (WSTRING) literal of one character where a CHAR (WCHAR) is due: that
    character (6.3.3: 'A' is a character literal too)."""
    if t in CHARS and isinstance(e.type, StringOf) and e.type.wide == (t == "WCHAR") and \
            isinstance(e.const, str) and len(e.const) == 1:
        return E(repr(e.const), t, e.const)
    return None


def _exact(values: Sequence[E]) -> bool:
    return all(v.exact for v in values)


def _bound_store(store: Callable[[str], str], coerced: str) -> Callable[[str], str]:
    """The statement storing a FUNCTION's output (``_VALUE_`` in ``coerced``) where the
    call bound it."""
    return lambda value: store(coerced.replace("_VALUE_", value))


def _symbol_clash(symbol: VarInfo) -> str:
    assert symbol.image is not None
    return (f"also the I/O name {symbol.display} of the config's [symbols] (rename one: the "
            "logic reads the I/O name as its image variable)")


def _bit_store(word: str, bit: int, t: str) -> Callable[[str], str]:
    """The statement setting one bit of an integer place (wrapped: bit 15 of an INT)."""
    mask = 1 << bit
    return lambda v: f"{word} = " + wrap_code(
        f"({word} | {mask}) if {v} else ({word} & {~mask})", t)


def _conversion(key: str) -> tuple[str, str] | None:
    if "_TO_" not in key:
        return None
    src, _, dst = key.partition("_TO_")
    src, dst = DATE_NAMES.get(src, src), DATE_NAMES.get(dst, dst)
    known = (*ELEMENTARY, "STRING", "WSTRING")
    if src in known and dst in known and src != dst:
        return src, dst
    return None


def _en_eno(args: Sequence[n.Arg], declared: Mapping[str, Any]
            ) -> tuple[n.Arg | None, n.Arg | None]:
    """A call's EN input and ENO output (IEC 61131-3, 6.6.1.6), unless the POU declares a
    variable of that name itself."""
    en = eno = None
    for arg in args:
        key = (arg.name or "").upper()
        if key == "EN" and "EN" not in declared:
            en = arg
        elif key == "ENO" and "ENO" not in declared:
            eno = arg
    return en, eno


def _holds_fb(t: Type) -> bool:
    while isinstance(t, ArrayOf):
        t = t.element
    return isinstance(t, FbOf)


def _span_of(x: Any) -> n.Span:
    span: n.Span = x.span
    return span


def _show(var: n.Var) -> str:
    text = var.name
    for sel in var.selectors:
        text += f".{sel.name}" if isinstance(sel, n.Field) else f".{sel.bit}" if isinstance(
            sel, n.Bit) else "[…]"
    return text


def _tname(t: Type) -> str:
    return {ANY_INT: "integer literal", ANY_REAL: "real literal"}.get(str(t), str(t))


def _calls(body: Iterable[n.Stmt]) -> set[str]:
    """Every function called in a body (for the recursion check)."""
    found: set[str] = set()
    stack: list[Any] = [tuple(body)]  # no recursion: a tree may be 10,000 deep
    while stack:
        x = stack.pop()
        if isinstance(x, n.Call):
            found.add(x.name.upper())
        if isinstance(x, tuple | list):
            stack.extend(x)
        elif hasattr(x, "__dataclass_fields__") and not isinstance(x, n.Span):
            stack.extend(getattr(x, name) for name in x.__dataclass_fields__)
    return found


# ---- the entry point (the compiled Logic: ncgate.plc.st.logic) -----------------------------


@contextmanager
def _room_to_recurse(frames: int) -> Iterator[None]:
    """The checker recurses along the nesting of statements (MAX_NESTING) and expressions
    (MAX_EXPR_DEPTH), a few frames a level: more than Python's default 1,000.  Python
    calls do not use the C stack in 3.11, so a higher limit is safe."""
    old = sys.getrecursionlimit()
    sys.setrecursionlimit(max(old, frames))
    try:
        yield
    finally:
        sys.setrecursionlimit(old)


# The last compilations, by the identity of their (immutable) parsed files and the context:
# a suite of scenarios or a sweep compiles the same parse again and again (ncgate.gateway.plc
# keeps the parse of a path and text), and its compilation was a fifth of a scenario's run.
# Each entry keeps its files alive, so an identity is never another file's -- and so only
# small logic is kept (a generated module up to KEPT_SOURCE_MAX characters): a big one's
# syntax tree, kept, would be walked by every collection of the cyclic collector (the
# reason Logic keeps none of it, docs/decisions.md).  A Logic is built afresh from an entry
# every time: what it holds that changes (the namespace, the variables' tables) is its own.
_COMPILED: dict[tuple[tuple[int, ...], Context],
                tuple[tuple[n.SourceFile, ...], Compiler, str, list[n.Span | None]]] = {}


def compile_logic(files: Sequence[n.SourceFile], context: Context | None = None) -> Logic:
    """Check and compile; raises :class:`LogicError` with every diagnostic found."""
    context = context or Context()
    key = (tuple(map(id, files)), context)
    kept = _COMPILED.get(key)
    if kept is not None and all(a is b for a, b in zip(kept[0], files, strict=True)):
        _, compiler, source, spans = kept
    else:
        compiler = Compiler(files, context)
        with _room_to_recurse(10 * MAX_NESTING + 10 * MAX_EXPR_DEPTH + 2000):
            source, spans = compiler.compile()
        if compiler.diagnostics:
            raise LogicError(sorted(compiler.diagnostics,
                                    key=lambda d: (d.span.file, d.span.line, d.span.column)))
        if len(source) <= KEPT_SOURCE_MAX:
            if len(_COMPILED) >= COMPILED_KEPT:
                del _COMPILED[next(iter(_COMPILED))]
            _COMPILED[key] = (tuple(files), compiler, source, spans)
    try:
        return Logic(files, compiler, source, spans)
    except (SyntaxError, RecursionError, MemoryError) as exc:
        # A limit of Python's compiler the generated code was not kept inside: never a
        # traceback, the statement it came from.
        line = exc.lineno if isinstance(exc, SyntaxError) and exc.lineno else len(spans)
        span = next((s for s in reversed(spans[:line]) if s is not None), None) or (
            files[0].pous[0].span if files and files[0].pous else n.Span("?", 1, 1))
        raise LogicError([StDiagnostic(StCode.UNSUPPORTED, "a statement too large or too "
                                       "deeply nested to compile: split it", span,
                                       compiler._source(span))]) from None
