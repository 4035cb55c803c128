"""The compiled code and the tree-walking evaluator are two readings of the same language:
on random programs (integer arithmetic that overflows, division, comparisons, boolean logic,
IF/CASE/FOR/WHILE, arrays, the image, timers and counters) and random inputs, both must leave
the same variables and the same image, scan after scan."""

from __future__ import annotations

import random

import pytest

from ncgate.plc.image import IOImage
from ncgate.plc.scan import PlcRuntime
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.parser import parse_source
from ncgate.plc.st.runtime import IterationGuard
from ncgate.plc.st.walk import Walker

from .st_harness import RecordingNc

INTS = [f"i{k}" for k in range(6)] + ["d0", "d1"]
BOOLS = [f"b{k}" for k in range(4)]
COMPARISONS = ["<", ">", "=", "<>", "<=", ">="]


class Gen:
    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)

    def int_expr(self, depth: int = 0) -> str:
        r = self.rng
        if depth > 2 or r.random() < 0.3:
            # a literal always beside a variable: a constant subtree out of range is a
            # load-time error (ST021), not something to compare
            return r.choice([r.choice(INTS[:6]), f"({r.choice(INTS[:6])} + "
                             f"{r.randrange(-300, 30000)})",
                             f"a[{r.randrange(1, 5)}]", f"SYVAR[{r.randrange(4)}]", "c.CV"])
        a, b = self.int_expr(depth + 1), self.int_expr(depth + 1)
        return r.choice([f"({a} + {b})", f"({a} - {b})", f"({a} * {b})",
                         f"({a} / {r.choice([3, -7, 100])})", f"({a} MOD {r.choice([5, -9])})",
                         f"ABS({a})", f"MIN({a}, {b})", f"MAX({a}, {b})", f"-{a}",
                         f"SEL({self.bool_expr(depth + 1)}, {a}, {b})",
                         f"LIMIT(-100, {a}, 100)"])

    def bool_expr(self, depth: int = 0) -> str:
        r = self.rng
        if depth > 2 or r.random() < 0.3:
            return r.choice([r.choice(BOOLS), "TRUE", f"SA[{r.randrange(8)}]", "t.Q"])
        a, b = self.bool_expr(depth + 1), self.bool_expr(depth + 1)
        return r.choice([f"({a} AND {b})", f"({a} OR {b})", f"({a} XOR {b})", f"NOT {a}",
                         f"({self.int_expr(depth + 1)} {r.choice(COMPARISONS)} "
                         f"{self.int_expr(depth + 1)})"])

    def stmt(self, depth: int = 0) -> str:
        r = self.rng
        kind = r.choice(["int", "int", "dint", "bool", "arr", "image", "if", "case", "for",
                         "while"] if depth < 2 else ["int", "bool", "image"])
        if kind == "int":
            return f"{r.choice(INTS[:6])} := {self.int_expr()};"
        if kind == "dint":
            return f"{r.choice(INTS[6:])} := {self.int_expr()} * 1000;"
        if kind == "bool":
            return f"{r.choice(BOOLS)} := {self.bool_expr()};"
        if kind == "arr":
            return f"a[{r.randrange(1, 5)}] := {self.int_expr()};"
        if kind == "image":
            return r.choice([f"SA[{8 + r.randrange(8)}] := {self.bool_expr()};",
                             f"SYVAR[{4 + r.randrange(4)}] := {self.int_expr()};"])
        if kind == "if":
            return (f"IF {self.bool_expr()} THEN {self.stmt(depth + 1)} ELSIF "
                    f"{self.bool_expr()} THEN {self.stmt(depth + 1)} ELSE "
                    f"{self.stmt(depth + 1)} END_IF")
        if kind == "case":
            return (f"CASE {self.int_expr()} OF 0: {self.stmt(depth + 1)} 1, 2: "
                    f"{self.stmt(depth + 1)} -5..-1: {self.stmt(depth + 1)} ELSE "
                    f"{self.stmt(depth + 1)} END_CASE")
        if kind == "for":
            return (f"FOR n{depth} := {r.randrange(-2, 3)} TO {r.randrange(0, 6)} BY "
                    f"{r.choice([1, 2])} DO IF {self.bool_expr()} THEN CONTINUE; END_IF "
                    f"{self.stmt(depth + 1)} IF {self.bool_expr()} THEN EXIT; END_IF END_FOR")
        return (f"w{depth} := 0; WHILE w{depth} < {r.randrange(4)} DO w{depth} := w{depth} + 1; "
                f"{self.stmt(depth + 1)} END_WHILE")

    def program(self, statements: int) -> str:
        body = "\n".join(self.stmt() for _ in range(statements))
        return ("PROGRAM rnd\nVAR i0, i1, i2, i3, i4, i5, n0, n1, w0, w1 : INT; d0, d1 : DINT;\n"
                "b0, b1, b2, b3 : BOOL; a : ARRAY[1..4] OF INT; t : TON; c : CTU; END_VAR\n"
                "t(IN := SA[0], PT := T#30ms); c(CU := SA[1], R := SA[2], PV := 3);\n"
                f"{body}\nEND_PROGRAM\n")


