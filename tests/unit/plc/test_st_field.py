"""Structured Text as real libraries write it (OSCAT, blark's TwinCAT samples): the issue
"What the field found".  Each test failed before its fix."""

from __future__ import annotations

import random
from collections.abc import Iterator
from pathlib import Path

import pytest

from ncgate.plc.image import IOImage
from ncgate.plc.retain import RetainStore
from ncgate.plc.scan import PlcRuntime, PlcState
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.diagnostics import LogicError
from ncgate.plc.st.parser import parse_source
from ncgate.plc.st.plcopen import read_logic_file
from ncgate.plc.st.types import ArrayOf, EnumOf
from ncgate.plc.st.walk import Walker

from .st_harness import Plc, RecordingNc, program


def _ticking(step_ns: int) -> Iterator[int]:
    now = 0
    while True:
        yield now
        now += step_ns


def test_a_straight_line_scan_over_the_watchdog_faults_and_counts_in_max_scan_us() -> None:
    # 3,000 assignments and no loop: the guard between loop chunks never runs.  The clock
    # the scan reads moves 100 ms at each look, so the scan takes longer than 1 ms whatever
    # the machine's speed.
    body = "\n".join(f"x := x + {i % 7};" for i in range(3000)) + "\nSA[1] := TRUE;"
    plc = Plc(program(body, "x : DINT;"))
    plc.runtime.watchdog_ms = 1
    ticks = _ticking(100_000_000)
    plc.runtime.clock_ns = lambda: next(ticks)
    plc.scan()
    status = plc.runtime.status
    assert status.state is PlcState.FAULT
    assert status.fault is not None and "watchdog" in status.fault.message
    assert status.max_scan_us >= 1000  # the faulted scan's time is counted
    assert plc.writes == []  # its outputs are dropped
    assert status.scans == 0


# -- item 12: EN and ENO (IEC 61131-3, 6.6.1.6) ------------------------------------------------

MARK = "¦"
CONTEXT = Context(64, 16, 8, 5, frozenset({4, 5}))


def diagnosed(marked: str) -> tuple[tuple[str, int, int], tuple[str, int, int]]:
    """(code, line, column) of the first diagnostic, and where ``¦`` marks it must be."""
    line = marked[:marked.index(MARK)].count("\n") + 1
    column = marked.index(MARK) - (marked.rfind("\n", 0, marked.index(MARK)) + 1) + 1
    source = marked.replace(MARK, "")
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "t.st")], CONTEXT)
    first = caught.value.diagnostics[0]
    return (first.code.code, first.span.line, first.span.column), \
        (first.code.code, line, column)


EN_LOGIC = """
FUNCTION Double : INT VAR_INPUT x : INT; END_VAR
Double := x * 2; calls := calls + 1;
END_FUNCTION
FUNCTION_BLOCK Count VAR_INPUT step : INT; END_VAR VAR_OUTPUT total : INT; END_VAR
total := total + step;
END_FUNCTION_BLOCK
VAR_GLOBAL calls : INT; END_VAR
PROGRAM main
VAR en : BOOL; ok1, ok2, ok3, ok4 : BOOL := TRUE; y, z, w, out : INT := 7; c : Count;
    u : CTU; END_VAR
y := Double(EN := en, x := 4, ENO => ok1);
Double(EN := en, x := 5, ENO => ok4);
z := 1 + MAX(EN := en, 3, 9);
c(EN := en, step := 2, total => out, ENO => ok2);
u(EN := en, CU := TRUE, PV := 5, ENO => ok3);
w := c.total;
END_PROGRAM
"""


def test_en_false_skips_the_call_and_en_true_runs_it_with_eno_following_en() -> None:
    plc = Plc(EN_LOGIC).scan()
    # EN FALSE: a function's result is its type's default, an FB is not called, nothing is
    # bound (out keeps its 7), ENO is FALSE
    assert (plc["main.y"], plc["main.z"], plc["main.out"], plc["main.w"]) == (0, 1, 7, 0)
    assert plc["main.u.CV"] == 0
    assert [plc[f"main.ok{i}"] for i in range(1, 5)] == [False] * 4
    plc.runtime.programs["MAIN"].v_EN = True
    plc.scan()
    assert (plc["main.y"], plc["main.z"], plc["main.out"], plc["main.w"]) == (8, 10, 2, 2)
    assert plc["main.u.CV"] == 1
    assert [plc[f"main.ok{i}"] for i in range(1, 5)] == [True] * 4


def test_eno_inside_an_expression_is_st031_at_eno() -> None:
    got, want = diagnosed("FUNCTION F : INT VAR_INPUT x : INT; END_VAR F := x; END_FUNCTION\n"
                          "PROGRAM p VAR y : INT; ok : BOOL; END_VAR\n"
                          "y := 1 + F(EN := TRUE, x := 1, ¦ENO => ok); END_PROGRAM")
    assert got == want


