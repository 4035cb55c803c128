"""What the compiler knows of the declarations before it compiles a body: each variable
(:class:`VarInfo`), each POU's interface (:class:`PouInfo`), each structure and enumeration
type, and the shape helpers that turn a flat initializer into an array's nested lists."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ncgate.plc.st import nodes as n
from ncgate.plc.st.types import (
    AnyLength,
    ArrayOf,
    StructOf,
    Type,
)


@dataclass
class VarInfo:
    display: str
    type: Type
    section: str
    qualifier: str | None
    span: n.Span
    initial: Any = None
    image: tuple[str, int] | None = None  # an I/O name of [symbols]: its image variable


@dataclass
class PouInfo:
    pou: n.Pou
    file: n.SourceFile
    vars: dict[str, VarInfo] = field(default_factory=dict)
    result: Type | None = None
    externals: set[str] = field(default_factory=set)  # VAR_EXTERNAL: globals it names

    @property
    def inputs(self) -> list[tuple[str, VarInfo]]:
        """A FUNCTION's parameters in order: VAR_INPUT and VAR_IN_OUT."""
        return [(k, v) for k, v in self.vars.items()
                if v.section in ("VAR_INPUT", "VAR_IN_OUT")]

    @property
    def in_outs(self) -> list[str]:
        return [k for k, v in self.vars.items() if v.section == "VAR_IN_OUT"]

    @property
    def copied_in_outs(self) -> list[str]:
        """The VAR_IN_OUTs a FUNCTION hands back for the caller to store (an array or a
        structure is the caller's own object, written in place)."""
        return [k for k in self.in_outs
                if not isinstance(self.vars[k].type, ArrayOf | AnyLength | StructOf)]

    @property
    def returned(self) -> list[str]:
        """What a FUNCTION returns beside its result, in this order: the copied in-outs,
        then its VAR_OUTPUTs (6.6.2.2: a FUNCTION may have outputs, bound with =>)."""
        return [*self.copied_in_outs,
                *(k for k, v in self.vars.items() if v.section == "VAR_OUTPUT")]

    @property
    def names(self) -> list[str]:
        """The Python names of its variables: v_X, and v_X__LO, the lower bound an
        ARRAY[*] VAR_IN_OUT was given with."""
        return [name for k, v in self.vars.items()
                for name in ([f"v_{k}", f"v_{k}__LO"] if isinstance(v.type, AnyLength)
                             else [f"v_{k}"])]


@dataclass
class StructInfo:
    decl: n.TypeDecl
    fields: dict[str, VarInfo]


@dataclass
class EnumInfo:
    display: str
    values: dict[str, int]  # value name (upper case) -> its integer
    names: dict[str, str]  # value name (upper case) -> as written
    default: int

    def name_of(self, value: int) -> str:
        return next((self.names[k] for k, v in self.values.items() if v == value), str(value))


def _leaf(t: Type) -> Type:
    while isinstance(t, ArrayOf):
        t = t.element
    return t


def _leaf_count(t: Type) -> int:
    count = 1
    while isinstance(t, ArrayOf):
        count *= t.length
        t = t.element
    return count


def _reshape(flat: list[Any], t: ArrayOf) -> list[Any]:
    """A flat list of initial values (row by row) as the nested lists of an array of arrays."""
    if not isinstance(t.element, ArrayOf):
        return flat
    size = _leaf_count(t.element)
    return [_reshape(flat[i * size:(i + 1) * size], t.element) for i in range(t.length)]
