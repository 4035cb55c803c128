"""A tree-walking evaluator of checked Structured Text: the baseline the compiler is measured
against (``bench/plc.py``) and an independent second reading of the language that the tests
compare the compiled code with.

It walks the syntax tree every scan, looking names up in dictionaries, as an interpreter
without a compile step does.  It covers what those programs use -- PROGRAMs and the standard
function blocks; elementary variables and arrays; assignments, IF, CASE, FOR, WHILE, REPEAT,
EXIT, CONTINUE, RETURN; every operator on integers and BOOLs; ABS, MIN, MAX, LIMIT, SEL;
the image -- and raises :class:`NotImplementedError` for the rest (user FUNCTIONs and
FUNCTION_BLOCKs, NC access).  It computes REALs in double, untyped: it is no reading of
REAL's single precision, which tests/unit/plc/test_st_iec_values.py checks instead.
Only logic that :func:`~ncgate.plc.st.compiler.compile_logic` accepted is walked.
"""

from __future__ import annotations

import contextlib
from typing import Any

from ncgate.plc.st import nodes as n
from ncgate.plc.st import stdlib
from ncgate.plc.st.compiler import IMAGE_NAMES as IMAGE
from ncgate.plc.st.compiler import Compiler, Context, IterationGuard, _fold, _pow
from ncgate.plc.st.types import ArrayOf, FbOf, Type, default_value


class _Exit(Exception):
    pass


class _Return(Exception):
    pass


class _Continue(Exception):
    pass


class Walker:
    """Runs the PROGRAMs of checked logic by walking their trees."""

    def __init__(self, files: list[n.SourceFile], context: Context, sa: bytearray,
                 k: bytearray, syvar: list[int], loop_limit: int = 100_000) -> None:
        compiler = Compiler(files, context)
        compiler.collect()
        self.pous = compiler.pous
        self.sa, self.k, self.syvar = sa, k, syvar
        self.loop_limit = loop_limit
        self.now_ms = 0
        self.left = 0
        self.state: dict[str, dict[str, Any]] = {}
        self.types: dict[str, dict[str, Type]] = {}
        for key, info in self.pous.items():
            if info.pou.kind != "PROGRAM":
                continue
            self.types[key] = {k2: v.type for k2, v in info.vars.items()}
            self.state[key] = {k2: self._new(v.type, v.initial) for k2, v in info.vars.items()}

    def _new(self, t: Type, initial: Any) -> Any:
        if isinstance(t, FbOf):
            if not t.std:
                raise NotImplementedError("the walker runs the standard function blocks only")
            return stdlib.FUNCTION_BLOCKS[t.name]()
        if isinstance(t, ArrayOf):
            if isinstance(t.element, FbOf):
                return [self._new(t.element, None) for _ in range(t.length)]
            return list(initial) if initial is not None else default_value(t)
        return initial if initial is not None else default_value(t)

    def scan(self, now_ms: int) -> None:
        self.now_ms = now_ms
        self.left = self.loop_limit
        for key, info in self.pous.items():
            if info.pou.kind == "PROGRAM":
                with contextlib.suppress(_Return):  # RETURN ends the program's scan
                    self.block(info.pou.body, key)

    # -- statements --------------------------------------------------------------------------

    def block(self, body: tuple[n.Stmt, ...], prog: str) -> None:
        for stmt in body:
            self.stmt(stmt, prog)

    def stmt(self, s: n.Stmt, prog: str) -> None:
        if isinstance(s, n.Assign):
            self.store(s.target, self.value(s.expr, prog), prog)
        elif isinstance(s, n.CallStmt):
            fb, t = self.locate(s.target, prog)
            assert isinstance(t, FbOf)
            outputs = []
            for arg in s.args:
                assert arg.name is not None
                if arg.output is None:
                    assert arg.expr is not None
                    value = self.value(arg.expr, prog)
                    member_type = _std_member(t.name, arg.name.upper())
                    setattr(fb, arg.name.upper(), _stored(value, member_type))
                else:
                    outputs.append((arg.output, arg.name.upper()))
            fb(self.now_ms)
            for target, name in outputs:
                self.store(target, getattr(fb, name), prog)
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
                    if not isinstance(label.lo, n.Literal) or not isinstance(
                            label.hi, n.Literal | None):
                        raise NotImplementedError("the walker takes literal CASE labels")
                    lo = label.lo.value
                    hi = label.hi.value if label.hi is not None else lo
                    if lo <= selector <= hi:
                        self.block(body, prog)
                        return
            if s.otherwise is not None:
                self.block(s.otherwise, prog)
        elif isinstance(s, n.For):
            var = n.Var(s.var, (), s.var_span)
            t = self.types[prog][s.var.upper()]
            self.store(var, self.value(s.start, prog), prog)
            end = self.value(s.end, prog)
            step = self.value(s.step, prog) if s.step is not None else 1
            while True:
                i = self.state[prog][s.var.upper()]
                if not (i <= end if step >= 0 else i >= end):
                    break
                self._tick()
                try:
                    self.block(s.body, prog)
                except _Exit:
                    break
                except _Continue:
                    pass
                self.state[prog][s.var.upper()] = _stored(i + step, t)
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

    def locate(self, var: n.Var, prog: str) -> tuple[Any, Type]:
        key = var.name.upper()
        if key in (*IMAGE, "NC"):
            raise NotImplementedError("the image is read through value()")
        obj: Any = self.state[prog][key]
        t: Type = self.types[prog][key]
        for sel in var.selectors:
            if isinstance(sel, n.Index):
                assert isinstance(t, ArrayOf)
                i = self.value(sel.expr, prog)
                if not t.lo <= i <= t.hi:
                    raise IndexError(f"index {i} outside {t.lo}..{t.hi}")
                obj, t = obj[i - t.lo], t.element
            else:
                assert isinstance(t, FbOf) and isinstance(sel, n.Field)
                name = sel.name.upper()
                obj, t = getattr(obj, name), _std_member(t.name, name)
        return obj, t

    def store(self, var: n.Var, value: Any, prog: str) -> None:
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
            self.state[prog][key] = _stored(value, self.types[prog][key])
            return
        *path, last = var.selectors
        holder, t = self.locate(n.Var(var.name, tuple(path), var.span), prog)
        if isinstance(last, n.Index):
            assert isinstance(t, ArrayOf)
            i = self.value(last.expr, prog)
            if not t.lo <= i <= t.hi:
                raise IndexError(f"index {i} outside {t.lo}..{t.hi}")
            holder[i - t.lo] = _stored(value, t.element)
        else:
            assert isinstance(t, FbOf) and isinstance(last, n.Field)
            name = last.name.upper()
            setattr(holder, name, _stored(value, _std_member(t.name, name)))

    def _image_at(self, var: n.Var, prog: str) -> tuple[Any, int]:
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

    def value(self, x: n.Expr, prog: str) -> Any:
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
            raise NotImplementedError("the walker reads no enumerations")
        key = x.name.upper()
        args = [self.value(a.expr, prog) for a in x.args if a.expr is not None]
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
        raise NotImplementedError(f"the walker does not call {x.name}")


def _std_member(fb: str, name: str) -> str:
    from ncgate.plc.st.compiler import STD_FBS

    return STD_FBS[fb][name][1]


def _stored(value: Any, t: Type) -> Any:
    """A value stored in a place of type ``t``: wrapped, or made a REAL."""
    if t in ("REAL", "LREAL"):
        return float(value)
    if t == "BOOL" or not isinstance(t, str):
        return value
    return stdlib.wrap(int(value), "DINT" if t == "TIME" else t)
