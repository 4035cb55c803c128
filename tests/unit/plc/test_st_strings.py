"""STRING and WSTRING (IEC 61131-3 3rd ed., 6.3.3 and 6.4.2) and the character string
functions (6.6.2.5.11, Table 43), run through the scan.  The expected values are the
standard's own examples in Table 43 (``LEN('ASTRING') = 7``, ``MID('ASTUTE', 2, 2) = 'ST'``,
``INSERT('ABC', 'XY', 2) = 'ABXYC'``, ``DELETE('ABXYC', 2, 3) = 'ABC'``, ``REPLACE('ABCDE',
'X', 2, 3) = 'ABXE'``, ``FIND('ABCBC', 'BC') = 2``) and its rules worked by hand: positions
count from 1, a STRING is 80 characters unless declared, and a longer value is cut to the
variable's length where it is stored."""

from __future__ import annotations

import pytest

from ncgate.plc.scan import PlcState

from .st_harness import Plc, program


@pytest.mark.parametrize(("expr", "expected"), [
    ("LEN('ASTRING')", 7),
    ("FIND('ABCBC', 'BC')", 2),
    ("FIND('ABCBC', 'XY')", 0),
    ("LEN('')", 0),
])
def test_len_and_find_as_table_43(expr: str, expected: int) -> None:
    assert Plc(program(f"v := {expr};", "v : INT;")).scan()["main.v"] == expected


@pytest.mark.parametrize(("expr", "expected"), [
    ("LEFT('ASTR', 3)", "AST"),
    ("RIGHT('ASTR', 3)", "STR"),
    ("MID('ASTUTE', 2, 2)", "ST"),
    ("CONCAT('AB', 'CD', 'E')", "ABCDE"),
    ("INSERT('ABC', 'XY', 2)", "ABXYC"),
    ("DELETE('ABXYC', 2, 3)", "ABC"),
    ("REPLACE('ABCDE', 'X', 2, 3)", "ABXE"),
    # Edges (docs/plc.md): a length past the end takes what is there; INSERT at 0 is a
    # prefix; MID past the end is empty; LEFT 0 is empty.
    ("LEFT('AB', 5)", "AB"),
    ("RIGHT('AB', 5)", "AB"),
    ("MID('ABC', 5, 2)", "BC"),
    ("MID('ABC', 2, 7)", ""),
    ("INSERT('ABC', 'X', 0)", "XABC"),
    ("INSERT('ABC', 'X', 3)", "ABCX"),
    ("DELETE('ABC', 9, 2)", "A"),
    ("LEFT('ABC', 0)", ""),
    # Named inputs, in any order (7.3.3.2: a formal call).
    ("MID(P := 2, IN := 'ASTUTE', L := 2)", "ST"),
])
def test_string_functions_as_table_43(expr: str, expected: str) -> None:
    assert Plc(program(f"s := {expr};", "s : STRING;")).scan()["main.s"] == expected


def test_the_functions_work_on_variables_at_run_time() -> None:
    plc = Plc(program("""
        name := CONCAT(first, ' ', last);
        n := LEN(name);
        at := FIND(name, last);
        initials := CONCAT(LEFT(first, 1), LEFT(last, 1));
        tail := RIGHT(name, n - at + 1);
    """, "first : STRING := 'Ada'; last : STRING := 'Lovelace'; name, initials, tail : "
         "STRING; n, at : INT;")).scan()
    assert plc["main.name"] == "Ada Lovelace" and plc["main.n"] == 12 and plc["main.at"] == 5
    assert plc["main.initials"] == "AL" and plc["main.tail"] == "Lovelace"


def test_a_value_longer_than_the_declared_length_is_cut_where_it_is_stored() -> None:
    plc = Plc(program("short := long; init_cut := init_cut; grown := CONCAT(short, short);",
                      "short : STRING[4]; long : STRING := 'ABCDEFG'; "
                      "init_cut : STRING(3) := 'XYZW'; grown : STRING[6];")).scan()
    assert (plc["main.short"], plc["main.init_cut"], plc["main.grown"]) == (
        "ABCD", "XYZ", "ABCDAB")


def test_a_string_is_80_characters_unless_declared() -> None:
    plc = Plc(program("s := CONCAT(big, big);", "s : STRING; big : STRING[60];")).scan()
    plc2 = Plc(program("s := CONCAT(s, 'ABCDEFGHIJ');", "s : STRING;")).scan(10)
    assert plc["main.s"] == "" and len(plc2["main.s"]) == 80


def test_escapes_of_string_literals() -> None:
    # 6.3.3, Table 7: $' $$ $L $N $R $T $P and $hh in a STRING, $hhhh in a WSTRING.
    plc = Plc(program("""s := 'it$'s $$5$N$41$R$T'; w := "caf$00E9 $"x$""; n := LEN(w);""",
                      "s : STRING; w : WSTRING; n : INT;")).scan()
    assert plc["main.s"] == "it's $5\nA\r\t" and plc["main.w"] == 'café "x"'
    assert plc["main.n"] == 8


def test_typed_string_literals_name_their_type() -> None:
    # 6.3.3, Table 7: STRING#'OK' and WSTRING#"OK" (and WSTRING#'OK').
    plc = Plc(program("""s := STRING#'O$4B'; w := WSTRING#"$0152K"; w2 := WSTRING#'ok';""",
                      "s : STRING; w, w2 : WSTRING;")).scan()
    assert (plc["main.s"], plc["main.w"], plc["main.w2"]) == ("OK", "\u0152K", "ok")


def test_strings_compare_character_by_character() -> None:
    plc = Plc(program("lt := a < b; eq := a = 'ABC'; ne := a <> b; mx := MAX(a, b);",
                      "a : STRING := 'ABC'; b : STRING := 'ABD'; lt, eq, ne : BOOL; "
                      "mx : STRING;")).scan()
    assert (plc["main.lt"], plc["main.eq"], plc["main.ne"], plc["main.mx"]) == (
        True, True, True, "ABD")


def test_numbers_convert_to_and_from_text() -> None:
    plc = Plc(program("s := INT_TO_STRING(i); b := BOOL_TO_STRING(TRUE); "
                      "back := STRING_TO_INT('  -42 '); w := STRING_TO_WSTRING(s);",
                      "i : INT := -7; s, b : STRING; back : INT; w : WSTRING;")).scan()
    assert (plc["main.s"], plc["main.b"], plc["main.back"], plc["main.w"]) == (
        "-7", "TRUE", -42, "-7")


@pytest.mark.parametrize("call", ["LEFT(s, -1)", "MID(s, 2, 0)", "DELETE(s, -2, 1)",
                                  "INSERT(s, 'x', -1)", "STRING_TO_INT('4x')"])
def test_a_negative_length_or_a_position_before_the_first_faults(call: str) -> None:
    # Table 43: L and P outside what the function takes is an error -- at run time, the
    # PLC goes to FAULT at the statement.
    plc = Plc(program(f"x := 1;\nr := {call};",
                      "s : STRING := 'ABC'; r : STRING; x : INT;".replace(
                          "r : STRING;", "r : INT;" if "TO_INT" in call else "r : STRING;")))
    plc.scan()
    assert plc.runtime.status.state is PlcState.FAULT
    fault = plc.runtime.status.fault
    assert fault is not None and fault.span is not None and fault.span.line == 6