@pytest.mark.parametrize("seed", range(40))
def test_compiled_and_walked_agree(seed: int) -> None:
    source = Gen(seed).program(25)
    files = [parse_source(source, "rnd.st")]
    context = Context(64, 16, 8, 5, frozenset())
    logic = compile_logic(files, context)
    image, walk_image = IOImage(64, 16, 8), IOImage(64, 16, 8)
    runtime = PlcRuntime(logic, image, RecordingNc(), ["rnd"])
    walker = Walker(files, context, walk_image.sa, walk_image.k, walk_image.syvar)
    rng = random.Random(seed)
    program = runtime.programs["RND"]
    for scan in range(12):
        inputs = [("SA", rng.randrange(8), "bit", rng.randrange(2)),
                  ("SYVAR", rng.randrange(4), "IN", rng.randrange(-32768, 32768))]
        image.write(inputs, "test")
        walk_image.write(inputs, "test")
        runtime.scan(scan * 10)
        faulted = runtime.status.fault
        try:
            walker.scan(scan * 10)
        except (ArithmeticError, IndexError, ValueError, IterationGuard) as exc:
            assert faulted is not None, f"only the walk failed: {exc}\n{source}"
            return
        assert faulted is None, f"only the compiled code failed: {faulted}\n{source}"
        for name, value in walker.state["RND"].items():
            got = getattr(program, f"v_{name}")
            if name == "T":
                got, value = (got.Q, got.ET), (value.Q, value.ET)
            elif name == "C":
                got, value = (got.Q, got.CV), (value.Q, value.CV)
            assert got == value, f"scan {scan}: {name}\n{source}"
        assert (bytes(image.sa), image.syvar) == (bytes(walk_image.sa), walk_image.syvar)


TYPED = """
TYPE
  E_Step : (IDLE, LOAD := 10, RUN, UNLOAD);
  Axis : STRUCT pos : DINT; target : DINT := 30; name : STRING[8] := 'ax'; END_STRUCT;
END_TYPE
FUNCTION_BLOCK Station
VAR_INPUT go : BOOL; part : INT; END_VAR
VAR_OUTPUT done : BOOL; count : DINT; END_VAR
VAR step : E_Step; ax : Axis; t : TON; label : STRING[16]; END_VAR
done := FALSE;
CASE step OF
  IDLE: IF go THEN step := E_Step#LOAD; ax.target := part * 3 + 10; END_IF
  LOAD: ax.pos := ax.pos + 4; IF ax.pos >= ax.target THEN step := RUN; END_IF
  RUN: t(IN := TRUE, PT := T#20ms); IF t.Q THEN t(IN := FALSE, PT := T#20ms); step := UNLOAD;
       END_IF
  UNLOAD: ax.pos := 0; count := count + 1; done := TRUE; label := CONCAT(ax.name, '-ok');
          step := IDLE;
END_CASE
END_FUNCTION_BLOCK
PROGRAM cell
VAR st : ARRAY[0..5] OF Station; n, at : INT; msg : STRING; last : E_Step; i : INT; END_VAR
FOR i := 0 TO 5 DO
  st[i](go := SA[i] OR i = 2, part := i);
  IF st[i].done THEN n := n + 1; msg := CONCAT(LEFT(msg, 20), 'd'); END_IF
END_FOR
at := FIND(msg, 'dd') + LEN(msg);
IF n > 3 THEN last := UNLOAD; ELSIF n > 1 THEN last := RUN; END_IF
END_PROGRAM
"""


def test_structures_enumerations_strings_and_user_fbs_read_alike_compiled_and_walked(
        ) -> None:
    # The second program of bench/plc.py is timed against the walker; here both readings
    # must agree on a smaller one, scan by scan, with inputs changing.
    files = [parse_source(TYPED, "typed.st")]
    context = Context()
    image, walk_image = IOImage(), IOImage()
    runtime = PlcRuntime(compile_logic(files, context), image, RecordingNc(), ["cell"])
    walker = Walker(files, context, walk_image.sa, walk_image.k, walk_image.syvar)
    rng = random.Random(29)
    for scan in range(120):
        if scan % 4 == 0:
            bits = [("SA", rng.randrange(6), "bit", rng.randrange(2))]
            image.write(bits, "test")
            walk_image.write(bits, "test")
        runtime.scan(scan * 10)
        walker.scan(scan * 10)
        program, state = runtime.programs["CELL"], walker.state["CELL"]
        for name in ("N", "AT", "MSG", "LAST"):
            assert getattr(program, f"v_{name}") == state[name], (scan, name)
        assert [s.v_COUNT for s in program.v_ST] == [s.state["COUNT"] for s in state["ST"]]
    assert runtime.programs["CELL"].v_N > 3  # the stations did complete parts
