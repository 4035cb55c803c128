"""Values the standards fix (issue 29, "wrong"): every expected value below comes from IEEE
754 (REAL is binary32, LREAL binary64: round to nearest, ties to even) or IEC 61131-3 3rd ed.
(literals 6.3, durations 6.3.3, keywords 6.1.2, conversions 6.6.2.5, errors on results beyond
a type's range), never from ncgate's output.  TIME is ncgate's documented 32-bit signed
milliseconds (the standard leaves its range to the implementation)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.plc.image import IOImage
from ncgate.plc.retain import RetainStore
from ncgate.plc.scan import PlcRuntime, PlcState
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.diagnostics import LogicError
from ncgate.plc.st.parser import parse_source

from .st_harness import Plc, RecordingNc, program

# binary32 values, from their bits (sign, exponent, 24-bit significand), not from code:
# 0.1 rounds to 13421773 * 2^-27; 1/3 to 11184811 * 2^-25; 2^24 + 1 ties to 2^24 (even).
SINGLE_0_1 = 13421773 / 2**27
SINGLE_THIRD = 11184811 / 2**25
TIME_MAX_MS = 2**31 - 1  # T#24d20h31m23s647ms


def fault_of(plc: Plc) -> str:
    plc.scan()
    assert plc.runtime.status.state is PlcState.FAULT, "the scan did not fault"
    return plc.nc.faults[0]


def first_code(source: str) -> tuple[str, int, int]:
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "iec.st")])
    d = caught.value.diagnostics[0]
    return d.code.code, d.span.line, d.span.column


# ---- constant expressions wrap where stored, like the same expression of variables ----------

def test_the_docs_example_32767_plus_1_loads_and_stores_minus_32768() -> None:
    plc = Plc(program("i := 32767 + 1; j := k + 1;", "i, j : INT; k : INT := 32767; "
                      "m : INT := 32767 + 1;")).scan()
    assert (plc["main.i"], plc["main.j"], plc["main.m"]) == (-32768, -32768, -32768)


def test_a_literal_that_does_not_fit_is_still_st021() -> None:
    assert first_code(program("i := 40000;", "i : INT;"))[0] == "ST021"


# ---- REAL is IEEE single, LREAL double -------------------------------------------------------

def test_real_adds_in_single_precision_and_lreal_in_double() -> None:
    plc = Plc(program("r := r + 1.0; r2 := r2 + one + one; l := l + 1.0;",
                      "r, r2 : REAL := 16777216.0; l : LREAL := 16777216.0;"
                      "one : REAL := 1.0;")).scan()
    # 2^24 + 1 is a tie between 2^24 and 2^24 + 2: to even, 2^24; each + rounds again.
    assert (plc["main.r"], plc["main.r2"], plc["main.l"]) == (16777216.0, 16777216.0,
                                                              16777217.0)


def test_a_real_literal_is_the_nearest_single_and_compares_equal_to_itself() -> None:
    plc = Plc(program("q := one / three; same := r = 0.1; wide := l = 0.1;",
                      "r : REAL := 0.1; l : LREAL := 0.1; one : REAL := 1.0; "
                      "three : REAL := 3.0; q : REAL; same, wide : BOOL;")).scan()
    assert plc["main.r"] == SINGLE_0_1 and plc["main.l"] == 0.1
    assert plc["main.q"] == SINGLE_THIRD
    assert (plc["main.same"], plc["main.wide"]) == (True, True)


def test_dint_to_real_rounds_to_the_nearest_single() -> None:
    plc = Plc(program("r := DINT_TO_REAL(d); s := d;", "d : DINT := 16777217; r, s : REAL;"))
    plc.scan()
    assert (plc["main.r"], plc["main.s"]) == (16777216.0, 16777216.0)


def test_a_real_result_beyond_singles_range_faults() -> None:
    assert "REAL" in fault_of(Plc(program("r := r * 2.0;", "r : REAL := 3.0E38;")))


def test_a_real_literal_beyond_singles_range_is_st021() -> None:
    assert first_code(program("r := 1.0E39;", "r : REAL;"))[0] == "ST021"


@pytest.mark.parametrize("body", ["i := REAL_TO_INT(r);", "i := LREAL_TO_INT(l);",
                                  "d := TRUNC(r);"])
def test_a_real_to_integer_conversion_out_of_range_faults_instead_of_wrapping(
        body: str) -> None:
    message = fault_of(Plc(program(body, "r : REAL := 1.0E38; l : LREAL := 1.0E39; "
                                         "i : INT; d : DINT;")))
    assert "does not fit" in message


def test_real_to_int_rounds_half_to_even_in_range() -> None:
    plc = Plc(program("a := REAL_TO_INT(r); b := REAL_TO_INT(-r);",
                      "r : REAL := 32767.4; a, b : INT;")).scan()
    assert (plc["main.a"], plc["main.b"]) == (32767, -32767)


def test_expt_of_zero_to_a_negative_power_names_that_error() -> None:
    message = fault_of(Plc(program("r := EXPT(z, -1.0);", "r, z : REAL;")))
    assert "EXPT" in message and "division by zero" not in message


# ---- TIME: 32-bit milliseconds, wrapped where stored ----------------------------------------

def test_time_wraps_at_32_bits_where_it_is_stored() -> None:
    plc = Plc(program("t := t + T#1ms; u := T#24d20h31m23s647ms;",
                      "t : TIME := T#24d20h31m23s647ms; u : TIME;")).scan()
    assert (plc["main.t"], plc["main.u"]) == (-(2**31), TIME_MAX_MS)


def test_a_duration_beyond_32_bits_is_st021() -> None:
    assert first_code(program("t := T#30d;", "t : TIME;")) == ("ST021", 5, 6)


def test_a_retained_time_comes_back_whatever_it_holds(tmp_path: Path) -> None:
    source = ("PROGRAM keep\nVAR RETAIN t : TIME := T#24d20h31m23s647ms; END_VAR\n"
              "t := t + T#5ms;\nEND_PROGRAM\n")
    logic = compile_logic([parse_source(source, "keep.st")], Context())
    store = RetainStore(tmp_path / "r.sqlite")
    PlcRuntime(logic, IOImage(), RecordingNc(), ["keep"], retain=store).scan(0)
    store.close()
    again = PlcRuntime(logic, IOImage(), RecordingNc(), ["keep"],
                       retain=RetainStore(tmp_path / "r.sqlite"))
    assert again.read("keep.t") == -(2**31) + 4


# ---- the lexical rules -------------------------------------------------------------------------

@pytest.mark.parametrize(("source", "column"), [
    ("PROGRAM p VAR by : INT; END_VAR END_PROGRAM", 15),
    ("PROGRAM p VAR x : INT; END_VAR x := do; END_PROGRAM", 37),
    ("PROGRAM p VAR x : INT; END_VAR end_if := 1; END_PROGRAM", 32),
])
def test_a_keyword_is_not_a_name(source: str, column: int) -> None:
    assert first_code(source) == ("ST002", 1, column)


@pytest.mark.parametrize("literal", ["T#5ms3s", "T#1.5s500ms", "DINT#-16#10", "1__000", "1_",
                                     "T#1h75m", "16#F__F"])
def test_a_literal_iec_does_not_allow_is_st005(literal: str) -> None:
    assert first_code(f"PROGRAM p VAR x : DINT; END_VAR\nx := {literal}; END_PROGRAM") == (
        "ST005", 2, 6)


@pytest.mark.parametrize(("literal", "ms"), [("T#1d2h3m4s5ms", 93_784_005), ("T#25h", 90_000_000),
                                             ("T#1.5s", 1500), ("T#1d_2h", 93_600_000),
                                             ("TIME#-2.5s", -2500)])
def test_durations_iec_allows_still_load(literal: str, ms: int) -> None:
    plc = Plc(program(f"t := {literal};", "t : TIME;")).scan()
    assert plc["main.t"] == ms


def test_names_that_start_like_keywords_are_names() -> None:
    plc = Plc(program("bye := 1; dot := 2; end_iffy := 3; format := 4;",
                      "bye, dot, end_iffy, format : INT;")).scan()
    assert plc["main.format"] == 4
