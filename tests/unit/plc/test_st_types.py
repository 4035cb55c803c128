"""Data types and declarations of IEC 61131-3 3rd ed. (issue 29): TYPE … END_TYPE with
structures, enumerations, subranges and aliases (6.4.4), named constants where a constant is
due (6.5.1.3, 7.3.3.3.3), multi-dimensional arrays and arrays of arrays (6.4.4.5), bit access
(6.5.1.2, Table 12), VAR_GLOBAL / VAR_EXTERNAL and VAR_IN_OUT (6.5.2.2), the 64-bit and date
types (6.4.2, Table 10) with their arithmetic (Table 30), MOVE (Table 22), pragmas (6.2).
Each program runs through the scan; the expected values are the standard's rules worked by
hand."""

from __future__ import annotations

import pytest

from ncgate.plc.image import IOImage
from ncgate.plc.scan import PlcRuntime, PlcState
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.parser import parse_source

from .st_harness import Plc, RecordingNc, program

TYPES = """
TYPE
  E_State : (IDLE, RUN := 5, DONE);          (* DONE follows RUN: 6 (6.4.4.2) *)
  E_Mode : (AUTO, MANUAL) := MANUAL;         (* a declared default *)
  Point : STRUCT
    x : INT := 1;
    y : REAL := 0.5;
  END_STRUCT;
  Line : STRUCT
    a, b : Point;
    tag : ARRAY[1..2] OF INT := [7, 8];
  END_STRUCT;
  Pct : INT(0..100);                          (* default: its lower limit, 0 *)
  Temp : INT(20..30);                         (* default: 20 (6.4.4.4) *)
  Count : DINT := 42;                         (* an alias with its own default *)
END_TYPE
"""


def run(body: str, decls: str, scans: int = 1) -> Plc:
    return Plc(TYPES + program(body, decls)).scan(scans)


def test_a_structure_has_its_members_defaults_and_a_nested_one_its_own() -> None:
    plc = run("l.b.x := l.a.x + 10; p.y := p.y * 2.0;", "l : Line; p : Point;")
    assert plc["main.l.a.x"] == 1 and plc["main.l.b.x"] == 11
    assert plc["main.l.tag"] == [7, 8] and plc["main.p.y"] == 1.0


def test_a_structure_initial_value_sets_the_members_it_names() -> None:
    plc = run("", "l : Line := (b := (x := 3), tag := [9]);")
    # 6.5.1.3: members not named keep their type's default; [9] fills one, the rest 0.
    assert (plc["main.l.a.x"], plc["main.l.b.x"], plc["main.l.b.y"], plc["main.l.tag"]) == (
        1, 3, 0.5, [9, 0])


def test_assigning_a_structure_copies_it() -> None:
    # 7.3.3.2.2: the assignment copies the value; changing the copy leaves the source.
    plc = run("b := a; b.x := 99; arr[2] := a; arr[2].x := 5;",
              "a, b : Point; arr : ARRAY[1..2] OF Point;")
    assert (plc["main.a.x"], plc["main.b.x"], plc["main.arr[2].x"], plc["main.arr[1].x"]) == (
        1, 99, 5, 1)


def test_an_array_of_structures_takes_an_initial_list() -> None:
    plc = run("", "pts : ARRAY[0..2] OF Point := [(x := 4), (y := 2.0)];")
    assert [plc[f"main.pts[{i}].x"] for i in range(3)] == [4, 1, 1]
    assert plc["main.pts[1].y"] == 2.0


def test_enumeration_values_count_on_from_the_last_given_and_drive_a_case() -> None:
    machine = """
        CASE st OF
          IDLE: st := E_State#RUN; n := n + 1;
          E_State#RUN: st := DONE;
          DONE: st := IDLE; cycles := cycles + 1;
        END_CASE
        IF st = E_State#DONE THEN seen := TRUE; END_IF
    """
    plc = run(machine, "st : E_State; n, cycles : INT; seen : BOOL;")
    assert plc["main.st"] == 5  # IDLE (0) -> RUN, which is 5
    plc.scan()
    assert plc["main.st"] == 6 and plc["main.seen"] is True  # RUN -> DONE = 6
    plc.scan()
    assert (plc["main.st"], plc["main.cycles"]) == (0, 1)


