"""plc.strict (issue 29, item 3): strict IEC 61131-3 by default; with plc.strict = false the
logic CODESYS accepts loads -- implicit narrowing (IEC 61131-3, 6.4.2 allows only the
widening conversions of Figure 11), an enumeration used as an integer (6.4.4.2: a distinct
type), E.RUN for E#RUN (6.4.4.2), AND_THEN/OR_ELSE for AND/OR (7.3.2 knows only these) --
each with an SW warning that gives the IEC spelling, at its position; the values are as
CODESYS computes them (a narrowed integer wraps to its type)."""

from __future__ import annotations

import pytest

from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.diagnostics import LogicError
from ncgate.plc.st.parser import parse_source

from .st_harness import Plc

LENIENT = Context(64, 16, 8, 5, frozenset({4, 5}), strict=False)

CASES = [
    # (source; the line and column of the construct; its error when strict; its warning)
    ("PROGRAM main VAR d : DINT := 70000; i : INT; END_VAR\ni := d;\nEND_PROGRAM", 2, 6,
     "ST020", "SW001"),
    ("PROGRAM main VAR l : LREAL := 0.1; r : REAL; END_VAR\nr := l;\nEND_PROGRAM", 2, 6,
     "ST020", "SW001"),
    ("TYPE E : (A, B, C); END_TYPE\nPROGRAM main VAR e : E; i : INT; END_VAR\n"
     "e := C;\ni := e;\nEND_PROGRAM", 4, 6, "ST020", "SW003"),
    ("TYPE E : (A, B, C); END_TYPE\nPROGRAM main VAR st : E; b : BOOL; END_VAR\n"
     "b := st = 2;\nEND_PROGRAM", 3, 9, "ST020", "SW003"),
    ("TYPE E : (A, B, C); END_TYPE\nPROGRAM main VAR st : E; END_VAR\n"
     "st := E.B;\nEND_PROGRAM", 3, 7, "ST020", "SW002"),
    ("PROGRAM main VAR a, b, c : BOOL; END_VAR\nc := a AND_THEN b;\nEND_PROGRAM", 2, 8,
     "ST031", "SW002"),
    ("PROGRAM main VAR a, b, c : BOOL; END_VAR\nc := a OR_ELSE b;\nEND_PROGRAM", 2, 8,
     "ST031", "SW002"),
    ("PROGRAM main VAR w : WORD; b : BOOL; END_VAR\nb := w.%X3;\nEND_PROGRAM", 2, 8,
     "ST031", "SW002"),
    ("FUNCTION Noop : VOID\nVAR_INPUT x : INT; END_VAR\nEND_FUNCTION\n"
     "PROGRAM main\nNoop(1);\nEND_PROGRAM", 1, 17, "ST011", "SW002"),
    # logi.CAD: ARRAY[..] for IEC's ARRAY[*] (6.5.3), _firstIndexOf/_lastIndexOf for its
    # LOWER_BOUND/UPPER_BOUND(a, 1)
    ("FUNCTION F : INT\nVAR_IN_OUT a : ARRAY[..] OF INT; END_VAR\nF := a[1];\n"
     "END_FUNCTION", 2, 16, "ST031", "SW002"),
    ("FUNCTION F : DINT\nVAR_IN_OUT a : ARRAY[*] OF INT; END_VAR\n"
     "F := _firstIndexOf(a);\nEND_FUNCTION", 3, 6, "ST012", "SW002"),
    ("FUNCTION F : DINT\nVAR_IN_OUT a : ARRAY[*] OF INT; END_VAR\n"
     "F := _lastIndexOf(a);\nEND_FUNCTION", 3, 6, "ST012", "SW002"),
]


@pytest.mark.parametrize(("source", "line", "column", "error", "warning"), CASES)
def test_strict_refuses_and_lenient_loads_with_a_warning_at_the_same_place(
        source: str, line: int, column: int, error: str, warning: str) -> None:
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "s.st")], Context())
    d = caught.value.diagnostics[0]
    assert (d.code.code, d.span.line, d.span.column, d.is_error) == (error, line, column, True)
    logic = compile_logic([parse_source(source, "s.st")], LENIENT)
    w = logic.warnings[0]
    assert (w.code.code, w.span.line, w.span.column, w.is_error) == (
        warning, line, column, False)
    assert "warning SW" in w.render()


def test_lenient_values_are_codesys_ones() -> None:
    plc = Plc("TYPE E : (A, B, C); END_TYPE\nPROGRAM main\nVAR d : DINT := 70000; "
              "i : INT; e : E; n : INT; l : LREAL := 0.1; r : REAL; a, b : BOOL; "
              "w : WORD := 8; bit3 : BOOL; END_VAR\n"
              "i := d; e := C; n := e; r := l; b := a AND_THEN (1 / n > 0); e := 1;\n"
              "bit3 := w.%X3; w.%X0 := TRUE;\n"
              "END_PROGRAM", context=LENIENT).scan()
    # 70000 wraps to INT: 70000 - 65536 = 4464; C is 2; REAL 0.1 is single's nearest.
    assert (plc["main.i"], plc["main.n"], plc["main.e"]) == (4464, 2, 1)
    assert plc["main.r"] == 0.10000000149011612 and plc["main.b"] is False
    assert (plc["main.bit3"], plc["main.w"]) == (True, 9)


def test_strict_says_to_write_array_star_once_and_lenient_names_the_iec_spelling() -> None:
    source = ("FUNCTION F : INT\nVAR_IN_OUT a : ARRAY[..] OF INT; END_VAR\nF := a[1];\n"
              "END_FUNCTION")
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "s.st")], Context())
    # one diagnostic: the declaration is read as ARRAY[*] after it, so a[1] adds none
    assert [d.code.code for d in caught.value.diagnostics] == ["ST031"]
    assert "ARRAY[*]" in caught.value.diagnostics[0].message
    (w,) = compile_logic([parse_source(source, "s.st")], LENIENT).warnings
    assert "ARRAY[*]" in w.message


def test_an_array_dots_parameter_takes_any_array_and_its_bounds_are_the_callers() -> None:
    """IEC 61131-3, 6.5.3: an ARRAY[*] VAR_IN_OUT is the caller's array, its bounds those
    LOWER_BOUND/UPPER_BOUND give; logi.CAD's ARRAY[..] and _firstIndexOf/_lastIndexOf are
    the same (plc.strict = false)."""
    plc = Plc("FUNCTION Span : DINT\nVAR_IN_OUT a : ARRAY[..] OF INT; END_VAR\n"
              "VAR i : DINT; END_VAR\n"
              "Span := _lastIndexOf(a) - _firstIndexOf(a) + 1;\n"
              "FOR i := _firstIndexOf(a) TO _lastIndexOf(a) DO a[i] := a[i] * 2; END_FOR;\n"
              "END_FUNCTION\n"
              "PROGRAM main\nVAR x : ARRAY[-2..1] OF INT := [1, 2, 3, 4]; "
              "y : ARRAY[5..6] OF INT := [7, 8]; nx, ny, lo, hi : DINT; END_VAR\n"
              "nx := Span(x); ny := Span(y);\n"
              "lo := LOWER_BOUND(x, 1); hi := UPPER_BOUND(x, 1);\n"
              "END_PROGRAM", context=LENIENT).scan()
    assert (plc["main.nx"], plc["main.ny"], plc["main.lo"], plc["main.hi"]) == (4, 2, -2, 1)
    assert (plc["main.x"], plc["main.y"]) == ([2, 4, 6, 8], [14, 16])
