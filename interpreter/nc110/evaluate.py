"""Expressions compiled to Python functions (spec 1.4).

An expression becomes ``fn(E, read) -> float``: ``E`` is the process's E-parameter list,
``read(area, index, view)`` reads the image.  Compiling once per block keeps the decoder's
arithmetic loop fast.  Functions take and give degrees.  Runtime errors (division by zero,
square root of a negative number) raise :class:`RuntimeAlarm`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import RuntimeAlarm
from ncgate.interpreter.nc110.nodes import Binary, Call, Expr, Num, Unary, VarKind, VarRef

Reader = Callable[[str, int, str], int]
Evaluator = Callable[[list[float], Reader], float]


def _div(a: float, b: float) -> float:
    if b == 0:
        raise RuntimeAlarm(AlarmCode.DIVISION_BY_ZERO, "division by zero")
    return a / b


def _sqr(a: float) -> float:
    if a < 0:
        raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"SQR of a negative number ({a:g})")
    return math.sqrt(a)


def _int(a: float) -> float:
    return float(math.trunc(a))


_FUNCS: dict[str, Callable[[float], float]] = {
    "SIN": lambda a: math.sin(math.radians(a)),
    "COS": lambda a: math.cos(math.radians(a)),
    "TAN": lambda a: math.tan(math.radians(a)),
    "ATN": lambda a: math.degrees(math.atan(a)),
    "SQR": _sqr,
    "ABS": abs,
    "INT": _int,
}


def _source(expr: Expr) -> str:
    if isinstance(expr, Num):
        return repr(expr.value)
    if isinstance(expr, VarRef):
        if expr.kind is VarKind.E:
            return f"E[{expr.index}]"
        return f"read({expr.kind.value!r}, {expr.index}, {expr.view.value!r})"
    if isinstance(expr, Unary):
        return f"(-{_source(expr.operand)})" if expr.op == "-" else _source(expr.operand)
    if isinstance(expr, Binary):
        left, right = _source(expr.left), _source(expr.right)
        if expr.op == "/":
            return f"_div({left}, {right})"
        return f"({left} {expr.op} {right})"
    assert isinstance(expr, Call)
    return f"_f_{expr.func}({_source(expr.arg)})"


_NAMESPACE: dict[str, Any] = {"_div": _div, **{f"_f_{k}": v for k, v in _FUNCS.items()}}


def _not_finite(value: float) -> float:
    what = "not a number" if value != value else "too large (overflow)"
    raise RuntimeAlarm(AlarmCode.VALUE_OUT_OF_RANGE, f"the value of an expression is {what}")


_NAMESPACE["_not_finite"] = _not_finite


def compile_expr(expr: Expr) -> Evaluator:
    """The expression as a function; it never returns inf or NaN (``v - v`` is 0 only for a
    finite v): overflow is an alarm at the block that computed it."""
    if isinstance(expr, Num):
        value = expr.value
        return lambda E, read: value
    fn: Evaluator = eval(f"lambda E, read: v if (v := {_source(expr)}) - v == 0 "
                         "else _not_finite(v)", dict(_NAMESPACE))
    return fn


def reads_image(expr: Expr) -> bool:
    """Whether evaluating the expression reads SA, SK or SYVAR."""
    if isinstance(expr, VarRef):
        return expr.kind is not VarKind.E
    if isinstance(expr, Unary):
        return reads_image(expr.operand)
    if isinstance(expr, Binary):
        return reads_image(expr.left) or reads_image(expr.right)
    if isinstance(expr, Call):
        return reads_image(expr.arg)
    return False


def syvars_read(expr: Expr) -> Iterator[int]:
    """The SYVAR indexes an expression reads."""
    if isinstance(expr, VarRef):
        if expr.kind is VarKind.SYVAR:
            yield expr.index
    elif isinstance(expr, Unary):
        yield from syvars_read(expr.operand)
    elif isinstance(expr, Binary):
        yield from syvars_read(expr.left)
        yield from syvars_read(expr.right)
    elif isinstance(expr, Call):
        yield from syvars_read(expr.arg)


def round_half_away(value: float) -> int:
    """Spec 1.3: a non-integer stored in an integer variable rounds half away from zero."""
    return math.floor(abs(value) + 0.5) * (1 if value >= 0 else -1)
