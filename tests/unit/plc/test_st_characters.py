"""CHAR and WCHAR, and a string's single characters (IEC 61131-3 3rd ed.), run through the
scan.  Expected values are the standard's: Table 10 gives the types and their initial values
('$00', "$0000"); a character literal is one character, typed ``CHAR#'A'``; ``s[i]`` is the
i-th character, the first at 1 (as Table 43's positions count); a character's code is its
ISO 8859-1 / UCS-2 code ('A' is 16#41, '€' is 16#20AC, beyond Latin-1).  Where the
standard is silent (docs/decisions.md): an index outside the string faults, as outside an
array; ``s[LEN(s) + 1] := c`` adds the character."""

from __future__ import annotations

import pytest

from ncgate.plc.scan import PlcState
from ncgate.plc.st.compiler import Context

from .st_harness import Plc, program

LENIENT = Context(64, 16, 8, 5, frozenset({4, 5}), strict=False)


def test_characters_are_declared_with_their_initial_values() -> None:
    plc = Plc(program("", "c : CHAR; w : WCHAR; a : CHAR := 'A'; t : CHAR := CHAR#'$41'; "
                          "e : WCHAR := WCHAR#\"$20AC\";")).scan()
    assert (plc["main.c"], plc["main.w"]) == ("\x00", "\x00")  # '$00', "$0000"
    assert (plc["main.a"], plc["main.t"], plc["main.e"]) == ("A", "A", "\u20ac")


def test_a_strings_characters_count_from_1_and_are_read_and_written() -> None:
    plc = Plc(program("""
        first := s[1]; second := s[i]; last := s[LEN(s)];
        s[1] := 'h'; s[5] := CHAR#'O';
        ws[2] := WCHAR#"$20AC"; wide := ws[2];
    """, "s : STRING[10] := 'Hello'; i : INT := 2; first, second, last : CHAR; "
         "ws : WSTRING := \"abc\"; wide : WCHAR;")).scan()
    assert (plc["main.first"], plc["main.second"], plc["main.last"]) == ("H", "e", "o")
    assert plc["main.s"] == "hellO" and plc["main.ws"] == "a\u20acc"
    assert plc["main.wide"] == "\u20ac"


def test_a_character_written_just_past_the_end_lengthens_the_string() -> None:
    plc = Plc(program("FOR i := 1 TO 2 DO s[LEN(s) + 1] := 'x'; END_FOR;",
                      "s : STRING[4] := 'ab'; i : INT;")).scan()
    assert plc.runtime.status.state is PlcState.RUNNING and plc["main.s"] == "abxx"
    # (past the declared length it faults: the last case below)


@pytest.mark.parametrize(("body", "decls", "words"), [
    ("c := s[i];", "s : STRING := 'abc'; i : INT := 4; c : CHAR;", "character 4 of a string "
     "of 3"),
    ("c := s[i];", "s : STRING := 'abc'; i : INT := 0; c : CHAR;", "character 0"),
    ("s[i] := 'x';", "s : STRING := 'abc'; i : INT := 5;", "character 5 of a string of 3"),
    ("s[i] := 'x';", "s : STRING[3] := 'abc'; i : INT := 4;", "character 4 of a string of 3"),
])
def test_a_character_outside_the_string_faults_at_its_statement(body: str, decls: str,
                                                               words: str) -> None:
    plc = Plc(program(body, decls)).scan()
    fault = plc.runtime.status.fault
    assert plc.runtime.status.state is PlcState.FAULT and fault is not None
    assert fault.span is not None and (fault.span.line, fault.span.column) == (5, 1)
    assert words in fault.message


def test_characters_compare_by_their_codes() -> None:
    plc = Plc(program("""
        eq := c = 'A'; lt := c < CHAR#'B'; gt := 'a' > c; ne := s[1] <> s[2];
        hi := MAX(c, CHAR#'Z', 'M'); lim := LIMIT('B', c, 'Y');
    """, "c : CHAR := 'A'; s : STRING := 'ab'; eq, lt, gt, ne : BOOL; hi, lim : CHAR;")).scan()
    assert (plc["main.eq"], plc["main.lt"], plc["main.gt"], plc["main.ne"]) == (
        True, True, True, True)
    assert (plc["main.hi"], plc["main.lim"]) == ("Z", "B")