def test_an_enumeration_starts_at_its_first_value_or_its_declared_default() -> None:
    plc = run("", "st : E_State; m : E_Mode; m2 : E_Mode := AUTO;")
    assert (plc["main.st"], plc["main.m"], plc["main.m2"]) == (0, 1, 0)


def test_codesys_qualified_enumeration_values_read_as_the_iec_typed_ones() -> None:
    # E_State.DONE is CODESYS's; with plc.strict = false it is E_State#DONE (SW002).
    plc = Plc(TYPES + program("IF E_State.DONE = E_State#DONE THEN ok := TRUE; END_IF",
                              "ok : BOOL;"), context=Context(strict=False)).scan()
    assert plc["main.ok"] is True


def test_a_subrange_starts_at_its_lower_limit_and_faults_outside_it() -> None:
    plc = run("p := p + 60;", "p : Pct; t : Temp;")
    assert (plc["main.p"], plc["main.t"]) == (60, 20)
    plc.scan()  # 120 is outside 0..100: an error (6.4.4.4), the PLC faults at the statement
    assert plc.runtime.status.state is PlcState.FAULT
    assert plc.runtime.status.fault is not None and plc.runtime.status.fault.span.line == \
        TYPES.count("\n") + 5


def test_an_alias_takes_its_base_type_and_its_own_default() -> None:
    plc = run("c := c + 1;", "c : Count;")
    assert plc["main.c"] == 43


def test_named_constants_give_array_bounds_case_labels_and_initial_values() -> None:
    source = """
    VAR_GLOBAL CONSTANT
      N : INT := 3;
      LAST : INT := N * 2;
    END_VAR
    PROGRAM main
    VAR CONSTANT
      LOW : INT := 1;
    END_VAR
    VAR
      a : ARRAY[LOW..LAST] OF INT := [3(N + 2)];
      start : INT := LAST + 1;
      k : INT := 6;
      hit : INT;
    END_VAR
    CASE k OF
      LOW..N: hit := 1;
      LAST: hit := 2;
    END_CASE
    END_PROGRAM
    """
    plc = Plc(source).scan()
    assert plc["main.a"] == [5, 5, 5, 0, 0, 0] and plc["main.start"] == 7
    assert plc["main.hit"] == 2


def test_multi_dimensional_arrays_fill_row_by_row_and_index_both_ways() -> None:
    # 6.4.4.5: [1, 2, 3, 4, 5, 6] fills m[1,1], m[1,2], m[1,3], m[2,1], ...
    plc = run("x := m[2, 1]; y := m[1][3]; aa[2][0] := m[2, 3] + 1; z := aa[2, 0];",
              "m : ARRAY[1..2, 1..3] OF INT := [1, 2, 3, 4, 5, 6]; x, y, z : INT;"
              "aa : ARRAY[1..2] OF ARRAY[0..1] OF INT;")
    assert (plc["main.x"], plc["main.y"], plc["main.z"]) == (4, 3, 7)
    assert plc["main.aa"] == [[0, 0], [7, 0]]


def test_an_index_outside_an_inner_dimension_faults() -> None:
    plc = run("i := 4; x := m[1, i];", "m : ARRAY[1..2, 1..3] OF INT; i, x : INT;")
    assert plc.runtime.status.state is PlcState.FAULT


def test_bit_access_reads_and_writes_one_bit() -> None:
    # Table 12: w.0 is the least significant bit; setting INT bit 15 makes it negative.
    plc = run("b0 := w.0; b3 := w.3; w.1 := TRUE; w.3 := FALSE; i.15 := TRUE; "
              "d.31 := TRUE; l.63 := TRUE;",
              "w : WORD := 16#0009; i : INT; d : DWORD; l : LWORD; b0, b3 : BOOL;")
    assert (plc["main.b0"], plc["main.b3"], plc["main.w"]) == (True, True, 0x0003)
    assert plc["main.i"] == -32768 and plc["main.d"] == 0x80000000
    assert plc["main.l"] == 1 << 63


