"""A tree-walking evaluator of checked Structured Text: the baseline the compiler is measured
against (``bench/plc.py``) and an independent second reading of the language that the tests
compare the compiled code with.

It walks the syntax tree every scan, looking names up in dictionaries, as an interpreter
without a compile step does.  It covers what those programs use -- PROGRAMs, the standard
function blocks and user FUNCTION_BLOCKs (inputs and outputs); elementary variables, arrays,
structures (dictionaries), enumerations and STRINGs; assignments, IF, CASE, FOR, WHILE,
REPEAT, EXIT, CONTINUE, RETURN; every operator on integers and BOOLs; ABS, MIN, MAX, LIMIT,
SEL, LEN, LEFT, RIGHT, MID, CONCAT, FIND (inputs in order or by their IEC names); EN and ENO
on calls; the image -- and raises
:class:`NotImplementedError` for the rest (user FUNCTIONs, VAR_IN_OUT, globals, NC
access).  It computes REALs in double, untyped: it is no reading of REAL's single precision,
which tests/unit/plc/test_st_iec_values.py checks instead.
Only logic that :func:`~ncgate.plc.st.compiler.compile_logic` accepted is walked.
"""

from __future__ import annotations

import contextlib
import copy
from typing import Any

from ncgate.plc.st import nodes as n
from ncgate.plc.st import stdlib
from ncgate.plc.st.compiler import FORMAL_INPUTS, Compiler, Context, _fold
from ncgate.plc.st.intrinsics import IMAGE_NAMES as IMAGE
from ncgate.plc.st.runtime import IterationGuard, _pow
from ncgate.plc.st.types import ArrayOf, EnumOf, FbOf, StringOf, StructOf, Type, default_value


class _Exit(Exception):
    pass


class _Return(Exception):
    pass


class _Continue(Exception):
    pass


class _Frame:
    """The variables of a PROGRAM or of a user FB instance, and their types."""

    def __init__(self, state: dict[str, Any], types: dict[str, Type]) -> None:
        self.state = state
        self.types = types


