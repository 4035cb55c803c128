"""No input gives a traceback (issue 29): the sizes generated I/O code reaches compile and
run -- a chain of 10,000 operators, 200 nested IFs and loops, 1,000 ELSIFs and CASE arms --
what is beyond the language's limits is ST031 at its position, and a seeded fuzz of
generated and then mutated programs finds each of them loads or gets coded diagnostics."""

from __future__ import annotations

import gc
import random

import pytest

from ncgate.plc.scan import PlcState
from ncgate.plc.st import logic
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.diagnostics import LogicError, StCode
from ncgate.plc.st.parser import parse_source

from .st_harness import Plc, program


def load_error(source: str) -> tuple[str, int, int]:
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "deep.st")])
    first = caught.value.diagnostics[0]
    return first.code.code, first.span.line, first.span.column


def test_a_sum_of_10000_terms_runs() -> None:
    terms = " + ".join(["one"] * 10_000)
    plc = Plc(program(f"s := {terms};", "one : DINT := 1; s : DINT;")).scan()
    assert plc["main.s"] == 10_000


def test_a_300_term_or_interlock_and_a_10000_term_and_run() -> None:
    ors = " OR ".join(f"b[{k}]" for k in range(1, 301))
    ands = " AND ".join(["t"] * 10_000)
    plc = Plc(program(f"b[300] := TRUE; any := {ors}; all := {ands} AND f;\n"
                      f"none := {ors.replace('b[300]', 'f')};",
                      "b : ARRAY[1..300] OF BOOL; t : BOOL := TRUE; f, any, all, none : BOOL;"))
    plc.scan()
    assert (plc["main.any"], plc["main.all"], plc["main.none"]) == (True, False, False)


def test_a_chain_keeps_left_to_right_order_and_and_still_guards_what_follows() -> None:
    # i <= 3 AND v[i] > 0 never reads v[4] (the operand after a FALSE is not evaluated,
    # 7.3.2): a chain cut into temporaries must still stop at the first FALSE.
    guard = " AND ".join(["ok"] * 40)
    plc = Plc(program(f"i := 4; r := {guard} AND i <= 3 AND v[i] > 0 AND {guard};",
                      "v : ARRAY[1..3] OF INT; i : INT; ok : BOOL := TRUE; r : BOOL;")).scan()
    assert plc.runtime.status.state is PlcState.RUNNING and plc["main.r"] is False


def test_200_nested_ifs_run_every_level() -> None:
    body = "IF n >= 0 THEN n := n + 1;\n" * 200 + " END_IF\n" * 200
    plc = Plc(program(body, "n : INT;")).scan()
    assert plc["main.n"] == 200


def test_200_nested_loops_with_exit_and_return_in_a_function() -> None:
    # Each WHILE runs its body once (i counts 0 -> 1); the innermost adds 1 to f three
    # times; RETURN from 200 loops deep ends the function; EXIT leaves one loop.
    levels = 200
    func = ("FUNCTION f : DINT VAR_INPUT stop : DINT; END_VAR VAR i : ARRAY[1..200] OF INT;"
            " k : INT; END_VAR\n"
            + "".join(f"i[{d}] := 0; WHILE i[{d}] < 1 DO i[{d}] := i[{d}] + 1;\n"
                      for d in range(1, levels + 1))
            + "FOR k := 1 TO 3 DO f := f + 1; IF f = stop THEN RETURN; END_IF END_FOR\n"
            + " END_WHILE\n" * levels + "f := f + 10;\nEND_FUNCTION\n")
    prog = ("PROGRAM main VAR full, cut, n : DINT; END_VAR\nfull := f(0); cut := f(2);\n"
            + "WHILE TRUE DO n := n + 1;\n" * levels + " EXIT; END_WHILE\n" * levels
            + "END_PROGRAM\n")
    plc = Plc(func + prog).scan()
    assert (plc["main.full"], plc["main.cut"], plc["main.n"]) == (13, 2, 200)