def test_en_and_eno_read_alike_compiled_and_walked() -> None:
    source = """
FUNCTION_BLOCK Count VAR_INPUT step : INT; END_VAR VAR_OUTPUT total : INT; END_VAR
total := total + step;
END_FUNCTION_BLOCK
PROGRAM main
VAR ok1, ok2 : BOOL; z, out : INT; c : Count; u : CTU; END_VAR
z := 1 + MAX(EN := SA[0], 3, 9) + LIMIT(EN := SA[1], IN := 50, MX := 20, MN := 0)
     + SEL(G := SA[2], IN0 := 100, IN1 := 200);
c(EN := SA[1], step := 2, total => out, ENO => ok1);
u(EN := SA[0] XOR SA[1], CU := SA[2], PV := 5, ENO => ok2);
SYVAR[0] := out + z + u.CV;
END_PROGRAM
"""
    files = [parse_source(source, "en.st")]
    context = Context(64, 16, 8, 5, frozenset())
    image, walk_image = IOImage(64, 16, 8), IOImage(64, 16, 8)
    runtime = PlcRuntime(compile_logic(files, context), image, RecordingNc(), ["main"])
    walker = Walker(files, context, walk_image.sa, walk_image.k, walk_image.syvar)
    rng = random.Random(12)
    for scan in range(40):
        bits = [("SA", rng.randrange(3), "bit", rng.randrange(2))]
        image.write(bits, "test")
        walk_image.write(bits, "test")
        runtime.scan(scan * 10)
        walker.scan(scan * 10)
        program, state = runtime.programs["MAIN"], walker.state["MAIN"]
        for name in ("OK1", "OK2", "Z", "OUT"):
            assert getattr(program, f"v_{name}") == state[name], (scan, name)
        assert program.v_U.CV == state["U"].CV
        assert image.syvar == walk_image.syvar


# -- item 13: the standard functions' formal names, MUL_TIME, BOOL 0/1, PERSISTENT, RETAIN in
# -- a FUNCTION_BLOCK ------------------------------------------------------------------------


def test_standard_functions_take_their_inputs_by_their_iec_names() -> None:
    plc = Plc(program(
        "a := SEL(G := g, IN0 := 1, IN1 := 2); b := SEL(IN1 := 20, G := NOT g, IN0 := 10);\n"
        "c := LIMIT(MN := 0, IN := 150, MX := 100); d := MUX(K := 2, IN0 := 5, IN1 := 6,\n"
        "IN2 := 7); e := MAX(IN1 := 3, IN2 := 9, IN3 := 4); f := MIN(IN2 := 8, IN1 := -1);\n"
        "r := EXPT(IN1 := 2.0, IN2 := 3.0); w := SHL(IN := WORD#1, N := 4);\n"
        "x := INT_TO_DINT(IN := 70); y := TO_DINT(IN := a);",
        "g : BOOL; a, b, c, d, e, f : INT; r : REAL; w : WORD; x, y : DINT;")).scan()
    got = [plc[f"main.{v}"] for v in "abcdefrwxy"]
    assert got == [1, 20, 100, 7, 9, -1, 8.0, 16, 70, 1]


@pytest.mark.parametrize("marked", [
    "a := SEL(G := TRUE, IN0 := 1, ¦IN2 := 2);",
    "a := LIMIT(MN := 0, ¦5, MX := 9);",
    "a := ¦SEL(G := TRUE, IN0 := 1);",
])
def test_a_standard_function_given_a_wrong_formal_name_is_st024_at_it(marked: str) -> None:
    got, want = diagnosed(program(marked, "a : INT;"))
    assert got == want and got[0] == "ST024"


def test_mul_time_and_div_time_in_both_editions_spellings() -> None:
    plc = Plc(program("a := MUL_TIME(T#1s, 3); b := DIV_TIME(IN1 := T#1s, IN2 := 4);\n"
                      "c := MULTIME(T#100ms, 2.5); d := DIVTIME(T#1s, 3.0);",
                      "a, b, c, d : TIME;")).scan()
    assert [plc[f"main.{v}"] for v in "abcd"] == [3000, 250, 250, 333]


def test_mul_time_of_no_time_is_st020() -> None:
    got, want = diagnosed(program("a := ¦MUL_TIME(3, 4);", "a : TIME;"))
    assert got == want and got[0] == "ST020"


