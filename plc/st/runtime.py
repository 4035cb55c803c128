"""What the generated code of the Structured Text compiler calls at run time: the helpers
(integer division and modulo as IEC has them, REAL's single precision, index and range checks,
the string functions, time arithmetic), the table of them every compiled module gets
(:data:`HELPERS`), and the faults a scan raises (:class:`PlcFault`, :class:`IterationGuard`).

Nothing here knows the syntax or the compiler: a second IEC language compiled to Python would
call the same helpers (ARCHITECTURE.md, "Where a new PLC language goes")."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import Any

from ncgate.plc.image import PlcError
from ncgate.plc.st import nodes as n
from ncgate.plc.st import stdlib

TOD_MS = 86_400_000


class PlcFault(PlcError, RuntimeError):
    """A runtime error of the logic: the PLC goes to FAULT.  ``span`` is the statement."""

    def __init__(self, message: str, span: n.Span | None, source_line: str = "") -> None:
        where = f"{span}: " if span is not None else ""
        super().__init__(f"{where}{message}")
        self.message = message
        self.span = span
        self.source_line = source_line


class IterationGuard(RuntimeError):
    """Raised inside the generated code when a scan's loop iterations run out."""


def _ix(i: int, lo: int, length: int) -> int:
    j = i - lo
    if 0 <= j < length:
        return j
    raise IndexError(f"index {i} outside {lo}..{lo + length - 1}")


def _mod(a: int, b: int) -> int:
    if b == 0:
        raise ZeroDivisionError("MOD by zero")
    return a - b * int(a / b) if abs(a) < 1 << 52 else int(math.fmod(a, b))


def _idiv(a: int, b: int) -> int:
    if b == 0:
        raise ZeroDivisionError("division by zero")
    q = abs(a) // abs(b)
    return q if (a < 0) == (b < 0) else -q


def _fdiv(a: float, b: float) -> float:
    if b == 0:
        raise ZeroDivisionError("division by zero")
    return a / b


_SINGLE = struct.Struct("<f")


def _f32(value: float) -> float:
    """A REAL result: rounded to IEEE 754 single precision, to nearest, ties to even (the
    double result of one +, -, *, / or SQRT rounded once is the single one: 53 >= 2*24+2).
    Beyond single's range it is an error, as IEC 61131-3 says of a result outside its type
    (an infinity would spread silently through a machine's logic)."""
    try:
        return _SINGLE.unpack(_SINGLE.pack(value))[0]  # type: ignore[no-any-return]
    except OverflowError:
        raise OverflowError(f"{float(value):g} is outside REAL's range (IEEE single, "
                            "+-3.4E38)") from None


to_real = _f32  # the value a REAL holds (RETAIN rounds what it restores with it)


# struct's words for a REAL result beyond single's range, which the scan rewords.
REAL_OVERFLOW = "float too large to pack with f format"


REAL_OVERFLOW_MESSAGE = "a REAL result outside REAL's range (IEEE single, +-3.4E38)"


def _f64(value: float) -> float:
    """An LREAL result: already IEEE double; an overflow to infinity is an error."""
    if math.isinf(value) or math.isnan(value):
        raise OverflowError("the result is outside LREAL's range (IEEE double, +-1.8E308)")
    return value


def _pow(a: float, b: float) -> float:
    try:
        result = float(a) ** b
    except ZeroDivisionError:
        raise ValueError(f"EXPT: {float(a):g} to the negative power {float(b):g} has no "
                         "value") from None
    except OverflowError:
        raise OverflowError(f"EXPT: {float(a):g} to the power {float(b):g} is outside the "
                            "range of its type") from None
    if isinstance(result, complex):
        raise ValueError(f"EXPT: {float(a):g} to the power {float(b):g} has no real value")
    return float(result)


def _sqrt(a: float) -> float:
    if a < 0:
        raise ValueError(f"SQRT of {a}")
    return math.sqrt(a)


def _r2i(value: float, lo: int, hi: int, type_name: str) -> int:
    """REAL -> integer: rounded half to even (IEC 61131-3, 6.6.2.5.6); a value outside the
    integer type is an error (a conversion error of IEC's), not a wrap."""
    if math.isnan(value) or math.isinf(value):
        raise ValueError(f"{value} has no integer value")
    v = round(value)
    if not lo <= v <= hi:
        raise OverflowError(f"{value:g} does not fit in {type_name} ({lo}..{hi})")
    return v


def _trunc(value: float) -> int:
    if math.isnan(value) or math.isinf(value):
        raise ValueError(f"{value} has no integer value")
    v = int(value)
    if not -(1 << 31) <= v < 1 << 31:
        raise OverflowError(f"TRUNC({value:g}) does not fit in DINT")
    return v


def _math(name: str, function: Callable[[float], float]) -> Callable[[float], float]:
    """EXP, LN, ... of IEC 61131-3 (Table 23): outside the function's domain, or beyond the
    range of a double, the logic faults and says which."""
    def call(x: float) -> float:
        try:
            return function(x)
        except (ValueError, OverflowError):
            raise ValueError(f"{name}({float(x):g}) has no value in LREAL") from None
    return call


_MATH = {"EXP": math.exp, "LN": math.log, "LOG": math.log10, "SIN": math.sin,
         "COS": math.cos, "TAN": math.tan, "ASIN": math.asin, "ACOS": math.acos,
         "ATAN": math.atan}


def _mux(k: int, values: tuple[Any, ...]) -> Any:
    if 0 <= k < len(values):
        return values[k]
    raise IndexError(f"MUX selector {k} outside 0..{len(values) - 1}")