def test_globals_are_shared_between_programs_in_scan_order() -> None:
    source = """
    VAR_GLOBAL
      counter : INT;
      seen : INT;
    END_VAR
    PROGRAM first
    counter := counter + 1;
    END_PROGRAM
    PROGRAM second
    VAR_EXTERNAL counter : INT; END_VAR
    seen := counter * 10;
    END_PROGRAM
    """
    plc = Plc(source).scan(2)
    # first runs before second in every scan: second sees this scan's count.
    assert plc.logic.namespace["_G"].v_SEEN == 20


def test_globals_of_one_file_serve_the_programs_of_another() -> None:
    gvl = "VAR_GLOBAL limit : INT := 3; END_VAR\n"
    prg = "PROGRAM main VAR n : INT; END_VAR IF n < limit THEN n := n + 1; END_IF END_PROGRAM"
    logic = compile_logic([parse_source(gvl, "gvl.st"), parse_source(prg, "main.st")],
                          Context())
    runtime = PlcRuntime(logic, IOImage(), RecordingNc(), ["main"])
    for t in range(5):
        runtime.scan(t * 10)
    assert runtime.read("main.n") == 3


def test_var_in_out_of_a_function_block_writes_the_callers_variable() -> None:
    source = """
    FUNCTION_BLOCK Bump
    VAR_IN_OUT v : INT; arr : ARRAY[1..3] OF INT; END_VAR
    VAR_INPUT step : INT; END_VAR
    v := v + step; arr[2] := arr[2] + 1;
    END_FUNCTION_BLOCK
    PROGRAM main
    VAR b : Bump; x : INT := 5; y : ARRAY[1..3] OF INT; END_VAR
    b(v := x, arr := y, step := 2);
    END_PROGRAM
    """
    plc = Plc(source).scan(2)
    assert plc["main.x"] == 9 and plc["main.y"] == [0, 2, 0]


def test_var_in_out_of_a_function_as_a_statement_and_on_the_right_of_an_assignment() -> None:
    source = """
    FUNCTION Swap : BOOL
    VAR_IN_OUT a, b : INT; END_VAR
    VAR t : INT; END_VAR
    t := a; a := b; b := t; Swap := TRUE;
    END_FUNCTION
    PROGRAM main
    VAR x : INT := 1; y : INT := 2; p : INT := 3; q : INT := 4; ok : BOOL; END_VAR
    Swap(x, y);
    ok := Swap(a := p, b := q);
    END_PROGRAM
    """
    plc = Plc(source).scan()
    assert (plc["main.x"], plc["main.y"], plc["main.p"], plc["main.q"], plc["main.ok"]) == (
        2, 1, 4, 3, True)


@pytest.mark.parametrize(("decl", "body", "expected"), [
    # 64-bit integers wrap at 2**63 and 2**64 (Table 10).
    ("v : LINT := 9223372036854775807;", "v := v + 1;", -(1 << 63)),
    ("v : ULINT;", "v := v - 1;", (1 << 64) - 1),
    ("v : LWORD := 16#FFFF_FFFF_FFFF_FFFF;", "v := v + 2;", 1),
    # LTIME is 64-bit nanoseconds: LT#1ms500us is 1,500,000 ns.
    ("v : LTIME := LT#1ms500us;", "v := v * 2;", 3_000_000),
    # TOD wraps at midnight: 23:59:59 + 2 s is 00:00:01.
    ("v : TOD := TOD#23:59:59;", "v := v + T#2s;", 1000),
    # DT + TIME, in seconds since 1970: 2024-01-31-23:00:00 + 2 h.
    ("v : DT := DT#2024-01-31-23:00:00;", "v := v + T#2h;", 1706742000 + 7200),
    # TIME * REAL (Table 30): T#1s * 1.5 = T#1.5s; TIME / REAL rounds to the ms.
    ("v : TIME := T#1s;", "v := v * 1.5;", 1500),
    ("v : TIME := T#1s;", "v := v / 3.0;", 333),
    # DATE - DATE is a TIME: two days.
    ("v : TIME;", "v := D#2024-03-01 - D#2024-02-28;", 2 * 86_400_000),
    # MOVE (Table 22) copies its input.
    ("v : ARRAY[1..2] OF INT; w : ARRAY[1..2] OF INT := [3, 4];", "v := MOVE(w); w[1] := 0;",
     [3, 4]),
])
def test_long_and_date_types_wrap_and_compute_as_iec_says(decl: str, body: str,
                                                          expected: object) -> None:
    assert Plc(program(body, decl)).scan()["main.v"] == expected