def test_return_continue_and_exit_from_deep_in_a_program_act_on_the_right_level() -> None:
    # RETURN 100 IFs deep ends the scan (after stays 0); 60 IFs inside a FOR, CONTINUE
    # skips k = 2 (the FOR still steps) and EXIT leaves at k = 4: c = 1 + 3, n = 2.
    deep_return = ("IF n >= 0 THEN n := n + 1;\n" * 100 + "CASE n OF 100: RETURN; END_CASE"
                   + " END_IF\n" * 100 + "after := 1;\n")
    deep_loop = ("FOR k := 1 TO 5 DO\n" + "IF k > 0 THEN\n" * 60
                 + "IF k = 2 THEN CONTINUE; END_IF IF k = 4 THEN EXIT; END_IF c := c + k;"
                 + " END_IF\n" * 60 + "m := m + 1; END_FOR\n")
    plc = Plc(program(deep_loop + deep_return, "n, after, c, m : DINT; k : INT;")).scan()
    assert (plc["main.n"], plc["main.after"]) == (100, 0)
    assert (plc["main.c"], plc["main.m"], plc["main.k"]) == (4, 2, 4)


def test_a_long_body_runs_in_order_returns_and_faults_at_its_line() -> None:
    """3,000 statements: the compiler cuts a long PROGRAM body into helper functions that
    Logic compiles one piece at a time (PIECE_LINES, PIECE_CHARS); the statements still run
    in their order, a RETURN ends the scan, and a fault in the last piece names its line."""
    body = "".join(f"x := x * 3 + {k};\n" for k in range(3000))  # order matters to x
    expected = 0
    for k in range(3000):
        expected = ((expected * 3 + k + 2**31) % 2**32) - 2**31
    plc = Plc(program(body + "IF x <> 0 THEN RETURN; END_IF\nafter := 1;",
                      "x, after : DINT;")).scan()
    assert (plc["main.x"], plc["main.after"]) == (expected, 0)
    assert len(plc.logic.python_source) > 3 * logic.PIECE_CHARS  # (several pieces)
    faulty = Plc(program(body + "v[x] := 1;", "x : DINT; v : ARRAY[1..2] OF INT;")).scan()
    fault = faulty.runtime.status.fault
    assert fault is not None and fault.span is not None
    assert fault.span.line == 5 + 3000 and "outside 1..2" in fault.message


def test_1000_elsifs_and_1000_case_arms_pick_their_branch() -> None:
    elsifs = "".join(f"ELSIF x = {k} THEN a := {k * 2};\n" for k in range(1, 1000))
    arms = "".join(f"{k}: c := {k * 3};\n" for k in range(1000))
    plc = Plc(program(f"x := 777;\nIF x = 0 THEN a := -1;\n{elsifs}END_IF\n"
                      f"CASE x OF\n{arms}ELSE c := -1; END_CASE\n"
                      "CASE x + 1000 OF\n" + arms + "ELSE e := -1; END_CASE",
                      "x, a, c, e : DINT;")).scan()
    assert (plc["main.a"], plc["main.c"], plc["main.e"]) == (1554, 2331, -1)


@pytest.mark.parametrize(("source", "line", "column"), [
    (program("b := " + "NOT " * 10_000 + "b;", "b : BOOL;"), 5, 6 + 4 * 64),
    (program("x := " + "x + (" * 1000 + "x" + ")" * 1000 + ";", "x : DINT;"), 5, 8 + 5 * 64),
    (program("IF x > 0 THEN\n" * 600 + "x := 0;" + " END_IF" * 600, "x : DINT;"), 517, 1),
], ids=["10000-NOTs", "1000-nested-parentheses-right", "600-nested-IFs"])
def test_nesting_beyond_the_limits_is_st031_where_it_starts(source: str, line: int,
                                                            column: int) -> None:
    assert load_error(source) == ("ST031", line, column)


def test_10000_parentheses_around_one_value_are_just_that_value() -> None:
    plc = Plc(program("x := " + "(" * 10_000 + "41 + 1" + ")" * 10_000 + ";", "x : INT;"))
    assert plc.scan()["main.x"] == 42


# ---- the fuzz --------------------------------------------------------------------------------