def test_the_literals_0_and_1_are_bools_where_a_bool_is_due() -> None:
    plc = Plc(program("a := 1; b := 0; c := a AND NOT b;", "a : BOOL; b : BOOL := 1;\n"
                      "c : BOOL := 0;")).scan()
    assert (plc["main.a"], plc["main.b"], plc["main.c"]) == (True, False, True)
    got, want = diagnosed(program("a := ¦2;", "a : BOOL;"))
    assert got == want and got[0] == "ST020"


PERSISTENT = """
FUNCTION_BLOCK Tally
VAR_INPUT pulse : BOOL; END_VAR
VAR RETAIN n : INT; END_VAR
VAR edge : R_TRIG; END_VAR
edge(CLK := pulse);
IF edge.Q THEN n := n + 1; END_IF
END_FUNCTION_BLOCK
PROGRAM keep
VAR PERSISTENT hours : DINT; END_VAR
VAR RETAIN PERSISTENT kept : INT; END_VAR
VAR tally : Tally; tallies : ARRAY[1..2] OF Tally; pulse : BOOL; plain : INT; END_VAR
pulse := NOT pulse; hours := hours + 1; kept := kept + 2; plain := plain + 1;
tally(pulse := pulse); tallies[2](pulse := pulse);
END_PROGRAM
"""


def test_persistent_and_retain_in_a_function_block_survive_a_restart(tmp_path: Path) -> None:
    def runtime(store: RetainStore) -> PlcRuntime:
        logic = compile_logic([parse_source(PERSISTENT, "keep.st")], Context())
        return PlcRuntime(logic, IOImage(), RecordingNc(), ["keep"], retain=store)

    store = RetainStore(tmp_path / "r.sqlite")
    first = runtime(store)
    for t in range(5):  # pulse TRUE, FALSE, TRUE, FALSE, TRUE: three rising edges
        first.scan(t * 10)
    store.close()
    again = runtime(RetainStore(tmp_path / "r.sqlite"))
    assert (again.read("keep.hours"), again.read("keep.kept"), again.read("keep.plain")) \
        == (5, 10, 0)
    # the instances of an FB that declares RETAIN are retained whole (as CODESYS does)
    assert again.read("keep.tally.n") == 3 and again.read("keep.tallies[2].n") == 3


def test_plcopen_persistent_variables_are_read_as_retained(tmp_path: Path) -> None:
    text = (Path(__file__).parent / "plcopen" / "beremiz_conveyor.xml").read_text("utf-8")
    assert text.count("<localVars>") >= 1
    path = tmp_path / "conveyor.xml"
    path.write_text(text.replace("<localVars>", '<localVars persistent="true">', 1),
                    encoding="utf-8")
    logic = compile_logic([read_logic_file(path)], Context())
    assert any(v.retain for table in logic.programs.values() for v in table.values()) or \
        any(v.retain for table in logic.fb_vars.values() for v in table.values())


def test_retain_in_a_function_is_st031_at_its_variable() -> None:
    got, want = diagnosed("FUNCTION F : INT VAR RETAIN ¦n : INT; END_VAR F := n; "
                          "END_FUNCTION\nPROGRAM p VAR x : INT; END_VAR x := F(); END_PROGRAM")
    assert got == want and got[0] == "ST031"


# -- item 17: an enumeration's value shown by its name ----------------------------------------

ENUMS = """
TYPE E_State : (IDLE, RUN := 5, DONE); E_Alias : E_State; END_TYPE
FUNCTION_BLOCK Station VAR_OUTPUT step : E_State; END_VAR step := DONE; END_FUNCTION_BLOCK
PROGRAM cell
VAR st : E_State := RUN; al : E_Alias := DONE; steps : ARRAY[1..2] OF E_State; s : Station;
    n : INT; END_VAR
s(); steps[2] := RUN;
END_PROGRAM
"""


def test_a_variable_of_an_enumeration_has_a_type_that_names_its_values() -> None:
    plc = Plc(ENUMS).scan()
    table = plc.logic.programs["CELL"]
    st, al, steps = table["ST"].type, table["AL"].type, table["STEPS"].type
    assert isinstance(st, EnumOf) and st.name_of(plc["cell.st"]) == "RUN"
    assert isinstance(al, EnumOf) and al.name_of(plc["cell.al"]) == "DONE"
    assert isinstance(steps, ArrayOf) and isinstance(steps.element, EnumOf)
    assert [steps.element.name_of(v) for v in plc["cell.steps"]] == ["IDLE", "RUN"]
    step = plc.logic.fb_vars["STATION"]["STEP"].type
    assert isinstance(step, EnumOf) and step.name_of(plc["cell.s.step"]) == "DONE"
    assert st.name_of(99) == 99  # no name: the integer, as stored
    assert st == EnumOf("E_STATE")  # the names are no part of the type's identity