def test_date_conversions_split_a_date_and_time() -> None:
    plc = Plc(program("d := DT_TO_DATE(dt); t := DT_TO_TOD(dt); back := CONCAT_DATE_TOD(d, t);",
                      "dt : DT := DT#2024-01-31-12:30:15; d : DATE; t : TOD; back : DT;")).scan()
    assert plc["main.d"] == 1706659200 and plc["main.t"] == 45_015_000
    assert plc["main.back"] == 1706659200 + 45_015


def test_pragmas_are_accepted_and_ignored() -> None:
    source = ("{attribute 'qualified_only'}\n{attribute 'strict'}\nPROGRAM main\nVAR\n"
              "  {attribute 'hide'}\n  x : INT;\nEND_VAR\nx := 1 {info 'here'} + 1;\n"
              "END_PROGRAM\n")
    assert Plc(source).scan()["main.x"] == 2


def test_a_constant_var_in_out_is_read_as_the_callers_value_not_folded() -> None:
    # VAR_IN_OUT CONSTANT (6.5.2.2): a reference the callee may not write; its value is the
    # caller's at each call, never a folded 0.
    source = """
    FUNCTION Twice : INT
    VAR_IN_OUT CONSTANT v : INT; END_VAR
    Twice := v * 2;
    END_FUNCTION
    PROGRAM main
    VAR x : INT := 21; y : INT; END_VAR
    y := Twice(x);
    END_PROGRAM
    """
    assert Plc(source).scan()["main.y"] == 42



def test_the_console_shows_a_structure_as_its_members() -> None:
    from ncgate.gateway.web.status import plain

    plc = run("l.b.x := 5;", "l : Line;")
    value = plc["main.l"]
    assert plain(value, "", {}) == {"A": {"X": 1, "Y": 0.5},
                                "B": {"X": 5, "Y": 0.5}, "TAG": [7, 8]}


def test_a_value_two_enumerations_have_takes_its_type_from_the_context() -> None:
    # 6.4.4.2: where the context gives the type (the variable assigned, the CASE selector,
    # the other side of a comparison, an input), a shared value needs no prefix.
    source = """
    TYPE E_Color : (RED, GREEN); E_Light : (OFF, RED, AMBER); END_TYPE
    FUNCTION IsRed : BOOL VAR_INPUT c : E_Light; END_VAR IsRed := c = RED; END_FUNCTION
    PROGRAM main
    VAR c : E_Color; l : E_Light; hit, same, is_red : BOOL; END_VAR
    c := RED; l := RED;
    CASE l OF OFF: hit := FALSE; RED: hit := TRUE; END_CASE
    same := c = RED;
    is_red := IsRed(RED);
    END_PROGRAM
    """
    plc = Plc(source).scan()
    assert (plc["main.c"], plc["main.l"]) == (0, 1)
    assert (plc["main.hit"], plc["main.same"], plc["main.is_red"]) == (True, True, True)


def test_a_function_without_a_result_and_one_returning_a_structure_or_array() -> None:
    # 6.6.2.2: a FUNCTION may have no result (called as a statement, its VAR_IN_OUT or the
    # globals carry what it does) or a result of a derived type.
    source = TYPES + """
    FUNCTION Clear
    VAR_IN_OUT a : ARRAY[1..3] OF INT; END_VAR
    VAR i : INT; END_VAR
    FOR i := 1 TO 3 DO a[i] := 0; END_FOR
    END_FUNCTION
    FUNCTION Origin : Point
    Origin.x := 0; Origin.y := -1.0;
    END_FUNCTION
    FUNCTION Ramp : ARRAY[1..3] OF INT
    Ramp[1] := 1; Ramp[2] := 2; Ramp[3] := 3;
    END_FUNCTION
    PROGRAM main
    VAR v : ARRAY[1..3] OF INT := [7, 8, 9]; p : Point; r : ARRAY[1..3] OF INT; END_VAR
    Clear(v);
    p := Origin();
    r := Ramp();
    END_PROGRAM
    """
    plc = Plc(source).scan()
    assert plc["main.v"] == [0, 0, 0] and (plc["main.p.x"], plc["main.p.y"]) == (0, -1.0)
    assert plc["main.r"] == [1, 2, 3]