DECLS = "a, i : INT; b, c : BOOL; r : REAL; v : ARRAY[1..4] OF INT; t : TON; cnt : CTU;"
# Token soup for mutations: keywords, operators, odd literals, punctuation.
SOUP = ["IF", "THEN", "ELSE", "END_IF", "FOR", "TO", "BY", "DO", "END_FOR", "WHILE",
        "END_WHILE", "REPEAT", "UNTIL", "END_REPEAT", "CASE", "OF", "END_CASE", "EXIT",
        "RETURN", "CONTINUE", "VAR", "END_VAR", ":=", "=>", ";", ":", ",", "(", ")", "[", "]",
        ".", "..", "+", "-", "*", "/", "**", "MOD", "AND", "OR", "XOR", "NOT", "<", ">=", "<>",
        "0", "-1", "32767", "65536", "1e39", "1.5", "16#FF", "2#102", "1__0", "T#5ms3s",
        "T#1.5s500ms", "T#30d", "DINT#-16#10", "INT#40000", "REAL#1e39", "TRUE", "(*", "*)",
        "/*", "*/", "//", "{", "}", "'s'", "$", "by", "do", "TYPE", "STRUCT", "SIN(", "LN(",
        "EXPT(", "REAL_TO_INT(", "TRUNC(", "ABS(", "MUX(", "SA[", "SYVAR[", "NC.P[1].", "t.Q",
        "t(IN := ", "f(", "v[", "i", "x", "a", "r", "tm"]


class Fuzz:
    """Mostly well-typed programs (INT, BOOL and REAL expressions kept apart), then, for
    most, a few words deleted, inserted or replaced from SOUP."""

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)

    def num(self, depth: int = 0) -> str:
        r = self.rng
        if depth > 1 or r.random() < 0.45:
            return r.choice(["a", "i", "v[i]", "v[2]", "cnt.CV", "SYVAR[1]", "NC.P[1].STATE",
                             "3", "-7", "32767", "INT#-3"])
        a, b = self.num(depth + 1), self.num(depth + 1)
        return r.choice([f"({a} + {b})", f"{a} - {b}", f"({a} * {b})", f"({a} / {b})",
                         f"{a} MOD {b}", f"-{a}", f"ABS({a})", f"MIN({a}, {b})",
                         f"LIMIT({a}, {b}, 3)", f"SEL({self.cond(depth + 1)}, {a}, {b})",
                         f"MUX({a}, 1, 2)", f"REAL_TO_INT({self.real(depth + 1)})",
                         " + ".join([a] * r.randrange(2, 8))])

    def real(self, depth: int = 0) -> str:
        r = self.rng
        if depth > 1 or r.random() < 0.45:
            return r.choice(["r", "2.5", "1.0E3", "0.0", "INT_TO_REAL(a)"])
        a, b = self.real(depth + 1), self.real(depth + 1)
        return r.choice([f"({a} + {b})", f"({a} * {b})", f"({a} / {b})", f"({a} ** {b})",
                         f"SQRT({a})", f"EXPT({a}, {b})", f"SIN({a})", f"LN({a})"])

    def cond(self, depth: int = 0) -> str:
        r = self.rng
        if depth > 1 or r.random() < 0.45:
            return r.choice(["b", "c", "TRUE", "t.Q", "SA[3]", "NC.P[2].IDLE"])
        a, b = self.cond(depth + 1), self.cond(depth + 1)
        return r.choice([f"{a} AND {b}", f"({a} OR {b})", f"{a} XOR {b}", f"NOT {a}",
                         f"({self.num(depth + 1)} < {self.num(depth + 1)})",
                         f"{self.num(depth + 1)} = {self.num(depth + 1)}",
                         f"{self.real(depth + 1)} >= {self.real(depth + 1)}"])

    def stmts(self, depth: int = 0) -> str:
        r = self.rng
        out = []
        for _ in range(r.randrange(1, 3)):
            kind = r.choice(["num", "num", "bool", "real"] + (
                ["if", "case", "for", "while", "repeat"] if depth < 1 else []) + [
                "call", "jump"])
            if r.random() < 0.005:  # now and then, the sizes generated I/O code reaches
                out.append(r.choice([
                    f"b := {' OR '.join(['c'] * r.randrange(200, 260))};",
                    "IF b THEN a := 1;\n" * (k := r.randrange(100, 120)) + " END_IF" * k]))
            elif kind == "num":
                out.append(f"{r.choice(['a', 'i', 'v[i]', 'SYVAR[0]'])} := {self.num()};")
            elif kind == "bool":
                out.append(f"{r.choice(['b', 'c', 'SA[2]', 'NC.START'])} := {self.cond()};")
            elif kind == "real":
                out.append(f"r := {self.real()};")
            elif kind == "if":
                out.append(f"IF {self.cond()} THEN {self.stmts(depth + 1)} ELSIF "
                           f"{self.cond()} THEN {self.stmts(depth + 1)} ELSE "
                           f"{self.stmts(depth + 1)} END_IF")
            elif kind == "case":
                out.append(f"CASE {self.num()} OF 1: {self.stmts(depth + 1)} 2..5, 9: "
                           f"{self.stmts(depth + 1)} ELSE {self.stmts(depth + 1)} END_CASE")
            elif kind == "for":
                out.append(f"FOR i := {self.num()} TO {self.num()} BY "
                           f"{r.choice(['1', '-2', 'a'])} DO {self.stmts(depth + 1)} END_FOR")
            elif kind == "while":
                out.append(f"WHILE {self.cond()} DO {self.stmts(depth + 1)} END_WHILE")
            elif kind == "repeat":
                out.append(f"REPEAT {self.stmts(depth + 1)} UNTIL {self.cond()} END_REPEAT")
            elif kind == "call":
                out.append(r.choice(["t(IN := b, PT := T#20ms);", "cnt(CU := b, PV := 3);",
                                     f"t(IN := {self.cond()}, PT := T#5ms, Q => c);"]))
            else:
                out.append(r.choice(["EXIT;", "CONTINUE;", "RETURN;"]))
        return "\n".join(out)

    def source(self) -> str:
        r = self.rng
        text = (f"PROGRAM main\nVAR\n{DECLS}\nEND_VAR\n{self.stmts()}\nEND_PROGRAM\n")
        if r.random() < 0.5:  # mutate
            words = text.split(" ")
            for _ in range(r.randrange(1, 4)):
                k = r.randrange(len(words))
                action = r.random()
                if action < 0.3:
                    del words[k]
                elif action < 0.7:
                    words.insert(k, r.choice(SOUP))
                else:
                    words[k] = r.choice(SOUP)
            text = " ".join(words)
        return text