# -- item 14: every error of a load; each construct outside the subset its own code ----------


def all_diagnosed(source: str) -> list[tuple[str, int, int]]:
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "t.st")], CONTEXT)
    return [(d.code.code, d.span.line, d.span.column) for d in caught.value.diagnostics]


def test_a_located_variable_is_st031_and_the_rest_of_the_load_is_still_checked() -> None:
    source = ("VAR_GLOBAL lamp AT %QX0.1 : BOOL; END_VAR\n"
              "PROGRAM p\nVAR start AT %IX0.0 : BOOL; i : INT; d : DINT; END_VAR\n"
              "IF start THEN lamp := TRUE; END_IF\n"
              "i := d;\nEND_PROGRAM\n")
    assert sorted(all_diagnosed(source)) == [("ST020", 5, 6), ("ST031", 1, 17),
                                             ("ST031", 3, 11)]


FB = "FUNCTION_BLOCK FB_Axis VAR_INPUT nId : INT; END_VAR END_FUNCTION_BLOCK\n"


@pytest.mark.parametrize(("code", "marked"), [
    ("ST035", FB + "FUNCTION_BLOCK FB_Lin ¦EXTENDS FB_Axis\nEND_FUNCTION_BLOCK"),
    ("ST035", "FUNCTION_BLOCK FB_Lin ¦IMPLEMENTS I_Axis\nEND_FUNCTION_BLOCK"),
    ("ST036", "PROGRAM p VAR t : ¦Tc2_Standard.TON; END_VAR END_PROGRAM"),
    ("ST036", "PROGRAM p VAR t : ARRAY[1..2] OF ¦Lib.T_Pos; END_VAR END_PROGRAM"),
    ("ST036", "TYPE S : STRUCT t : ¦Lib.T_Pos; END_STRUCT END_TYPE PROGRAM p END_PROGRAM"),
    ("ST037", FB + "PROGRAM p VAR ax : FB_Axis¦(nId := 1); END_VAR END_PROGRAM"),
    ("ST038", FB + "PROGRAM p VAR ax : ARRAY[0..1] OF FB_Axis¦[(nId := 1), (nId := 2)];\n"
              "END_VAR END_PROGRAM"),
    ("ST039", "TYPE E_Mode : (AUTO, MANUAL) ¦DINT; END_TYPE PROGRAM p END_PROGRAM"),
    ("ST039", "TYPE E_Mode : ¦INT (AUTO := 1, MANUAL); END_TYPE PROGRAM p END_PROGRAM"),
    ("ST041", "FUNCTION_BLOCK ¦PUBLIC FB_Axis\nVAR x : INT; END_VAR\nEND_FUNCTION_BLOCK"),
    ("ST041", "FUNCTION_BLOCK ¦ABSTRACT FB_Base\nEND_FUNCTION_BLOCK"),
    ("ST042", "PROGRAM p VAR x : INT;¦; END_VAR x := 1; END_PROGRAM"),
    ("ST042", "PROGRAM p VAR x : INT; END_VAR x := 1; END_PROGRAM¦;"),
    ("ST042", "FUNCTION_BLOCK FB_Axis¦; VAR x : INT; END_VAR END_FUNCTION_BLOCK"),
    ("ST042", "FUNCTION F : INT¦; VAR_INPUT a : INT; END_VAR F := a; END_FUNCTION"),
])
def test_what_codesys_and_twincat_write_beyond_the_subset_has_its_own_code(
        code: str, marked: str) -> None:
    got, want = diagnosed(marked)
    assert got == want and got[0] == code


@pytest.mark.parametrize("marked", [
    "PROGRAM p VAR x : INT; END_VAR\nx := ¦; END_PROGRAM",
    "PROGRAM p VAR variance : INT; END_VAR\nCASE variance OF 1: variance := ¦: 2; END_CASE "
    "END_PROGRAM",
])
def test_a_plain_syntax_error_is_still_st002(marked: str) -> None:
    got, want = diagnosed(marked)
    assert got == want and got[0] == "ST002"


def test_an_unknown_pragma_warns_at_its_brace_and_the_logic_loads() -> None:
    source = ("PROGRAM p VAR x : INT; END_VAR\n{attribute 'hide'}\n"
              "x := 1; {{ printf(\"%d\\n\", x); }}\n{IF defined (SIM)}\nx := 2;\n{END_IF}\n"
              "END_PROGRAM\n")
    logic = compile_logic([parse_source(source, "t.st")], CONTEXT)
    assert [(w.code.code, w.span.line, w.span.column) for w in logic.warnings] == [
        ("SW004", 3, 9), ("SW004", 4, 1), ("SW004", 6, 1)]