def test_a_function_without_a_result_in_an_expression_is_st020() -> None:
    from ncgate.plc.st.diagnostics import LogicError

    source = ("FUNCTION Noop\nVAR_INPUT x : INT; END_VAR\nEND_FUNCTION\nPROGRAM main\n"
              "VAR i : INT; END_VAR\ni := Noop(1);\nEND_PROGRAM\n")
    with pytest.raises(LogicError) as caught:
        Plc(source)
    d = caught.value.diagnostics[0]
    assert (d.code.code, d.span.line, d.span.column) == ("ST020", 6, 6)


def test_an_any_length_array_in_out_takes_arrays_of_any_bounds() -> None:
    # 6.5.3: ARRAY[*] in a VAR_IN_OUT; LOWER_BOUND and UPPER_BOUND give the caller's bounds.
    source = """
    FUNCTION SortInt
    VAR_IN_OUT a : ARRAY[*] OF INT; END_VAR
    VAR i, j : DINT; t : INT; END_VAR
    FOR i := LOWER_BOUND(a, 1) TO UPPER_BOUND(a, 1) - 1 DO
      FOR j := LOWER_BOUND(a, 1) TO UPPER_BOUND(a, 1) - 1 - (i - LOWER_BOUND(a, 1)) DO
        IF a[j] > a[j + 1] THEN t := a[j]; a[j] := a[j + 1]; a[j + 1] := t; END_IF
      END_FOR
    END_FOR
    END_FUNCTION
    FUNCTION_BLOCK Summer
    VAR_IN_OUT data : ARRAY[*] OF INT; END_VAR
    VAR_OUTPUT total : DINT; lo, hi : DINT; END_VAR
    VAR k : DINT; END_VAR
    total := 0; lo := LOWER_BOUND(data, 1); hi := UPPER_BOUND(data, 1);
    FOR k := lo TO hi DO total := total + data[k]; END_FOR
    END_FUNCTION_BLOCK
    PROGRAM main
    VAR a : ARRAY[-2..2] OF INT := [5, -1, 4, 0, 3]; b : ARRAY[10..12] OF INT := [9, 8, 7];
        s : Summer; total, lo, hi : DINT; fixed_hi : DINT; m : ARRAY[1..2, 3..9] OF INT;
    END_VAR
    SortInt(a); SortInt(b);
    s(data := b, total => total, lo => lo, hi => hi);
    fixed_hi := UPPER_BOUND(m, 2);
    END_PROGRAM
    """
    plc = Plc(source).scan()
    assert plc["main.a"] == [-1, 0, 3, 4, 5] and plc["main.b"] == [7, 8, 9]
    assert (plc["main.total"], plc["main.lo"], plc["main.hi"]) == (24, 10, 12)
    assert plc["main.fixed_hi"] == 9