def test_the_conversions_of_characters() -> None:
    plc = Plc(program("""
        b := CHAR_TO_BYTE(CHAR#'A'); c := BYTE_TO_CHAR(16#61); w := WCHAR_TO_WORD(WCHAR#"$20AC");
        wc := WORD_TO_WCHAR(16#41); via := TO_CHAR(BYTE#16#42); t := CHAR_TO_STRING('z');
        first := STRING_TO_CHAR('xyz'); none := STRING_TO_CHAR(empty);
        widened := CHAR_TO_WCHAR(CHAR#'$E9'); narrowed := WCHAR_TO_CHAR(WCHAR#"$20AC");
        kept := WCHAR_TO_CHAR(WCHAR#"$00E9"); ws := WCHAR_TO_WSTRING(WCHAR#"$20AC");
        wfirst := WSTRING_TO_WCHAR("$20ACx"); d := CHAR_TO_DWORD('A'); cut := WCHAR_TO_BYTE(
        WCHAR#"$20AC");
    """, "b, cut : BYTE; c, via, first, none, narrowed, kept : CHAR; w : WORD; d : DWORD; "
         "wc, widened, wfirst : WCHAR; t : STRING; ws : WSTRING; empty : STRING;")).scan()
    assert (plc["main.b"], plc["main.c"], plc["main.w"], plc["main.wc"]) == (
        0x41, "a", 0x20AC, "A")
    assert (plc["main.via"], plc["main.t"], plc["main.first"], plc["main.none"]) == (
        "B", "z", "x", "\x00")
    # CHAR -> WCHAR keeps the character; a WCHAR beyond Latin-1 has no CHAR: '?'
    assert (plc["main.widened"], plc["main.narrowed"], plc["main.kept"]) == (
        "\u00e9", "?", "\u00e9")
    assert (plc["main.ws"], plc["main.wfirst"], plc["main.d"]) == ("\u20ac", "\u20ac", 0x41)
    assert plc["main.cut"] == 0xAC  # a bit string conversion keeps the low bits


def test_a_character_is_a_string_where_one_is_due() -> None:
    """6.4.2 (Figure 11): CHAR -> STRING implicitly; Table 43 takes characters (ANY_CHARS)
    in CONCAT's inputs and as the second input of INSERT, REPLACE and FIND."""
    plc = Plc(program("""
        s := c; joined := CONCAT('AB', c, CHAR#'D'); at := FIND('ABCBC', c);
        ins := INSERT('AC', CHAR#'B', 1); rep := REPLACE('AXC', CHAR#'B', 1, 2);
    """, "c : CHAR := 'C'; s, joined, ins, rep : STRING; at : INT;")).scan()
    assert (plc["main.s"], plc["main.joined"], plc["main.at"]) == ("C", "ABCD", 3)
    assert (plc["main.ins"], plc["main.rep"]) == ("ABC", "ABC")


def test_codesys_s_character_as_a_byte_loads_leniently_with_a_warning() -> None:
    """CODESYS and logi.CAD read s[i] as a BYTE: with plc.strict = false a character and an
    integer mix as its code, each place an SW002 that names IEC's conversion."""
    plc = Plc(program("""
        b := s[1]; big := s[2] > 16#60; s[3] := 16#63; s[1] := b + 1;
    """, "s : STRING := 'AbX'; b : BYTE; big : BOOL;"), context=LENIENT).scan()
    assert (plc["main.b"], plc["main.big"], plc["main.s"]) == (0x41, True, "Bbc")
    warnings = plc.logic.warnings
    assert [w.code.code for w in warnings] == ["SW002"] * 4
    assert [w.message.rsplit("(IEC: ", 1)[1] for w in warnings] == [
        "CHAR_TO_BYTE)", "CHAR_TO_BYTE)", "BYTE_TO_CHAR)", "BYTE_TO_CHAR)"]