@pytest.mark.parametrize("seed", range(4))  # 4 x 550: 2,200 programs a run
def test_generated_programs_load_or_get_coded_diagnostics_with_positions(seed: int) -> None:
    loaded = refused = 0
    for k in range(550):
        fuzz = Fuzz(seed * 1000 + k)
        source = fuzz.source()
        lines = source.count("\n") + 1
        try:
            plc = Plc(source, loop_limit=500)
        except LogicError as exc:
            refused += 1
            assert exc.diagnostics, source
            for d in exc.diagnostics:
                assert isinstance(d.code, StCode), source
                assert 1 <= d.span.line <= lines and d.span.column >= 1, (d.render(), source)
                assert d.code.code in d.render()
            continue
        loaded += 1
        plc.scan(2)  # a runtime error is a FAULT, and nothing escapes the scan
        assert plc.runtime.status.state in (PlcState.RUNNING, PlcState.FAULT)
    assert loaded > 60 and refused > 60, (loaded, refused)  # both kinds are exercised


# The data types, strings and declarations of issue 29 go through the same mill.
TYPED_HEAD = """{attribute 'qualified_only'}
TYPE
  E : (IDLE, RUN := 5, DONE);
  P : STRUCT x : INT := 1; s : STRING[8]; END_STRUCT;
  R : INT(0..100);
END_TYPE
VAR_GLOBAL CONSTANT N : INT := 4; END_VAR
VAR_GLOBAL g : P; END_VAR
FUNCTION_BLOCK Fb
VAR_INPUT k : INT; END_VAR VAR_IN_OUT io : INT; END_VAR VAR_OUTPUT q : BOOL; END_VAR
io := io + k; q := io > N;
END_FUNCTION_BLOCK
"""
TYPED_DECLS = (DECLS + " e : E; p : P; pts : ARRAY[1..N, 0..1] OF P; s : STRING; "
               "w : WORD; sub : R; d : DT; lt : LTIME; f : Fb;")
TYPED_SOUP = [*SOUP, "E#RUN", "E.RUN", "RUN", "p.x", "p.s", "pts[1, 0].x", "w.3", "w.%X3",
              "'a$N'", '"w"', "STRING[", "LEN(", "MID(", "CONCAT(", "N", "g.x", "sub",
              "D#2024-02-30", "DT#2024-01-01-1:2:3", "TOD#25:00", "LT#1ms5us", "VAR_IN_OUT",
              "VAR_GLOBAL", "END_STRUCT", "END_TYPE", "(x := 1)", "[1, 2(3)]", "{", "}",
              "f(k := 1, io := a);", "AND_THEN", "OR_ELSE"]