def test_an_array_or_structure_in_out_is_the_callers_own_even_inside_an_expression() -> None:
    # 6.5.2.2: a VAR_IN_OUT is the caller's variable: the callee's writes, a whole
    # assignment too, are the caller's; an ARRAY[*] input is a copy (6.5.3).
    source = TYPES + """
    FUNCTION IndexOf : DINT
    VAR_IN_OUT a : ARRAY[*] OF INT; END_VAR
    VAR_INPUT x : INT; END_VAR
    VAR k : DINT; END_VAR
    IndexOf := -1;
    FOR k := LOWER_BOUND(a, 1) TO UPPER_BOUND(a, 1) DO
      IF a[k] = x THEN IndexOf := k; RETURN; END_IF
    END_FOR
    END_FUNCTION
    FUNCTION Reset : BOOL
    VAR_IN_OUT p : Point; END_VAR
    VAR fresh : Point; END_VAR
    fresh.x := 100; p := fresh; Reset := TRUE;
    END_FUNCTION
    FUNCTION Total : DINT
    VAR_INPUT a : ARRAY[*] OF INT; END_VAR
    VAR k : DINT; END_VAR
    FOR k := LOWER_BOUND(a, 1) TO UPPER_BOUND(a, 1) DO Total := Total + a[k]; a[k] := 0;
    END_FOR
    END_FUNCTION
    PROGRAM main
    VAR v : ARRAY[5..8] OF INT := [3, 9, 4, 9]; at, sum : DINT; p : Point; ok : BOOL; END_VAR
    at := IndexOf(v, 4) * 10 + IndexOf(v, 77);
    ok := Reset(p) AND TRUE;
    sum := Total(v);
    END_PROGRAM
    """
    plc = Plc(source).scan()
    assert plc["main.at"] == 7 * 10 - 1 and plc["main.sum"] == 25
    assert plc["main.v"] == [3, 9, 4, 9]  # Total's input was a copy
    assert (plc["main.p.x"], plc["main.ok"]) == (100, True)


def test_a_function_named_as_a_standard_one_replaces_it_only_when_not_strict() -> None:
    from ncgate.plc.st.diagnostics import LogicError

    source = ("FUNCTION INT_TO_STRING : STRING\nVAR_INPUT i : INT; END_VAR\n"
              "INT_TO_STRING := 'mine';\nEND_FUNCTION\n"
              "PROGRAM main\nVAR s : STRING; END_VAR\ns := INT_TO_STRING(5);\nEND_PROGRAM\n")
    with pytest.raises(LogicError) as caught:
        Plc(source)
    d = caught.value.diagnostics[0]
    assert (d.code.code, d.span.line, d.span.column) == ("ST032", 1, 1)
    plc = Plc(source, context=Context(strict=False)).scan()
    assert plc["main.s"] == "mine"
    assert [w.code.code for w in plc.logic.warnings] == ["SW002"]


def test_overloaded_to_conversions_take_the_arguments_own_type() -> None:
    # 6.6.2.5.2, Table 22: TO_INT(x) is <type of x>_TO_INT(x).
    plc = Plc(program("i := TO_INT(d); r := TO_REAL(i); s := TO_STRING(i); w := TO_WORD(b);"
                      "back := TO_DINT(2.5);",
                      "d : DINT := 70000; i : INT; r : REAL; s : STRING; w : WORD; "
                      "b : BOOL := TRUE; back : DINT;")).scan()
    # DINT_TO_INT wraps (70000 - 65536); LREAL_TO_DINT rounds half to even.
    assert (plc["main.i"], plc["main.r"], plc["main.s"]) == (4464, 4464.0, "4464")
    assert (plc["main.w"], plc["main.back"]) == (1, 2)


def test_a_function_with_outputs_binds_them_with_an_arrow() -> None:
    # 6.6.2.2 (3rd ed.): a FUNCTION may have VAR_OUTPUTs; the call binds them with =>;
    # one left unbound is dropped, and then the call is an ordinary expression.
    source = """
    FUNCTION DivMod : BOOL
    VAR_INPUT a, b : INT; END_VAR
    VAR_OUTPUT q, r : INT; END_VAR
    IF b = 0 THEN DivMod := FALSE; RETURN; END_IF
    q := a / b; r := a MOD b; DivMod := TRUE;
    END_FUNCTION
    PROGRAM main
    VAR ok, ok2, again : BOOL; q, r : INT; wide : DINT; END_VAR
    ok := DivMod(a := 17, b := 5, q => q, r => wide);
    DivMod(a := -7, b := 2, q => r);
    again := DivMod(a := 1, b := 0) OR TRUE;
    END_PROGRAM
    """
    plc = Plc(source).scan()
    assert (plc["main.ok"], plc["main.q"], plc["main.wide"]) == (True, 3, 2)
    assert plc["main.r"] == -3 and plc["main.again"] is True
