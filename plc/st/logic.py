"""Compiled logic (:class:`Logic`): the generated module exec'd into a namespace of its own,
its programs' and function blocks' variables (:class:`ProgramVar`), the way back from a
Python line to the ST statement (for faults), and RETAIN's dump and load of aggregates.

The module's code is compiled a piece at a time (a waiting thread gets the interpreter in
between) and kept for small logic, so a suite of scenarios does not compile it again."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import threading
import time
import types as pytypes
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from ncgate.plc.st import nodes as n
from ncgate.plc.st import stdlib
from ncgate.plc.st.intrinsics import NC_OUTPUTS, NC_PROCESS_OUTPUTS
from ncgate.plc.st.runtime import HELPERS, TOD_MS, to_real
from ncgate.plc.st.types import (
    CHARS,
    REALS,
    AnyLength,
    ArrayOf,
    EnumOf,
    FbOf,
    Ranged,
    StringOf,
    StructOf,
    Type,
    limits,
)

if TYPE_CHECKING:
    from ncgate.plc.st.compiler import Compiler


# The module is compiled in pieces of whole top-level definitions of about PIECE_CHARS
# characters: Python's compile() holds the interpreter for the whole call (~0.35 us a
# character), and a reload compiles in a thread (the compiler's PIECE_LINES cuts long bodies).
PIECE_CHARS = 32_000
# Compilations kept for the next load of the same parse (compile_logic), and the largest
# generated module kept (bigger logic is compiled afresh: its syntax tree is not kept).
COMPILED_KEPT = 8
KEPT_SOURCE_MAX = 64 * 1024


@dataclass
class ProgramVar:
    key: str
    display: str
    type: Type
    retain: bool
    constant: bool = False  # VAR CONSTANT: an online change gives it its new value


class Logic:
    """Compiled logic: the generated module, its programs, and the way back from a Python
    line to the ST statement (for faults)."""

    def __init__(self, files: Sequence[n.SourceFile], compiler: Compiler, source: str,
                 spans: list[n.Span | None]) -> None:
        # What a fault's location needs, and nothing of the syntax tree: kept, its hundreds
        # of thousands of nodes (a 20,000-statement program: 460,000 objects) each stayed in
        # the cyclic collector's care -- a 130 ms young and a 340 ms full collection, on
        # whichever thread allocated next, after every reload.  Spans as tuples: those the
        # collector stops tracking once it has seen them.
        self.files = tuple(n.SourceFile(f.path, f.text, ()) for f in files)
        self.python_source = source
        self.reads_nc = compiler.reads_nc
        self.reads_et = compiler.reads_et
        self.image_keys = frozenset(compiler.image_keys)  # (see Compiler.image_keys)
        self.image_areas = frozenset(compiler.image_areas)
        # What of the image each POU writes and reads at a constant place -> where it first
        # does (file, line, column), and the areas it writes and reads at a place it
        # computes: Compiler.image_writes ... (see image_writes, image_reads, computed).
        self._writes = {pou: {key: (s.file, s.line, s.column) for key, s in found.items()}
                        for pou, found in compiler.image_writes.items()}
        self._reads = {pou: frozenset(found) for pou, found in compiler.image_reads.items()}
        self._computed = ({pou: frozenset(a) for pou, a in compiler.computed_reads.items()},
                          {pou: frozenset(a) for pou, a in compiler.computed_writes.items()})
        self.uses = {pou: frozenset(used) for pou, used in compiler.uses.items()}
        # plc.strict = false: what loaded only because CODESYS accepts it (SW codes)
        self.warnings = tuple(sorted(compiler.warnings, key=lambda d: (
            d.span.file, d.span.line, d.span.column)))
        self._spans = [None if s is None else (s.file, s.line, s.column) for s in spans]
        # One name for one generated module (its frames are told from others' by it): the
        # code of an identical module is compiled once (_compiled_pieces keeps it).
        self._filename = f"<ncgate-st {hashlib.sha1(source.encode()).hexdigest()[:12]}>"
        self.namespace: dict[str, Any] = dict(HELPERS)
        k = compiler.ctx.processes
        self.namespace.update(_NOW=0, _LEFT=0, _NCE=0, _NCL=(0, 0, 0), _NCS=[],
                              _NCO=[False] * len(NC_OUTPUTS), _NCW=[""] * len(NC_OUTPUTS),
                              _NCV=[100], _NCVW=[""],
                              _NCP=[[False] * len(NC_PROCESS_OUTPUTS) for _ in range(k)],
                              _NCPW=[[""] * len(NC_PROCESS_OUTPUTS) for _ in range(k)],
                              _NCPV=[100] * k, _NCPVW=[""] * k,
                              _NC_SEND=lambda s, t, w: None)
        for code in _compiled_pieces(source, self._filename):
            exec(code, self.namespace)
        self.programs: dict[str, dict[str, ProgramVar]] = {}
        self.display: dict[str, str] = {}
        self.fb_vars: dict[str, dict[str, ProgramVar]] = {}
        retains = compiler.retains
        for key, info in compiler.pous.items():
            table = {k: ProgramVar(k, v.display, v.type,
                                   v.qualifier == "RETAIN" or retains(v.type),
                                   v.qualifier == "CONSTANT")
                     for k, v in info.vars.items()}
            if info.pou.kind == "PROGRAM":
                self.programs[key] = table
                self.display[key] = info.pou.name
            elif info.pou.kind == "FUNCTION_BLOCK":
                self.fb_vars[key] = table
        self.struct_fields: dict[str, dict[str, ProgramVar]] = {
            key: {k: ProgramVar(k, v.display, v.type, False) for k, v in struct.fields.items()}
            for key, struct in compiler.structs.items()}
        self.globals: dict[str, ProgramVar] = {
            k: ProgramVar(k, v.display, v.type, v.qualifier == "RETAIN" or retains(v.type),
                          v.qualifier == "CONSTANT")
            for k, v in compiler.globals.items() if v.image is None}
        self.enums = dict(compiler.enums)


    def reached(self, programs: Iterable[str] | None = None) -> set[str]:
        """The POUs whose code runs: ``programs`` (PROGRAM names; None: every one), the
        function blocks they have instances of and the functions they call, and so on
        (a FUNCTION_BLOCK with no instance, a PROGRAM not run, is not reached)."""
        stack = [p.upper() for p in (self.programs if programs is None else programs)]
        reached = {""}  # (what is not inside a POU: the globals)
        while stack:
            pou = stack.pop()
            if pou not in reached:
                reached.add(pou)
                stack.extend(self.uses.get(pou, ()))
        return reached

    def image_writes(self, programs: Iterable[str] | None = None
                     ) -> dict[tuple[str, int], tuple[str, int, int]]:
        """What of the image the code ``programs`` reach writes at a constant place:
        ("SA", bit), ("SK", byte), ("SYVAR", n) -> where it first does (SW006)."""
        out: dict[tuple[str, int], tuple[str, int, int]] = {}
        for pou in self.reached(programs):
            for key, where in self._writes.get(pou, {}).items():
                if key not in out or where < out[key]:
                    out[key] = where
        return out

    def image_reads(self, programs: Iterable[str] | None = None) -> set[tuple[str, int]]:
        """Likewise, what it reads (ncgate map's plant logic)."""
        return {key for pou in self.reached(programs) for key in self._reads.get(pou, ())}

    def computed(self, programs: Iterable[str] | None = None) -> tuple[set[str], set[str]]:
        """The areas the code ``programs`` reach reads, and writes, at a place it computes."""
        reached = self.reached(programs)
        reads, writes = self._computed
        return ({a for pou in reached for a in reads.get(pou, ())},
                {a for pou in reached for a in writes.get(pou, ())})

    def reset_globals(self) -> None:
        """The VAR_GLOBALs at their initial values (a cold start of the logic)."""
        self.namespace["_G"] = self.namespace["_Globals"]()

    # -- RETAIN of aggregates: a value as JSON, and back ---------------------------------------

    def dump(self, value: Any, t: Type) -> Any:
        """A variable's value as JSON: a structure or an FB instance as an object of its
        members (an FB's internal state too: a retained CTU keeps CV and its edge memory)."""
        if isinstance(t, ArrayOf):
            return [self.dump(v, t.element) for v in value]
        if isinstance(t, StructOf):
            return {k: self.dump(getattr(value, f"v_{k}"), f.type)
                    for k, f in self.struct_fields[t.name].items()}
        if isinstance(t, FbOf):
            if t.std:
                return _dump_std(value)
            return {k: self.dump(getattr(value, f"v_{k}"), f.type)
                    for k, f in self.fb_vars[t.name].items()}
        return value

    def members_of(self, t: Any) -> dict[str, ProgramVar] | None:
        """The members of a user FB's instance or a structure (for a path: main.fb.x)."""
        if isinstance(t, FbOf) and not t.std:
            return self.fb_vars.get(t.name)
        if isinstance(t, StructOf):
            return self.struct_fields.get(t.name)
        return None

    def fresh(self, t: Type) -> Any:
        """A new instance of an aggregate type (its initial value), None for a scalar."""
        if isinstance(t, ArrayOf):
            return [self.fresh(t.element) for _ in range(t.length)]
        if isinstance(t, FbOf):
            return self.namespace[f"_STD_{t.name}" if t.std else f"FB_{t.name}"]()
        if isinstance(t, StructOf):
            return self.namespace[f"S_{t.name}"]()
        return None

    def restore(self, stored: Any, t: Type) -> Any:
        """A RETAIN value from the store as the logic holds it; ValueError when it no
        longer fits its variable's type (retyped, resized, other members)."""
        return self.load(stored, t, self.fresh(t))

    def fits(self, stored: Any, t: Type) -> bool:
        try:
            self.restore(stored, t)
        except (ValueError, TypeError, AttributeError, OverflowError):
            return False
        return True

    def load(self, stored: Any, t: Type, fresh: Any) -> Any:
        """A stored value into ``fresh`` (a new instance of ``t``), or ValueError when the
        value no longer fits the type (the caller then keeps the initial value)."""
        if isinstance(t, ArrayOf):
            if not isinstance(stored, list) or len(stored) != t.length:
                raise ValueError("not an array of that length")
            return [self.load(s, t.element, f) for s, f in zip(stored, fresh, strict=True)]
        if isinstance(t, StructOf | FbOf):
            if isinstance(t, FbOf) and t.std:
                _load_std(fresh, stored)
                return fresh
            table = self.struct_fields[t.name] if isinstance(t, StructOf) else \
                self.fb_vars[t.name]
            if not isinstance(stored, dict) or set(stored) != set(table):
                raise ValueError("other members")
            for k, f in table.items():
                setattr(fresh, f"v_{k}", self.load(stored[k], f.type,
                                                   getattr(fresh, f"v_{k}")))
            return fresh
        if not _fits_scalar(stored, t):
            raise ValueError(f"not a {t}")
        return to_real(stored) if t == "REAL" else stored

    def new_program(self, key: str) -> Any:
        return self.namespace[f"P_{key}"]()

    # -- the state a scan leaves, as one value (the scan's test for a scan that changed nothing)

    def program_state(self, key: str, timeless: bool = False) -> StateOf | None:
        """A function giving the whole state of an instance of PROGRAM ``key`` -- its
        variables, its FB instances' inner state (a TON's start), its arrays and structures
        -- as one value that compares equal only when the two states are the same; None
        when a member is of no type it knows.  ``timeless``: all but the timers' ETs."""
        return self._kept_state(f"P_{key}", self.programs[key], timeless)

    def globals_state(self, timeless: bool = False) -> StateOf | None:
        """:meth:`program_state` of the VAR_GLOBALs (the module's ``_G``)."""
        return self._kept_state("_Globals", self.globals, timeless)

    def _kept_state(self, cls: str, table: dict[str, ProgramVar], timeless: bool
                    ) -> StateOf | None:
        """:meth:`_object_state` of the generated class ``cls``, made once for the same
        module and types (a scenario suite loads the same logic at every run)."""
        key = (self._filename, cls, timeless, tuple((k, str(v.type)) for k, v in table.items()))
        with _STATES_LOCK:  # (sweeps run logic in threads)
            if key in _STATES:
                return _STATES[key]
        made = self._object_state(self.namespace[cls], table, timeless)
        with _STATES_LOCK:
            if len(_STATES) >= COMPILED_KEPT * 4:
                _STATES.pop(next(iter(_STATES)))
            _STATES[key] = made
        return made

    def _state_of(self, t: Type, timeless: bool) -> StateOf | Literal[False] | None:
        """The state of a value of type ``t``: None when the value is its own (a number,
        a string, a BOOL: immutable), False when it cannot be told."""
        if isinstance(t, ArrayOf | AnyLength):
            each = self._state_of(t.element, timeless)
            if each is False:
                return False
            if isinstance(t, AnyLength):  # the caller's array, or None before a call
                return lambda v: None if v is None else tuple(
                    v if each is None else map(each, v))
            return tuple if each is None else lambda v: tuple(map(each, v))
        if isinstance(t, StructOf | FbOf):
            parts: list[str] = []
            helpers: dict[str, StateOf] = {}
            if not self._members(t, "o", parts, helpers, timeless):
                return False
            return _state_function(parts, helpers)
        if t in REALS:
            return _real_state
        return None

    def _object_state(self, cls: Any, table: dict[str, ProgramVar], timeless: bool
                      ) -> StateOf | None:
        """A generated class's instance (a PROGRAM, the VAR_GLOBALs): by its slots."""
        parts: list[str] = []
        helpers: dict[str, StateOf] = {}
        if not self._slots(cls, table, "o", parts, helpers, timeless):
            return None
        return _state_function(parts, helpers)

    def _slots(self, cls: Any, table: dict[str, ProgramVar], holder: str, parts: list[str],
               helpers: dict[str, StateOf], timeless: bool) -> bool:
        """The state of each member of ``holder`` (code: a generated class's instance) as
        code into ``parts`` -- a structure's or an FB's members are read in place, as
        their holder's -- and the functions that code calls (an array's, a REAL's) into
        ``helpers``; False when one cannot be told."""
        fresh = cls()
        for slot in cls.__slots__:
            path = f"{holder}.{slot}"
            var = table.get(slot[2:]) if slot.startswith("v_") else None
            if var is None:  # (an ARRAY[*]'s lower bound): a scalar, or unknown
                if not isinstance(getattr(fresh, slot), bool | int | str):
                    return False
                parts.append(path)
            elif isinstance(var.type, StructOf | FbOf):
                if not self._members(var.type, path, parts, helpers, timeless):
                    return False
            else:
                state = self._state_of(var.type, timeless)
                if state is False:
                    return False
                if state is None:
                    parts.append(path)
                else:
                    name = f"_s{len(helpers)}"
                    helpers[name] = state
                    parts.append(f"{name}({path})")
        return True

    def _members(self, t: StructOf | FbOf, holder: str, parts: list[str],
                 helpers: dict[str, StateOf], timeless: bool) -> bool:
        if isinstance(t, StructOf):
            return self._slots(self.namespace[f"S_{t.name}"], self.struct_fields[t.name],
                               holder, parts, helpers, timeless)
        if not t.std:
            return self._slots(self.namespace[f"FB_{t.name}"], self.fb_vars[t.name], holder,
                               parts, helpers, timeless)
        return _std_members(self.namespace[f"_STD_{t.name}"], holder, parts, timeless)

    def locate(self, tb: pytypes.TracebackType | None) -> tuple[n.Span | None, str]:
        """The ST statement of the innermost generated frame in a traceback."""
        line = None
        while tb is not None:
            if tb.tb_frame.f_code.co_filename == self._filename:
                line = tb.tb_lineno
            tb = tb.tb_next
        if line is None:
            return None, ""
        for i in range(min(line, len(self._spans)) - 1, -1, -1):
            where = self._spans[i]
            if where is not None:
                span = n.Span(*where)
                for f in self.files:
                    if f.path == span.file:
                        return span, f.line(span.line)
                return span, ""
        return None, ""


def _compiled_pieces(source: str, filename: str) -> tuple[pytypes.CodeType, ...]:
    """The module's code, kept for small logic (see _COMPILED)."""
    if len(source) > KEPT_SOURCE_MAX:
        return _compile_pieces(source, filename)
    return _kept_pieces(source, filename)


@functools.lru_cache(maxsize=COMPILED_KEPT)
def _kept_pieces(source: str, filename: str) -> tuple[pytypes.CodeType, ...]:
    return _compile_pieces(source, filename)


def _compile_pieces(source: str, filename: str) -> tuple[pytypes.CodeType, ...]:
    """The module compiled a piece at a time (PIECE_CHARS: whole top-level definitions),
    each with the line numbers it has in ``source``; between pieces, a thread waiting for
    the interpreter gets it."""
    lines = source.split("\n")
    starts = [i for i, line in enumerate(lines) if line[:1] not in ("", " ")]
    pieces: list[pytypes.CodeType] = []
    first, size = 0, 0
    for i, end in enumerate([*starts[1:], len(lines)]):
        size += sum(len(line) + 1 for line in lines[starts[i]:end])
        if size >= PIECE_CHARS or end == len(lines):
            try:
                code = compile("\n".join(lines[first:end]) + "\n", filename, "exec")
            except SyntaxError as exc:  # (its line in the whole source, for the diagnostic)
                exc.lineno = (exc.lineno or 1) + first
                raise
            pieces.append(_moved(code, first) if first else code)
            first, size = end, 0
            time.sleep(0)
    return tuple(pieces)


def _moved(code: pytypes.CodeType, lines: int) -> pytypes.CodeType:
    """``code`` as if its source began ``lines`` lines further down (3.11: each code
    object's line table counts from its co_firstlineno)."""
    consts = tuple(_moved(c, lines) if isinstance(c, pytypes.CodeType) else c
                   for c in code.co_consts)
    return code.replace(co_firstlineno=code.co_firstlineno + lines, co_consts=consts)


# A value's state: comparable, and equal only for the same state.
StateOf = Callable[[Any], Any]


def _real_state(value: float) -> tuple[float, float]:
    """A REAL's state: -0.0 and 0.0 compare equal, yet 1.0 / x tells them apart."""
    return value, math.copysign(1.0, value)


# The state functions made (Logic._kept_state): (module, class, timeless, types) -> function.
_STATES: dict[tuple[str, str, bool, tuple[tuple[str, str], ...]], StateOf | None] = {}
_STATES_LOCK = threading.Lock()


def _state_function(parts: list[str], helpers: dict[str, StateOf]) -> StateOf:
    """``state(o)``: the tuple of ``parts`` (code on ``o``), compiled once for the same code
    -- straight-line attribute reads, 5x faster than an attrgetter of the dotted paths."""
    namespace: dict[str, Any] = dict(helpers)
    exec(_state_code("def state(o):\n    return (" + "".join(f"{part}, " for part in parts)
                     + ")\n"), namespace)
    state: StateOf = namespace["state"]
    return state


@functools.lru_cache(maxsize=COMPILED_KEPT * 4)
def _state_code(source: str) -> pytypes.CodeType:
    return compile(source, "<ncgate-st state>", "exec")


def _std_members(cls: Any, holder: str, parts: list[str], timeless: bool = False) -> bool:
    """A standard FB's members (a dataclass: TON, CTU with its R_TRIG, ...), read in place
    (``timeless``: a timer's ET left out)."""
    fresh = cls()
    for f in dataclasses.fields(cls):
        if timeless and f.name == "ET" and isinstance(fresh, stdlib.Timer):
            continue
        value = getattr(fresh, f.name)
        if dataclasses.is_dataclass(value):
            if not _std_members(value.__class__, f"{holder}.{f.name}", parts, timeless):
                return False
        elif value is None or isinstance(value, bool | int | str):
            parts.append(f"{holder}.{f.name}")
        else:
            return False
    return True


def _dump_std(fb: Any) -> dict[str, Any]:
    import dataclasses

    return {f.name: (_dump_std(v) if dataclasses.is_dataclass(v := getattr(fb, f.name))
                     else v) for f in dataclasses.fields(fb)}


def _load_std(fb: Any, stored: Any) -> None:
    import dataclasses

    fields = {f.name: f for f in dataclasses.fields(fb)}
    if not isinstance(stored, dict) or set(stored) != set(fields):
        raise ValueError("other members")
    for name in fields:
        current = getattr(fb, name)
        if dataclasses.is_dataclass(current):
            _load_std(current, stored[name])
        elif type(stored[name]) is not type(current) and not (
                current is None or stored[name] is None):
            raise ValueError(f"{name} is not a {type(current).__name__}")
        else:
            setattr(fb, name, stored[name])


def _fits_scalar(value: Any, t: Type) -> bool:
    if t == "BOOL":
        return isinstance(value, bool)
    if isinstance(t, StringOf):
        return isinstance(value, str) and len(value) <= t.length
    if t in CHARS:
        return isinstance(value, str) and len(value) == 1 and ord(value) <= (
            255 if t == "CHAR" else 65535)
    if t in REALS:
        return isinstance(value, float | int) and not isinstance(value, bool) and \
            math.isfinite(value)
    if isinstance(t, EnumOf):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(t, str) and t in stdlib.INTEGER_TYPES:
        lo, hi = limits(t) if t != "TOD" else (0, TOD_MS - 1)
        ok = isinstance(value, int) and not isinstance(value, bool) and lo <= value <= hi
        return ok and (not isinstance(t, Ranged) or t.lo <= value <= t.hi)
    return False