class TypedFuzz(Fuzz):
    def stmts(self, depth: int = 0) -> str:
        r = self.rng
        extra = [
            f"p.x := {self.num()};", "p.s := CONCAT(p.s, 'ab');", "s := MID(s, a, i);",
            "a := LEN(s) + FIND(s, 'b');", "e := E#RUN;", "IF e = DONE THEN e := IDLE; END_IF",
            "CASE e OF IDLE: e := RUN; RUN, DONE: e := E#IDLE; END_CASE",
            f"pts[{r.choice(['1', 'N', 'i'])}, 1].x := {self.num()};", f"w.3 := {self.cond()};",
            f"b := w.{r.choice(['0', '15', '16'])};", "sub := sub + 30;", "d := d + T#1h;",
            "lt := lt * 2;", "f(k := a, io := i, q => b);", "g := p; g.x := g.x + 1;",
            "s := LEFT(s, a); s := INSERT(s, 'x', i);",
        ]
        return "\n".join([super().stmts(depth), *r.sample(extra, r.randrange(1, 4))])

    def source(self) -> str:
        r = self.rng
        text = (f"{TYPED_HEAD}PROGRAM main\nVAR\n{TYPED_DECLS}\nEND_VAR\n{self.stmts()}\n"
                "END_PROGRAM\n")
        if r.random() < 0.6:
            words = text.split(" ")
            for _ in range(r.randrange(1, 4)):
                k = r.randrange(len(words))
                action = r.random()
                if action < 0.3:
                    del words[k]
                elif action < 0.7:
                    words.insert(k, r.choice(TYPED_SOUP))
                else:
                    words[k] = r.choice(TYPED_SOUP)
            text = " ".join(words)
        return text


@pytest.mark.parametrize("seed", range(2))  # 2 x 300 more, with the types of issue 29
def test_generated_typed_programs_load_or_get_coded_diagnostics(seed: int) -> None:
    loaded = refused = 0
    for k in range(300):
        source = TypedFuzz(50_000 + seed * 1000 + k).source()
        lines = source.count("\n") + 1
        try:
            plc = Plc(source, loop_limit=500)
        except LogicError as exc:
            refused += 1
            for d in exc.diagnostics:
                assert isinstance(d.code, StCode), source
                assert 1 <= d.span.line <= lines and d.span.column >= 1, (d.render(), source)
            continue
        loaded += 1
        plc.scan(2)
        assert plc.runtime.status.state in (PlcState.RUNNING, PlcState.FAULT)
    assert loaded > 30 and refused > 30, (loaded, refused)


def test_loaded_logic_leaves_the_syntax_tree_to_be_freed() -> None:
    """The logic keeps what a fault's location needs, not the parsed program: a reload of
    big logic otherwise left hundreds of thousands of nodes for the cyclic collector to walk
    on every collection -- 130 to 340 ms pauses on the loop's thread (docs/decisions.md)."""
    statements = 2000
    body = "".join(f"x := x * 3 + {k};\nIF x > {k} THEN y := NOT y; END_IF\n"
                   for k in range(statements))
    source = program(body, "x : DINT; y : BOOL;")
    compile_logic([parse_source(program("x := 1;", "x : INT;"), "warm.st")])  # (lark's own)
    gc.collect()
    before = len(gc.get_objects())
    parsed = parse_source(source, "big.st")
    logic = compile_logic([parsed], Context())
    del parsed
    gc.collect()
    kept = len(gc.get_objects()) - before
    assert logic.programs and kept < statements, kept  # the tree: > 30 nodes a statement


def test_the_parse_tree_is_freed_a_piece_at_a_time_and_what_is_held_stays() -> None:
    """lark's tree of a file is taken apart node by node once the syntax tree is built (its
    last reference dropped at once freed 460,000 nodes in one 107 ms call into C: a big
    reload's longest hold of the interpreter); a node something else holds is left whole."""
    import weakref

    from lark import Token, Tree

    from ncgate.plc.st.parser import _dismantle

    held = Tree("held", [Tree("inner", [Token("NAME", "a")])])
    root = Tree("root", [Tree("a", [Tree("b", [Token("NAME", "x")]), held]),
                         Tree("c", [Token("NAME", "y")])])
    a, b = weakref.ref(root.children[0]), weakref.ref(root.children[0].children[0])
    _dismantle(root)
    assert root.children == [] and a() is None and b() is None  # freed as it went
    assert held.children[0].children == [Token("NAME", "a")]  # held here: left whole
