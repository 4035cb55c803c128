"""The diagnostics corpus of the Structured Text front end: each case marks with ``¦`` the
column where the diagnostic must point (chosen by hand from the rule it breaks), and names
its stable code."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.diagnostics import LogicError
from ncgate.plc.st.parser import parse_file, parse_source

MARK = "¦"
CONTEXT = Context(64, 16, 8, 5, frozenset({4, 5}))

CASES = [
    # syntax
    ("ST002", "PROGRAM p VAR x : INT; END_VAR\nx := ¦; END_PROGRAM"),
    ("ST001", "PROGRAM p VAR x : INT; END_VAR\nx := 5 ¦$ 3; END_PROGRAM"),
    ("ST002", "PROGRAM p VAR x : INT; END_VAR\nIF x > 1 ¦x := 2; END_IF END_PROGRAM"),
    ("ST005", "PROGRAM p VAR b : BOOL; END_VAR\nb := ¦BOOL#2; END_PROGRAM"),
    # names
    ("ST010", "PROGRAM p VAR counter : INT; END_VAR\n¦countr := 1; END_PROGRAM"),
    ("ST011", "PROGRAM p VAR x : ¦INTEGER; END_VAR\nEND_PROGRAM"),
    ("ST031", "PROGRAM p VAR x : ¦LDATE; END_VAR\nEND_PROGRAM"),
    # characters (IEC 61131-3 3rd ed.): a typed CHAR literal is one character, a constant
    # character index lies in the declared length, s[i] is a CHAR (no implicit BYTE)
    ("ST005", "PROGRAM p VAR c : CHAR; END_VAR\nc := ¦CHAR#'AB'; END_PROGRAM"),
    ("ST022", "PROGRAM p VAR s : STRING[4]; c : CHAR; END_VAR\nc := s[¦5]; END_PROGRAM"),
    ("ST022", "PROGRAM p VAR s : STRING[4]; END_VAR\ns[¦0] := 'A'; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR s : STRING; b : BYTE; END_VAR\nb := ¦s[1]; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR s : STRING; END_VAR\ns[1] := ¦65; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR s : STRING; c : CHAR; END_VAR\nc := ¦s; END_PROGRAM"),
    ("ST031", "PROGRAM p VAR c : CHAR; i : INT; END_VAR\ni := ¦CHAR_TO_INT(c); END_PROGRAM"),
    ("ST012", "PROGRAM p VAR x : INT; END_VAR\nx := ¦FOO(1); END_PROGRAM"),
    ("ST012", "PROGRAM p VAR x : BOOL; END_VAR\nx := ¦TON(IN := TRUE); END_PROGRAM"),
    ("ST013", "PROGRAM p VAR a : INT; ¦a : BOOL; END_VAR\nEND_PROGRAM"),
    ("ST013", "PROGRAM p VAR ¦SA : INT; END_VAR\nEND_PROGRAM"),
    ("ST014", "PROGRAM p VAR t : TON; b : BOOL; END_VAR\nb := t.¦QQ; END_PROGRAM"),
    ("ST014", "PROGRAM p VAR x : INT; END_VAR\nx := NC.P[1].¦STATUS; END_PROGRAM"),
    ("ST014", "PROGRAM p VAR x : INT; END_VAR\nx := NC.¦EVENT; END_PROGRAM"),
    ("ST014", "FUNCTION_BLOCK f VAR hidden : INT; END_VAR END_FUNCTION_BLOCK\n"
              "PROGRAM p VAR i : f; x : INT; END_VAR\nx := i.¦hidden; END_PROGRAM"),
    # types
    ("ST020", "PROGRAM p VAR b : BOOL; END_VAR\nb := ¦5; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR i : INT; d : DINT; END_VAR\ni := ¦d; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR i : INT; END_VAR\nIF ¦i THEN i := 0; END_IF END_PROGRAM"),
    ("ST020", "PROGRAM p VAR t : TIME; END_VAR\nt := ¦1000; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR r : REAL; i : INT; END_VAR\ni := ¦r; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR b : BOOL; i : INT; END_VAR\nb := b ¦AND i; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR x : INT; END_VAR\nSK[0] := ¦x; END_PROGRAM"),
    ("ST021", "PROGRAM p VAR s : SINT; END_VAR\ns := ¦200; END_PROGRAM"),
    ("ST021", "PROGRAM p VAR s : INT := ¦40000; END_VAR\nEND_PROGRAM"),
    ("ST022", "PROGRAM p VAR b : BOOL; END_VAR\nb := SA[¦64]; END_PROGRAM"),
    ("ST022", "PROGRAM p VAR v : ARRAY[1..10] OF INT; END_VAR\nv[¦11] := 0; END_PROGRAM"),
    ("ST022", "PROGRAM p VAR x : INT; END_VAR\nx := NC.P[¦6].STATE; END_PROGRAM"),
    ("ST022", "PROGRAM p VAR x : INT; END_VAR\nx := SYVAR[¦8]; END_PROGRAM"),
    ("ST023", "PROGRAM p VAR x : INT; END_VAR\n¦NC.P[1].STATE := 1; END_PROGRAM"),
    ("ST023", "PROGRAM p VAR t : TON; END_VAR\n¦t.Q := TRUE; END_PROGRAM"),
    ("ST023", "PROGRAM p VAR CONSTANT k : INT := 1; END_VAR\n¦k := 2; END_PROGRAM"),
    ("ST023", "PROGRAM p VAR i : INT; END_VAR\nFOR i := 1 TO 3 DO ¦i := 5; END_FOR END_PROGRAM"),
    ("ST023", "PROGRAM p VAR b : BOOL; END_VAR\n¦NC.EVENTS := 1; END_PROGRAM"),
    ("ST024", "PROGRAM p VAR t : TON; END_VAR\nt(¦TRUE); END_PROGRAM"),
    ("ST024", "PROGRAM p VAR t : TON; END_VAR\nt(IN := TRUE, ¦IN := FALSE); END_PROGRAM"),
    ("ST024", "PROGRAM p VAR t : TON; b : BOOL; END_VAR\nt(¦Q := b); END_PROGRAM"),
    ("ST024", "PROGRAM p VAR x : INT; END_VAR\nx := ¦LIMIT(1, 2); END_PROGRAM"),
    ("ST025", "PROGRAM p VAR x : INT; END_VAR\n¦x(); END_PROGRAM"),
    ("ST026", "PROGRAM p VAR x : INT; END_VAR\n¦EXIT; END_PROGRAM"),
    ("ST027", "PROGRAM p VAR x : INT; END_VAR\nx := 5 / ¦0; END_PROGRAM"),
    ("ST027", "PROGRAM p VAR x : INT; END_VAR\nx := x MOD ¦0; END_PROGRAM"),
    ("ST028", "PROGRAM p VAR x : INT; y : INT := ¦x; END_VAR\nEND_PROGRAM"),
    # structure
    ("ST030", "¦FUNCTION f : INT VAR_INPUT a : INT; END_VAR f := f(a); END_FUNCTION"),
    ("ST030", "¦FUNCTION_BLOCK fb VAR me : fb; END_VAR END_FUNCTION_BLOCK"),
    ("ST031", "FUNCTION f : INT VAR RETAIN ¦n : INT; END_VAR f := n; END_FUNCTION"),
    ("ST031", "FUNCTION f : INT VAR t : ¦TON; END_VAR f := 1; END_FUNCTION"),
    # outside the subset (issue 29): ST031 where the construct starts
    ("ST031", "PROGRAM p VAR x ¦AT %IX0.0 : BOOL; END_VAR\nEND_PROGRAM"),
    ("ST031", "PROGRAM p VAR q : ¦POINTER TO INT; END_VAR\nEND_PROGRAM"),
    ("ST031", "PROGRAM p VAR q : ¦REF_TO INT; END_VAR\nEND_PROGRAM"),
    ("ST031", "PROGRAM p VAR w : WORD; b : BOOL; END_VAR\nb := w.¦%X3; END_PROGRAM"),
    ("ST031", "PROGRAM p VAR_IN_OUT ¦x : INT; END_VAR END_PROGRAM"),
    ("ST031", "FUNCTION f : INT VAR_IN_OUT a : INT; END_VAR f := a; END_FUNCTION\n"
              "PROGRAM p VAR x : INT; END_VAR\nx := 1 + ¦f(x); END_PROGRAM"),
    ("ST031", "PROGRAM p VAR s : STRING; END_VAR\ns := ¦TIME_TO_STRING(T#1s); END_PROGRAM"),
    # data types, constants, strings, bits, VAR_IN_OUT (issue 29)
    ("ST013", "TYPE E : (A, B); END_TYPE TYPE ¦E : INT; END_TYPE PROGRAM p END_PROGRAM"),
    ("ST013", "TYPE E : (A, B, ¦A); END_TYPE PROGRAM p END_PROGRAM"),
    ("ST030", "TYPE ¦S : STRUCT s : S; END_STRUCT END_TYPE PROGRAM p END_PROGRAM"),
    ("ST014", "TYPE S : STRUCT a : INT; END_STRUCT END_TYPE\nPROGRAM p VAR s : S; END_VAR\n"
              "s.¦b := 1; END_PROGRAM"),
    ("ST014", "TYPE S : STRUCT a : INT; END_STRUCT END_TYPE\n"
              "PROGRAM p VAR s : S := (a := 1, ¦c := 2); END_VAR END_PROGRAM"),
    ("ST020", "TYPE E : (A, B); F : (B, C); END_TYPE\nPROGRAM p VAR e : E; END_VAR\n"
              "IF ¦B = e THEN e := A; END_IF END_PROGRAM"),
    ("ST020", "TYPE E : (A, B); F : (C, D); END_TYPE\nPROGRAM p VAR e : E; END_VAR\n"
              "CASE e OF A: e := B; ¦F#C: e := A; END_CASE END_PROGRAM"),
    ("ST020", "TYPE E : (A, B); END_TYPE\nPROGRAM p VAR e : E; i : INT; END_VAR\n"
              "e := ¦i; END_PROGRAM"),
    ("ST010", "TYPE E : (A, B); END_TYPE\nPROGRAM p VAR e : E; END_VAR\n"
              "e := ¦E#C; END_PROGRAM"),
    ("ST021", "TYPE Pct : INT(0..100); END_TYPE\nPROGRAM p VAR x : Pct; END_VAR\n"
              "x := ¦101; END_PROGRAM"),
    ("ST028", "PROGRAM p VAR n : INT := 3; a : ARRAY[1..¦n] OF INT; END_VAR\nEND_PROGRAM"),
    ("ST010", "PROGRAM p VAR x : INT; END_VAR\nCASE x OF ¦RED: x := 1; END_CASE END_PROGRAM"),
    ("ST022", "PROGRAM p VAR w : WORD; b : BOOL; END_VAR\nb := w.¦16; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR r : REAL; b : BOOL; END_VAR\nb := r.¦1; END_PROGRAM"),
    ("ST020", "PROGRAM p VAR s : STRING; w : WSTRING; END_VAR\ns := ¦w; END_PROGRAM"),
    ("ST024", "PROGRAM p VAR s : STRING; END_VAR\ns := ¦LEFT(s); END_PROGRAM"),
    ("ST020", "PROGRAM p VAR s : STRING; END_VAR\ns := LEFT(s, ¦'3'); END_PROGRAM"),
    ("ST005", "PROGRAM p VAR s : STRING; END_VAR\ns := ¦'caf\u0100'; END_PROGRAM"),
    ("ST005", "PROGRAM p VAR d : DATE; END_VAR\nd := ¦D#2023-02-29; END_PROGRAM"),
    ("ST024", "FUNCTION_BLOCK fb VAR_IN_OUT x : INT; END_VAR x := x + 1; END_FUNCTION_BLOCK\n"
              "PROGRAM p VAR f : fb; END_VAR\nf(x := ¦3); END_PROGRAM"),
    ("ST024", "FUNCTION_BLOCK fb VAR_IN_OUT x : INT; END_VAR x := x + 1; END_FUNCTION_BLOCK\n"
              "PROGRAM p VAR f : fb; END_VAR\n¦f(); END_PROGRAM"),
    ("ST020", "FUNCTION_BLOCK fb VAR_IN_OUT x : INT; END_VAR x := x + 1; END_FUNCTION_BLOCK\n"
              "PROGRAM p VAR f : fb; d : DINT; END_VAR\nf(x := ¦d); END_PROGRAM"),
    ("ST010", "PROGRAM p VAR_EXTERNAL ¦g : INT; END_VAR END_PROGRAM"),
    ("ST031", "PROGRAM p VAR a : ¦ARRAY[*] OF INT; END_VAR END_PROGRAM"),
    ("ST031", "FUNCTION f VAR_IN_OUT a : ARRAY[*] OF INT; END_VAR VAR b : ARRAY[1..2] OF INT;"
              " END_VAR\nb := ¦a; END_FUNCTION"),
    ("ST022", "PROGRAM p VAR a : ARRAY[1..2] OF INT; x : DINT; END_VAR\n"
              "x := UPPER_BOUND(a, ¦2); END_PROGRAM"),
    ("ST020", "FUNCTION f VAR_IN_OUT a : ARRAY[*] OF INT; END_VAR END_FUNCTION\n"
              "PROGRAM p VAR r : ARRAY[1..2] OF REAL; END_VAR\nf(¦r); END_PROGRAM"),
    ("ST026", "PROGRAM p\n¦CONTINUE; END_PROGRAM"),
    ("ST003", "PROGRAM p ¦(* never (* closed *)\nEND_PROGRAM"),
    ("ST032", "PROGRAM p END_PROGRAM\n¦PROGRAM P END_PROGRAM"),
    ("ST032", "¦FUNCTION_BLOCK TON END_FUNCTION_BLOCK"),
    ("ST033", "PROGRAM p\nNC.SEND(¦2, 1); END_PROGRAM"),
    ("ST034", "PROGRAM p VAR x : INT; END_VAR\nCASE x OF 1..3: x := 0; ¦2: x := 1; END_CASE "
              "END_PROGRAM"),
]


def locate(marked: str) -> tuple[str, int, int]:
    line_no, column = 0, 0
    for number, line in enumerate(marked.splitlines(), start=1):
        if MARK in line:
            line_no, column = number, line.index(MARK) + 1
    assert line_no, "a case marks its position"
    return marked.replace(MARK, ""), line_no, column


@pytest.mark.parametrize(("code", "marked"), CASES, ids=[f"{c}-{i}" for i, (c, _) in
                                                         enumerate(CASES)])
def test_diagnostic_code_and_position(code: str, marked: str) -> None:
    source, line, column = locate(marked)
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "case.st")], CONTEXT)
    first = caught.value.diagnostics[0]
    assert (first.code.code, first.span.line, first.span.column) == (code, line, column), (
        first.render())


def test_rendering_is_file_line_col_code_then_the_line_and_a_caret() -> None:
    source = "PROGRAM p VAR counter : INT; END_VAR\n  countr := 1;\nEND_PROGRAM\n"
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "main.st")], CONTEXT)
    assert str(caught.value) == (
        "main.st:2:3: error ST010: unknown variable countr (did you mean counter?)\n"
        "    countr := 1;\n"
        "    ^")


def test_every_error_of_a_file_is_reported_at_once() -> None:
    source = ("PROGRAM p VAR b : BOOL; s : SINT; END_VAR\n"
              "b := 5;\n"
              "s := 300;\n"
              "nope := 1;\n"
              "END_PROGRAM\n")
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "main.st")], CONTEXT)
    assert [(d.code.code, d.span.line) for d in caught.value.diagnostics] == [
        ("ST020", 2), ("ST021", 3), ("ST010", 4)]


def test_a_file_that_is_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin1.st"
    path.write_bytes(b"PROGRAM p\n(* caf\xe9 *)\nEND_PROGRAM\n")
    with pytest.raises(LogicError) as caught:
        parse_file(path)
    first = caught.value.diagnostics[0]
    assert (first.code.code, first.span.line, first.span.column) == ("ST004", 2, 7)
