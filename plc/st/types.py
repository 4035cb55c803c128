"""The types of ncgate's Structured Text and the rules between them.

Elementary types are their IEC names (``"INT"``); an untyped integer or real literal has the
pseudo-type ``ANY_INT`` / ``ANY_REAL`` until the place it goes to gives it one.  Implicit
conversions are the widening ones of IEC 61131-3 (3rd ed., 6.4.2, Figure 11): a signed
integer to a wider signed one, an unsigned or bit string to a wider (or, for unsigned, a
same-width bit string) one, any integer to REAL/LREAL (ncgate, like CODESYS, also accepts
DINT -> REAL), REAL -> LREAL.  Narrowing needs a conversion function (``DINT_TO_INT``).
"""

from __future__ import annotations

from dataclasses import dataclass

from ncgate.plc.st.stdlib import INTEGER_TYPES, limits

SIGNED = ("SINT", "INT", "DINT")
UNSIGNED = ("USINT", "UINT", "UDINT")
BITS = ("BYTE", "WORD", "DWORD")
REALS = ("REAL", "LREAL")
INTS = (*SIGNED, *UNSIGNED, *BITS)
ELEMENTARY = ("BOOL", *INTS, *REALS, "TIME")
ANY_INT, ANY_REAL = "ANY_INT", "ANY_REAL"
__all__ = ["limits"]  # re-exported: the type's range, as stdlib defines it for wrap()


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
class FbOf:
    """An instance of a function block (``std``: one of the standard ones)."""

    name: str
    std: bool

    def __str__(self) -> str:
        return self.name


Type = str | ArrayOf | FbOf


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
    if (a == ANY_REAL and is_int(b)) or (b == ANY_REAL and is_int(a)):
        return "REAL" if ANY_INT not in (a, b) else ANY_REAL
    if widens(a, b):
        return b
    if widens(b, a):
        return a
    return None


def default_value(t: Type) -> object:
    """The initial value of a variable declared without one (IEC: 0, FALSE, 0.0, T#0s)."""
    if t == "BOOL":
        return False
    if t in REALS:
        return 0.0
    if isinstance(t, ArrayOf):
        return [default_value(t.element) for _ in range(t.length)]
    return 0
