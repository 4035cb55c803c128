"""The types of ncgate's Structured Text and the rules between them.

Elementary types are their IEC names (``"INT"``); an untyped integer or real literal has the
pseudo-type ``ANY_INT`` / ``ANY_REAL`` until the place it goes to gives it one.  Implicit
conversions are the widening ones of IEC 61131-3 (3rd ed., 6.4.2, Figure 11): a signed
integer to a wider signed one, an unsigned or bit string to a wider (or, for unsigned, a
same-width bit string) one, any integer to REAL/LREAL (ncgate, like CODESYS, also accepts
DINT -> REAL), REAL -> LREAL.  Narrowing needs a conversion function (``DINT_TO_INT``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ncgate.plc.st.stdlib import INTEGER_TYPES, limits

SIGNED = ("SINT", "INT", "DINT", "LINT")
UNSIGNED = ("USINT", "UINT", "UDINT", "ULINT")
BITS = ("BYTE", "WORD", "DWORD", "LWORD")
REALS = ("REAL", "LREAL")
INTS = (*SIGNED, *UNSIGNED, *BITS)
DURATIONS = ("TIME", "LTIME")  # TIME: 32-bit ms; LTIME: 64-bit ns
DATES = ("DATE", "TOD", "DT")  # DATE, DT: 32-bit s since 1970; TOD: ms since midnight
# One character (3rd ed., Table 10: 17a, 17b), a Python str of length 1: CHAR of a STRING
# (Latin-1), WCHAR of a WSTRING.
CHARS = ("CHAR", "WCHAR")
ELEMENTARY = ("BOOL", *INTS, *REALS, *DURATIONS, *DATES, *CHARS)
# The long names of the date types (6.4.2, Table 10) and what ncgate calls them.
DATE_NAMES = {"TIME_OF_DAY": "TOD", "DATE_AND_TIME": "DT"}
ANY_INT, ANY_REAL = "ANY_INT", "ANY_REAL"
STRING_DEFAULT = 80  # a STRING's length when none is declared (CODESYS, TwinCAT, Beremiz)
__all__ = ["limits"]  # re-exported: the type's range, as stdlib defines it for wrap()


class Ranged(str):
    """A subrange type (``INT(0..100)``, 6.4.4.4): the name of its base type -- so every
    rule of the base applies -- with its limits, checked where a value is stored."""

    lo: int
    hi: int

    def __new__(cls, base: str, lo: int, hi: int) -> Ranged:
        self = super().__new__(cls, base)
        self.lo, self.hi = lo, hi
        return self


@dataclass(frozen=True, slots=True)
class StringOf:
    """STRING[length] (one byte a character) or WSTRING[length] (UTF-16 units)."""

    length: int
    wide: bool = False

    def __str__(self) -> str:
        return f"{'WSTRING' if self.wide else 'STRING'}[{self.length}]"


@dataclass(frozen=True, slots=True)
class StructOf:
    """A structure type (TYPE … STRUCT); its members are the compiler's ``structs[name]``."""

    name: str

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True, slots=True)
class EnumOf:
    """An enumeration type; its values are integers (the compiler's ``enums[name]``).
    ``names``: each value's name as written, by its integer, on the type a declaration
    resolves to (not part of its identity), so that whoever shows a variable's value --
    the console's status -- shows ``RUN``, not ``5``."""

    name: str
    names: tuple[tuple[int, str], ...] = field(default=(), compare=False, repr=False)

    def __str__(self) -> str:
        return self.name

    def name_of(self, value: int) -> str | int:
        """The value's name (the first, when two names share it), or the integer itself
        when it is none of the type's (a CODESYS-lenient assignment stored it)."""
        return next((name for number, name in self.names if number == value), value)


@dataclass(frozen=True, slots=True)
class ArrayOf:
    lo: int
    hi: int
    element: Type

    @property
    def length(self) -> int:
        return self.hi - self.lo + 1

    def __str__(self) -> str:
        return f"ARRAY[{self.lo}..{self.hi}] OF {self.element}"


@dataclass(frozen=True, slots=True)
class AnyLength:
    """``ARRAY[*] OF element`` (IEC 61131-3, 6.5.3): a VAR_IN_OUT that takes an array of
    any bounds; LOWER_BOUND and UPPER_BOUND give them."""

    element: Type

    def __str__(self) -> str:
        return f"ARRAY[*] OF {self.element}"


@dataclass(frozen=True, slots=True)
class FbOf:
    """An instance of a function block (``std``: one of the standard ones)."""

    name: str
    std: bool

    def __str__(self) -> str:
        return self.name


Type = str | ArrayOf | AnyLength | FbOf | StringOf | StructOf | EnumOf


def bits(t: str) -> int:
    return INTEGER_TYPES[t][0]


def is_int(t: Type) -> bool:
    return t in INTS or t == ANY_INT


def is_real(t: Type) -> bool:
    return t in REALS or t == ANY_REAL


def is_num(t: Type) -> bool:
    return is_int(t) or is_real(t)


def widens(src: Type, dst: Type) -> bool:
    """May a value of ``src`` be stored in ``dst`` without a conversion function?"""
    if src == dst:
        return True
    if isinstance(dst, StringOf) and src in CHARS:  # 6.4.2, Figure 11: CHAR -> STRING
        return (src == "WCHAR") == dst.wide
    if isinstance(src, StringOf) and isinstance(dst, StringOf):
        return src.wide == dst.wide  # a longer value is truncated where it is stored
    if not isinstance(src, str) or not isinstance(dst, str):
        return False
    if src == ANY_INT:
        return dst in INTS or dst in REALS
    if src == ANY_REAL:
        return dst in REALS
    if src in INTS and dst in REALS:
        return True
    if src == "REAL":
        return dst == "LREAL"
    if src in SIGNED:
        return dst in SIGNED and bits(src) <= bits(dst)
    if src in UNSIGNED:
        return ((dst in UNSIGNED or dst in BITS) and bits(src) <= bits(dst)) or (
            dst in SIGNED and bits(src) < bits(dst))
    if src in BITS:
        return (dst in BITS or dst in UNSIGNED) and bits(src) <= bits(dst)
    return False


def common(a: Type, b: Type) -> Type | None:
    """The type both operands of an arithmetic operator convert to, or None."""
    if a == b:
        return a
    if isinstance(a, StringOf) and isinstance(b, StringOf):
        return StringOf(max(a.length, b.length), a.wide) if a.wide == b.wide else None
    if (a == ANY_REAL and is_int(b)) or (b == ANY_REAL and is_int(a)):
        return "REAL" if ANY_INT not in (a, b) else ANY_REAL
    if widens(a, b):
        return b
    if widens(b, a):
        return a
    return None


def default_value(t: Type) -> object:
    """The initial value of a variable declared without one (IEC 6.4.2, Table 10: 0, FALSE,
    0.0, T#0s, D#1970-01-01, '', '$00', a subrange's lower limit)."""
    if t == "BOOL":
        return False
    if t in CHARS:
        return "\0"
    if t in REALS:
        return 0.0
    if isinstance(t, ArrayOf):
        return [default_value(t.element) for _ in range(t.length)]
    if isinstance(t, StringOf):
        return ""
    if isinstance(t, Ranged):
        return t.lo if t.lo > 0 or t.hi < 0 else 0
    return 0