def _guard() -> None:
    raise IterationGuard("the loop iteration guard ran out")


def _length(name: str, value: int) -> int:
    if value < 0:
        raise ValueError(f"{name}: L = {value} is negative")
    return value


def _position_of(name: str, value: int, first: int = 1) -> int:
    if value < first:
        raise ValueError(f"{name}: P = {value}; positions start at {first}")
    return value


def _left(s: str, n: int) -> str:
    return s[:_length("LEFT", n)]


def _right(s: str, n: int) -> str:
    n = _length("RIGHT", n)
    return s[len(s) - n:] if n < len(s) else s


def _midstr(s: str, n: int, p: int) -> str:
    start = _position_of("MID", p) - 1
    return s[start:start + _length("MID", n)]


def _insert(a: str, b: str, p: int) -> str:
    p = _position_of("INSERT", p, 0)
    return a[:p] + b + a[p:]


def _delete(s: str, n: int, p: int) -> str:
    start = _position_of("DELETE", p) - 1
    return s[:start] + s[start + _length("DELETE", n):]


def _replace(a: str, b: str, n: int, p: int) -> str:
    start = _position_of("REPLACE", p) - 1
    return a[:start] + b + a[start + _length("REPLACE", n):]


def _find(a: str, b: str) -> int:
    return a.find(b) + 1 if b else 0


def _char_at(s: str, i: int) -> str:
    """``s[i]``: the i-th character, counted from 1 (a CHAR or WCHAR)."""
    if 1 <= i <= len(s):
        return s[i - 1]
    raise IndexError(f"character {i} of a string of {len(s)} (1..{len(s)})")


def _set_char(s: str, i: int, c: str, length: int) -> str:
    """``s[i] := c``: the string with its i-th character replaced; at LEN(s) + 1 (within the
    declared length) the character is added (docs/decisions.md)."""
    if 1 <= i <= len(s):
        return f"{s[:i - 1]}{c}{s[i:]}"
    if i == len(s) + 1 <= length:
        return s + c
    raise IndexError(f"character {i} of a string of {len(s)} (1..{min(len(s) + 1, length)})")


def _code_char(code: int, t: str) -> str:
    """The CHAR (WCHAR) of a code, cut to 8 (16) bits as a BYTE (WORD) is."""
    return chr(code & (255 if t == "CHAR" else 65535))


def _ranged(value: int, lo: int, hi: int) -> int:
    """A value stored in a subrange variable: outside its limits it is an error
    (IEC 61131-3, 6.4.4.4)."""
    if lo <= value <= hi:
        return value
    raise ValueError(f"{value} is outside the subrange {lo}..{hi}")


def _fill(obj: Any, value: Any) -> None:
    """A structure VAR_IN_OUT assigned whole: the caller's structure takes the members."""
    for name in type(obj).__slots__:
        setattr(obj, name, getattr(value, name))


def _struct(obj: Any, values: dict[str, Any]) -> Any:
    """A structure instance with the members of its declared initial value."""
    for name, value in values.items():
        setattr(obj, name, value)
    return obj


def _time_real(ms: int, factor: float, divide: bool) -> int:
    """TIME * or / a number (IEC 61131-3, Table 30): rounded to the nearest unit, half to
    even, as a REAL converts to an integer (6.6.2.5.6)."""
    if divide:
        if factor == 0:
            raise ZeroDivisionError("division by zero")
        value = ms / factor
    else:
        value = ms * factor
    if math.isnan(value) or math.isinf(value):
        raise OverflowError("a TIME result beyond any range")
    return round(value)


def _tostr(value: Any, t: str) -> str:
    """X_TO_STRING: the literal's text without its type prefix, as CODESYS writes it."""
    if t == "BOOL":
        return "TRUE" if value else "FALSE"
    if t in ("REAL", "LREAL"):
        return repr(float(value)).upper().replace("E+", "E")
    return str(value)


def _strto(text: str, t: str) -> Any:
    """STRING_TO_X: the number in the text (leading and trailing blanks ignored)."""
    text = text.strip()
    try:
        if t == "BOOL":
            return text.upper() in ("TRUE", "1")
        if t in ("REAL", "LREAL"):
            return float(text.replace("_", ""))
        return int(text.replace("_", ""), 0) if text[:2].lower() in ("0x", "0b") else \
            int(text.replace("_", ""))
    except ValueError:
        raise ValueError(f"STRING_TO_{t}: {text!r} is not a number") from None


HELPERS: dict[str, Any] = {
    "_ix": _ix, "_mod": _mod, "_idiv": _idiv, "_fdiv": _fdiv, "_pow": _pow, "_sqrt": _sqrt,
    "_r2i": _r2i, "_trunc": _trunc, "_mux": _mux, "_guard": _guard, "_f32": _f32,
    "_f64": _f64, "_F32P": _SINGLE.pack, "_F32U": _SINGLE.unpack,
    **{f"_{name}": _math(name, f) for name, f in _MATH.items()},
    "_shl": stdlib.SHL, "_shr": stdlib.SHR, "_rol": stdlib.ROL, "_ror": stdlib.ROR,
    "_left": _left, "_right": _right, "_midstr": _midstr, "_insert": _insert,
    "_delete": _delete, "_replace": _replace, "_find": _find, "_ranged": _ranged,
    "_struct": _struct, "_fill": _fill, "_time_real": _time_real, "_tostr": _tostr,
    "_strto": _strto, "_char_at": _char_at, "_set_char": _set_char,
    "_code_char": _code_char,
    **{f"_STD_{name}": cls for name, cls in stdlib.FUNCTION_BLOCKS.items()},
}
