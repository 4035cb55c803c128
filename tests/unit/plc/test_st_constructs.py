"""Constructs of IEC 61131-3 3rd ed. the subset now has (issue 29): CONTINUE (7.3.3.4.4),
nested comments and ``/* */`` (6.1.5), the numeric functions EXP ... ATAN (Table 23), and a
FUNCTION called as a statement (7.3.3.2).  Expected values are the standard's rules worked
by hand, and for the functions IEEE 754 single precision of the exact mathematical value."""

from __future__ import annotations

import math

import pytest

from ncgate.plc.scan import PlcState

from .st_harness import Plc, program


def test_continue_skips_the_rest_of_a_for_body_and_still_steps() -> None:
    # Sum of the odd numbers 1..9 (25); the FOR still ends at 11 (its last step).
    plc = Plc(program("FOR i := 1 TO 10 DO IF i MOD 2 = 0 THEN CONTINUE; END_IF "
                      "s := s + i; END_FOR", "i, s : INT;")).scan()
    assert (plc["main.s"], plc["main.i"]) == (25, 11)


def test_continue_in_while_retests_and_in_repeat_tests_until() -> None:
    plc = Plc(program("""
        WHILE n < 6 DO n := n + 1; IF n < 4 THEN CONTINUE; END_IF w := w + 1; END_WHILE
        REPEAT k := k + 1; IF k > 0 THEN CONTINUE; END_IF r := 100; UNTIL k >= 3 END_REPEAT
    """, "n, w, k, r : INT;")).scan()
    # WHILE: n = 4, 5, 6 reach w (3); REPEAT: CONTINUE goes to UNTIL, r never set, k = 3.
    assert (plc["main.w"], plc["main.k"], plc["main.r"]) == (3, 3, 0)


def test_continue_applies_to_the_innermost_loop() -> None:
    plc = Plc(program("FOR i := 1 TO 3 DO FOR j := 1 TO 3 DO IF j = 2 THEN CONTINUE; END_IF "
                      "c := c + 1; END_FOR END_FOR", "i, j, c : INT;")).scan()
    assert plc["main.c"] == 6


def test_comments_nest_and_slash_star_comments_and_line_comments_are_ignored() -> None:
    plc = Plc(program("""
        (* outer (* inner x := 1; *) still a comment x := 2; *)
        /* a /* nested */ block x := 3; */
        x := x + 10; // x := 4;
        y := 5 (* mid-expression *) + 1;
    """, "x, y : INT;")).scan()
    assert (plc["main.x"], plc["main.y"]) == (10, 6)


def test_a_comment_keeps_positions_for_diagnostics() -> None:
    from ncgate.plc.st.compiler import compile_logic
    from ncgate.plc.st.diagnostics import LogicError
    from ncgate.plc.st.parser import parse_source
    source = "PROGRAM p (* one\n(* two *) *) VAR x : INT; END_VAR\nx := nope; END_PROGRAM\n"
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "c.st")])
    d = caught.value.diagnostics[0]
    assert (d.code.code, d.span.line, d.span.column) == ("ST010", 3, 6)


def single(x: float) -> float:
    """The binary32 nearest to x, worked from its significand (24 bits)."""
    mantissa, exponent = math.frexp(x)
    return round(mantissa * 2**24) / 2**24 * 2.0**exponent


@pytest.mark.parametrize(("call", "exact"), [
    ("SIN(0.0)", 0.0), ("COS(0.0)", 1.0), ("EXP(0.0)", 1.0), ("LN(1.0)", 0.0),
    ("LOG(100.0)", 2.0), ("TAN(0.0)", 0.0), ("ASIN(1.0)", math.pi / 2),
    ("ACOS(0.0)", math.pi / 2), ("ATAN(1.0)", math.pi / 4), ("EXP(1.0)", math.e),
])
def test_the_numeric_functions_give_the_nearest_single(call: str, exact: float) -> None:
    plc = Plc(program(f"r := {call}; l := LREAL#1.0 * {call.replace('(', '(LREAL#')};",
                      "r : REAL; l : LREAL;")).scan()
    assert plc["main.r"] == (single(exact) if exact else 0.0)
    assert plc["main.l"] == pytest.approx(exact, rel=1e-15, abs=1e-300)


@pytest.mark.parametrize("call", ["LN(0.0)", "LOG(-1.0)", "ASIN(2.0)", "EXP(1000.0)"])
def test_a_numeric_function_outside_its_domain_faults_and_names_itself(call: str) -> None:
    plc = Plc(program(f"r := {call.replace('(', '(x + ')};", "r : REAL; x : REAL;")).scan()
    assert plc.runtime.status.state is PlcState.FAULT
    assert call.split("(")[0] in plc.nc.faults[0]


def test_a_function_called_as_a_statement_runs_and_its_result_is_dropped() -> None:
    plc = Plc("""
FUNCTION mark : BOOL
VAR_INPUT bit : INT; END_VAR
SA[bit] := TRUE; mark := TRUE;
END_FUNCTION
PROGRAM main
mark(3); mark(bit := 5);
END_PROGRAM
""").scan()
    assert [plc.image.read("SA", k, "bit") for k in (3, 4, 5)] == [1, 0, 1]