class Walker:
    """Runs the PROGRAMs of checked logic by walking their trees."""

    def __init__(self, files: list[n.SourceFile], context: Context, sa: bytearray,
                 k: bytearray, syvar: list[int], loop_limit: int = 100_000) -> None:
        compiler = Compiler(files, context)
        compiler.collect()
        self.compiler = compiler
        self.pous = compiler.pous
        self.sa, self.k, self.syvar = sa, k, syvar
        self.loop_limit = loop_limit
        self.now_ms = 0
        self.left = 0
        self.state: dict[str, dict[str, Any]] = {}
        self.types: dict[str, dict[str, Type]] = {}
        self.frames: dict[str, _Frame] = {}
        for key, info in self.pous.items():
            if info.pou.kind != "PROGRAM":
                continue
            self.types[key] = {k2: v.type for k2, v in info.vars.items()}
            self.state[key] = {k2: self._new(v.type, v.initial) for k2, v in info.vars.items()}
            self.frames[key] = _Frame(self.state[key], self.types[key])

    def _new(self, t: Type, initial: Any) -> Any:
        if isinstance(t, FbOf):
            if t.std:
                return stdlib.FUNCTION_BLOCKS[t.name]()
            info = self.pous[t.name]
            if any(v.section == "VAR_IN_OUT" for v in info.vars.values()):
                raise NotImplementedError("the walker passes no VAR_IN_OUT")
            return _Frame({k: self._new(v.type, v.initial) for k, v in info.vars.items()},
                          {k: v.type for k, v in info.vars.items()})
        if isinstance(t, StructOf):
            fields = self.compiler.structs[t.name].fields
            given = initial or {}
            return {k: self._new(f.type, given.get(k, f.initial)) for k, f in fields.items()}
        if isinstance(t, ArrayOf):
            if isinstance(t.element, FbOf | StructOf | ArrayOf):
                return [self._new(t.element, None if initial is None else initial[i])
                        for i in range(t.length)]
            return list(initial) if initial is not None else default_value(t)
        return initial if initial is not None else default_value(t)

    def scan(self, now_ms: int) -> None:
        self.now_ms = now_ms
        self.left = self.loop_limit
        for key, info in self.pous.items():
            if info.pou.kind == "PROGRAM":
                with contextlib.suppress(_Return):  # RETURN ends the program's scan
                    self.block(info.pou.body, self.frames[key])

    # -- statements --------------------------------------------------------------------------

    def block(self, body: tuple[n.Stmt, ...], prog: _Frame) -> None:
        for stmt in body:
            self.stmt(stmt, prog)

    def stmt(self, s: n.Stmt, prog: _Frame) -> None:
        if isinstance(s, n.Assign):
            self.store(s.target, self.value(s.expr, prog), prog)
        elif isinstance(s, n.CallStmt):
            fb, t = self.locate(s.target, prog)
            assert isinstance(t, FbOf)
            declared = fb.types if not t.std else {}
            args, enabled = self._enabled(s.args, declared, prog)
            if not enabled:  # EN FALSE (6.6.1.6): not called, nothing bound
                self._eno(s.args, declared, enabled, prog)
                return
            outputs = []
            for arg in args:
                assert arg.name is not None
                name = arg.name.upper()
                if arg.output is None:
                    assert arg.expr is not None
                    value = self.value(arg.expr, prog)
                    if t.std:
                        setattr(fb, name, _stored(value, _std_member(t.name, name)))
                    else:
                        fb.state[name] = _stored(value, fb.types[name])
                else:
                    outputs.append((arg.output, name))
            if t.std:
                fb(self.now_ms)
            else:
                with contextlib.suppress(_Return):
                    self.block(self.pous[t.name].pou.body, fb)
            for target, name in outputs:
                self.store(target, getattr(fb, name) if t.std else fb.state[name], prog)
            self._eno(s.args, declared, enabled, prog)
        elif isinstance(s, n.If):
            for cond, body in s.branches:
                if self.value(cond, prog):
                    self.block(body, prog)
                    return
            if s.otherwise is not None:
                self.block(s.otherwise, prog)
        elif isinstance(s, n.Case):
            selector = self.value(s.selector, prog)
            for labels, body in s.arms:
                for label in labels:
                    lo = self.value(label.lo, prog)
                    hi = self.value(label.hi, prog) if label.hi is not None else lo
                    if lo <= selector <= hi:
                        self.block(body, prog)
                        return
            if s.otherwise is not None:
                self.block(s.otherwise, prog)
        elif isinstance(s, n.For):
            var = n.Var(s.var, (), s.var_span)
            t = prog.types[s.var.upper()]
            self.store(var, self.value(s.start, prog), prog)
            end = self.value(s.end, prog)
            step = self.value(s.step, prog) if s.step is not None else 1
            while True:
                i = prog.state[s.var.upper()]
                if not (i <= end if step >= 0 else i >= end):
                    break
                self._tick()
                try:
                    self.block(s.body, prog)
                except _Exit:
                    break
                except _Continue:
                    pass
                prog.state[s.var.upper()] = _stored(i + step, t)
        elif isinstance(s, n.While):
            while self.value(s.cond, prog):
                self._tick()
                try:
                    self.block(s.body, prog)
                except _Exit:
                    break
                except _Continue:
                    pass
        elif isinstance(s, n.Repeat):
            while True:
                self._tick()
                try:
                    self.block(s.body, prog)
                except _Exit:
                    break
                except _Continue:
                    pass
                if self.value(s.cond, prog):
                    break
        elif isinstance(s, n.Exit):
            raise _Exit
        elif isinstance(s, n.Continue):
            raise _Continue
        else:
            raise _Return

    def _tick(self) -> None:
        self.left -= 1
        if self.left < 0:
            raise IterationGuard("the loop iteration guard ran out")

    # -- places --------------------------------------------------------------------------------

    def locate(self, var: n.Var, prog: _Frame) -> tuple[Any, Type]:
        key = var.name.upper()
        if key in (*IMAGE, "NC"):
            raise NotImplementedError("the image is read through value()")
        obj: Any = prog.state[key]
        t: Type = prog.types[key]
        for sel in var.selectors:
            if isinstance(sel, n.Index):
                assert isinstance(t, ArrayOf)
                i = self.value(sel.expr, prog)
                if not t.lo <= i <= t.hi:
                    raise IndexError(f"index {i} outside {t.lo}..{t.hi}")
                obj, t = obj[i - t.lo], t.element
            elif isinstance(sel, n.Field) and isinstance(t, StructOf):
                name = sel.name.upper()
                obj, t = obj[name], self.compiler.structs[t.name].fields[name].type
            elif isinstance(sel, n.Field) and isinstance(t, FbOf) and not t.std:
                name = sel.name.upper()
                obj, t = obj.state[name], obj.types[name]
            else:
                assert isinstance(t, FbOf) and isinstance(sel, n.Field)
                name = sel.name.upper()
                obj, t = getattr(obj, name), _std_member(t.name, name)
        return obj, t

    def store(self, var: n.Var, value: Any, prog: _Frame) -> None:
        key = var.name.upper()
        if key in IMAGE:
            array, index = self._image_at(var, prog)
            if key == "SA":
                if value:
                    self.sa[index >> 3] |= 1 << (index & 7)
                else:
                    self.sa[index >> 3] &= 255 ^ (1 << (index & 7))
            else:
                array[index] = _stored(value, "INT" if key == "SYVAR" else "BYTE")
            return
        if key == "NC":
            raise NotImplementedError("the walker does not drive the NC")
        if not var.selectors:
            prog.state[key] = _stored(value, prog.types[key])
            return
        *path, last = var.selectors
        holder, t = self.locate(n.Var(var.name, tuple(path), var.span), prog)
        if isinstance(last, n.Index):
            assert isinstance(t, ArrayOf)
            i = self.value(last.expr, prog)
            if not t.lo <= i <= t.hi:
                raise IndexError(f"index {i} outside {t.lo}..{t.hi}")
            holder[i - t.lo] = _stored(value, t.element)
        elif isinstance(t, StructOf) and isinstance(last, n.Field):
            name = last.name.upper()
            holder[name] = _stored(value, self.compiler.structs[t.name].fields[name].type)
        elif isinstance(t, FbOf) and not t.std and isinstance(last, n.Field):
            name = last.name.upper()
            holder.state[name] = _stored(value, holder.types[name])
        else:
            assert isinstance(t, FbOf) and isinstance(last, n.Field)
            name = last.name.upper()
            setattr(holder, name, _stored(value, _std_member(t.name, name)))

    def _image_at(self, var: n.Var, prog: _Frame) -> tuple[Any, int]:
        """The array behind ``SA/SAB/SK/SYVAR[i]`` and ``i``, checked against its size (for
        SA in bits)."""
        key = var.name.upper()
        index = self.value(var.selectors[0].expr, prog)  # type: ignore[union-attr]
        array = {"SA": self.sa, "SAB": self.sa, "SK": self.k, "SYVAR": self.syvar}[key]
        size = len(array) * 8 if key == "SA" else len(array)
        if not 0 <= index < size:
            raise IndexError(f"index {index} outside the image")
        return array, index

    # -- expressions -----------------------------------------------------------------------------

    def value(self, x: n.Expr, prog: _Frame) -> Any:
        if isinstance(x, n.Literal):
            return x.value
        if isinstance(x, n.Var):
            key = x.name.upper()
            if key in IMAGE:
                array, index = self._image_at(x, prog)
                return bool(self.sa[index >> 3] >> (index & 7) & 1) if key == "SA" \
                    else array[index]
            if key == "NC":
                raise NotImplementedError("the walker does not read the NC")
            if key not in prog.state:
                owners = self.compiler.enum_values.get(key)
                if owners and not x.selectors:  # an enumeration's value, by its name
                    return self.compiler.enums[owners[0]].values[key]
                raise NotImplementedError("the walker reads no globals")
            obj, _ = self.locate(x, prog)
            return obj
        if isinstance(x, n.Unary):
            v = self.value(x.operand, prog)
            if x.op == "NOT":
                if isinstance(v, bool):
                    return not v
                raise NotImplementedError("NOT of a bit string")
            return -v if x.op == "-" else v
        if isinstance(x, n.Binary):
            a, b = self.value(x.left, prog), self.value(x.right, prog)
            op = x.op
            if op == "AND":
                return (a and b) if isinstance(a, bool) else a & b
            if op == "OR":
                return (a or b) if isinstance(a, bool) else a | b
            if op == "XOR":
                return (a != b) if isinstance(a, bool) else a ^ b
            if op == "=":
                return a == b
            if op == "<>":
                return a != b
            if op == "<":
                return a < b
            if op == ">":
                return a > b
            if op == "<=":
                return a <= b
            if op == ">=":
                return a >= b
            if op == "**":
                return _pow(a, b)
            # + - * / MOD: as the compiler folds constants (a float / 0 raises too)
            return _fold(op, a, b, isinstance(a, float) or isinstance(b, float))
        if isinstance(x, n.EnumLit):
            return self.compiler.enums[x.type_name.upper()].values[x.name.upper()]
        key = x.name.upper()
        given, enabled = self._enabled(x.args, {}, prog)
        if key in FORMAL_INPUTS and any(a.name is not None for a in given):  # SEL(G := ..)
            given = self.compiler.formal(n.Call(x.name, given, x.span),
                                         FORMAL_INPUTS[key]).args
        args = [self.value(a.expr, prog) for a in given if a.expr is not None]
        result = self._call(key, x, args)  # (the standard functions have no side effect)
        self._eno(x.args, {}, enabled, prog)
        return result if enabled else type(result)()  # EN FALSE: its type's default

    def _enabled(self, args: tuple[n.Arg, ...], declared: dict[str, Any], prog: _Frame
                 ) -> tuple[tuple[n.Arg, ...], bool]:
        """A call's arguments but EN and ENO, and EN's value; ENO => stores it (IEC
        61131-3, 6.6.1.6) -- unless the POU declares EN or ENO itself."""
        enabled, rest = True, []
        for arg in args:
            name = (arg.name or "").upper()
            if name == "EN" and name not in declared and arg.expr is not None:
                enabled = bool(self.value(arg.expr, prog))
            elif not (name == "ENO" and name not in declared):
                rest.append(arg)
        return tuple(rest), enabled

    def _eno(self, args: tuple[n.Arg, ...], declared: dict[str, Any], enabled: bool,
             prog: _Frame) -> None:
        """ENO => v, after the call: v is EN."""
        for arg in args:
            if (arg.name or "").upper() == "ENO" and "ENO" not in declared and \
                    arg.output is not None:
                self.store(arg.output, enabled, prog)

    def _call(self, key: str, x: n.Call, args: list[Any]) -> Any:
        if key == "ABS":
            return abs(args[0])
        if key == "MIN":
            return min(args)
        if key == "MAX":
            return max(args)
        if key == "LIMIT":
            return min(max(args[1], args[0]), args[2])
        if key == "SEL":
            return args[2] if args[0] else args[1]
        if key == "LEN":
            return len(args[0])
        if key == "CONCAT":
            return "".join(args)
        if key == "LEFT":
            return args[0][:args[1]]
        if key == "RIGHT":
            return args[0][len(args[0]) - args[1]:] if args[1] < len(args[0]) else args[0]
        if key == "MID":
            return args[0][args[2] - 1:args[2] - 1 + args[1]]
        if key == "FIND":
            return args[0].find(args[1]) + 1 if args[1] else 0
        raise NotImplementedError(f"the walker does not call {x.name}")


def _std_member(fb: str, name: str) -> str:
    from ncgate.plc.st.compiler import STD_FBS

    return STD_FBS[fb][name][1]


def _stored(value: Any, t: Type) -> Any:
    """A value stored in a place of type ``t``: wrapped, or made a REAL."""
    if t in ("REAL", "LREAL"):
        return float(value)
    if isinstance(t, StringOf):
        return value[:t.length]
    if isinstance(t, StructOf):
        return copy.deepcopy(value)
    if t == "BOOL" or isinstance(t, EnumOf) or not isinstance(t, str):
        return value
    return stdlib.wrap(int(value), "DINT" if t == "TIME" else t)
