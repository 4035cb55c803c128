"""Structured Text programs run scan by scan; each expected value is worked out from
IEC 61131-3 (3rd ed.) by hand, in the comment beside it, not taken from the compiler."""

from __future__ import annotations

import pytest

from ncgate.plc.scan import PlcState

from .st_harness import Plc, program


def run(body: str, decls: str, scans: int = 1) -> Plc:
    return Plc(program(body, decls)).scan(scans)


def test_integers_wrap_when_stored() -> None:
    plc = run("""
        i := 32767; i := i + 1;          (* INT: 32767 + 1 wraps to -32768 *)
        u := 255; u := u + 1;            (* USINT: 0 *)
        s := -128; s := s - 1;           (* SINT: 127 *)
        w := 0; w := w - 1;              (* WORD: 65535 *)
        d := 2147483647; d := d + 1;     (* DINT: -2147483648 *)
        ud := 0; ud := ud - 1;           (* UDINT: 4294967295 *)
        big := 30000 + 30000;            (* DINT holds 60000: no wrap *)
        mid := (i + 0) / 2;              (* exact intermediate: -32768 / 2 = -16384 *)
    """, "i, mid : INT; u : USINT; s : SINT; w : WORD; d, big : DINT; ud : UDINT;")
    assert [plc[f"main.{v}"] for v in ("i", "u", "s", "w", "d", "ud", "big", "mid")] == [
        -32768, 0, 127, 65535, -2147483648, 4294967295, 60000, -16384]


def test_division_truncates_toward_zero_and_mod_takes_the_dividends_sign() -> None:
    plc = run("""
        a := -7; b := 2;
        q1 := a / b;        (* -3, not -4 *)
        m1 := a MOD b;      (* -1 *)
        m2 := 7 MOD -2;     (* 1 *)
        q2 := 7 / -2;       (* -3 *)
        r := 7.0 / 2.0;     (* 3.5 *)
    """, "a, b, q1, m1, m2, q2 : INT; r : REAL;")
    assert (plc["main.q1"], plc["main.m1"], plc["main.m2"], plc["main.q2"], plc["main.r"]) == (
        -3, -1, 1, -3, 3.5)


def test_by_a_positive_constant_the_same_rules_hold() -> None:
    """By a positive constant the compiled code divides inline, not through a helper: the
    standard's results all the same, nested and with a dividend that is read once."""
    plc = run("""
        a := -7;
        q1 := a / 2;                    (* -3 *)
        m1 := a MOD 2;                  (* -1 *)
        m2 := a MOD 7;                  (* 0 *)
        q2 := 7 / 2;                    (* 3 *)
        q3 := (a / 2) MOD 2;            (* -3 MOD 2 = -1 *)
        q4 := (a MOD 4) / 3 + a / 3;    (* -3 / 3 + -2 = -3 *)
        n := n + 1;
        q5 := (n * -5) / 2;             (* n = 1: -5 / 2 = -2 *)
    """, "a, q1, q2, q3, q4, q5, m1, m2, n : INT;")
    assert [plc[f"main.{v}"] for v in ("q1", "m1", "m2", "q2", "q3", "q4", "q5")] == [
        -3, -1, 0, 3, -1, -3, -2]


def test_precedence_of_the_standard() -> None:
    plc = run("""
        x1 := 2 + 3 * 4;                 (* 14 *)
        x2 := (2 + 3) * 4;               (* 20 *)
        b1 := 1 + 2 = 3;                 (* comparison is looser than +: TRUE *)
        b2 := NOT f AND t;               (* (NOT f) AND t = TRUE *)
        b3 := t OR t AND f;              (* AND before OR: TRUE *)
        b4 := t XOR t OR t;              (* XOR before OR: (t XOR t) OR t = TRUE *)
        b5 := t XOR t AND f;             (* AND before XOR: t XOR (t AND f) = TRUE *)
        b6 := 3 > 2 = TRUE;              (* > before =: (3 > 2) = TRUE *)
        r1 := 2.0 ** 3.0 * 2.0;          (* ** before *: 16.0 *)
        r2 := -2.0 ** 2.0;               (* unary minus before ** (7.3.2's grammar): 4.0 *)
        x3 := 10 - 4 - 3;                (* left to right: 3 *)
        x4 := 7 & 3;                     (* & is AND: bitwise on integers = 3 *)
    """, "x1, x2, x3, x4 : INT; b1, b2, b3, b4, b5, b6, t : BOOL := TRUE; f : BOOL; "
         "r1, r2 : REAL;")
    got = [plc[f"main.{v}"] for v in ("x1", "x2", "b1", "b2", "b3", "b4", "b5", "b6", "r1",
                                       "r2", "x3", "x4")]
    assert got == [14, 20, True, True, True, True, True, True, 16.0, 4.0, 3, 3]


def test_literals() -> None:
    plc = run("""
        a := 16#FF; b := 2#1010_1010; c := 8#17; d := 1_000; e := INT#-5;
        t1 := T#1s500ms; t2 := T#1.5s; t3 := TIME#1m; t4 := T#1h2m3s4ms; t5 := T#-250ms;
        w := WORD#16#FFFF; r := REAL#2; bo := BOOL#1; x := 1.5E3;
    """, "a, b, c, d, e : INT; t1, t2, t3, t4, t5 : TIME; w : WORD; r, x : REAL; bo : BOOL;")
    assert [plc[f"main.{v}"] for v in ("a", "b", "c", "d", "e")] == [255, 170, 15, 1000, -5]
    assert [plc[f"main.t{i}"] for i in range(1, 6)] == [1500, 1500, 60000, 3723004, -250]
    assert (plc["main.w"], plc["main.r"], plc["main.bo"], plc["main.x"]) == (65535, 2.0,
                                                                              True, 1500.0)


def test_case_with_lists_ranges_and_else() -> None:
    source = program("""
        CASE sel OF
          1, 3: out := 10;
          4..6: out := 20;
          -2: out := 30;
        ELSE
          out := 99;
        END_CASE
        sel := sel + 1;
    """, "sel : INT := -2; out : INT;")
    plc = Plc(source)
    seen = []
    for _ in range(10):  # sel = -2 .. 7
        plc.scan()
        seen.append(plc["main.out"])
    assert seen == [30, 99, 99, 10, 99, 10, 20, 20, 20, 99]


def test_loops_exit_and_their_variables() -> None:
    plc = run("""
        sum := 0;
        FOR i := 10 TO 1 BY -3 DO sum := sum + i; END_FOR   (* 10 + 7 + 4 + 1 = 22 *)
        after := i;                                          (* -2: one step past the end *)
        FOR j := 1 TO 100 DO IF j = 5 THEN EXIT; END_IF END_FOR
        n := 0;
        WHILE n < 3 DO n := n + 1; END_WHILE
        REPEAT k := k + 1; UNTIL TRUE END_REPEAT             (* runs once *)
        FOR j2 := 5 TO 1 DO never := 1; END_FOR             (* never runs *)
    """, "i, j, j2, sum, after, n, k, never : INT;")
    assert [plc[f"main.{v}"] for v in ("sum", "after", "j", "n", "k", "never")] == [
        22, -2, 5, 3, 1, 0]


def test_return_ends_the_program_for_this_scan() -> None:
    plc = run("a := 1; IF a = 1 THEN RETURN; END_IF a := 2;", "a : INT;")
    assert plc["main.a"] == 1


def test_functions_and_function_blocks() -> None:
    source = """
FUNCTION Scale : REAL
VAR_INPUT x : INT; factor : REAL := 2.0; END_VAR
Scale := INT_TO_REAL(x) * factor;
END_FUNCTION

FUNCTION_BLOCK Debounce
VAR_INPUT raw : BOOL; scans : INT := 3; END_VAR
VAR_OUTPUT stable : BOOL; END_VAR
VAR count : INT; END_VAR
IF raw THEN count := count + 1; ELSE count := 0; END_IF
stable := count >= scans;
END_FUNCTION_BLOCK

PROGRAM main
VAR d : Debounce; out : BOOL; a, b, c : REAL; END_VAR
a := Scale(5);                 (* factor defaults to 2.0: 10.0 *)
b := Scale(x := 5, factor := 0.5);
c := Scale(3, 3.0);
d(raw := SA[0], stable => out);
SA[1] := out;
END_PROGRAM
"""
    plc = Plc(source)
    plc.image.write([("SA", 0, "bit", 1)], "test")
    stable = [bool(plc.scan().image.read("SA", 1, "bit")) for _ in range(4)]
    assert stable == [False, False, True, True]  # TRUE from the third scan with raw
    assert (plc["main.a"], plc["main.b"], plc["main.c"]) == (10.0, 2.5, 9.0)
    assert plc["main.d.stable"] is True


def test_arrays_with_initial_values_and_repetition() -> None:
    plc = run("""
        total := 0;
        FOR i := 1 TO 6 DO total := total + v[i]; END_FOR     (* 1+2+7+7+7+0 = 24 *)
        v[6] := 5;
    """, "v : ARRAY[1..6] OF INT := [1, 2, 3(7)]; i, total : INT;")
    assert plc["main.total"] == 24
    assert plc["main.v"] == [1, 2, 7, 7, 7, 5]
    assert plc["main.v[6]"] == 5


def test_conversions_round_half_to_even_and_wrap() -> None:
    plc = run("""
        a := REAL_TO_INT(2.5); b := REAL_TO_INT(3.5); c := REAL_TO_INT(-2.5);
        d := INT_TO_BYTE(300); e := DINT_TO_INT(70000); f := BOOL_TO_INT(TRUE);
        g := INT_TO_BOOL(7); h := TIME_TO_DINT(T#2s); t := DINT_TO_TIME(250);
        k := TRUNC(-2.7);
    """, "a, b, c, e, f : INT; d : BYTE; g : BOOL; h, k : DINT; t : TIME;")
    assert [plc[f"main.{v}"] for v in "abcdefghtk"] == [2, 4, -2, 44, 4464, 1, True, 2000,
                                                        250, -2]


def test_standard_functions() -> None:
    plc = run("""
        a := ABS(-5); b := MIN(4, 2, 9); c := MAX(4, 2, 9); d := LIMIT(0, 15, 10);
        e := SEL(TRUE, 1, 2); f := MUX(2, 10, 20, 30);
        w1 := SHL(WORD#16#8001, 1); w2 := SHR(WORD#16#8001, 1); w3 := ROL(WORD#16#8001, 1);
        w4 := ROR(WORD#16#8001, 1); r := SQRT(16.0);
    """, "a, b, c, d, e, f : INT; w1, w2, w3, w4 : WORD; r : REAL;")
    assert [plc[f"main.{v}"] for v in ("a", "b", "c", "d", "e", "f")] == [5, 2, 9, 10, 2, 30]
    assert [plc[f"main.w{i}"] for i in range(1, 5)] == [0x0002, 0x4000, 0x0003, 0xC000]
    assert plc["main.r"] == 4.0


def test_timers_see_the_scan_clock() -> None:
    """TON with PT 30 ms on a 10 ms scan: IN rises at the scan of t=0, Q at t=30."""
    plc = Plc(program("t(IN := SA[0], PT := T#30ms); SA[1] := t.Q;", "t : TON;"))
    plc.image.write([("SA", 0, "bit", 1)], "test")
    q = []
    for _ in range(5):
        plc.scan()
        q.append((plc.now_ms - 10, plc.image.read("SA", 1, "bit"), plc["main.t.ET"]))
    assert q == [(0, 0, 0), (10, 0, 10), (20, 0, 20), (30, 1, 30), (40, 1, 30)]


def test_r_trig_pulses_for_one_scan() -> None:
    plc = Plc(program("r(CLK := SA[0]); IF r.Q THEN n := n + 1; END_IF", "r : R_TRIG; n : INT;"))
    plc.scan()
    plc.image.write([("SA", 0, "bit", 1)], "test")
    plc.scan(3)  # one rising edge, held for three scans: one pulse
    plc.image.write([("SA", 0, "bit", 0)], "test")
    plc.scan()
    plc.image.write([("SA", 0, "bit", 1)], "test")
    plc.scan()
    assert plc["main.n"] == 2


def test_outputs_are_one_write_by_plc_and_only_what_changed() -> None:
    plc = Plc(program("SA[3] := TRUE; SA[12] := SA[0]; SK[2] := 7; SYVAR[1] := -5; "
                      "SAB[5] := SAB[5];", ""))
    plc.scan()
    assert len(plc.writes) == 1
    changes, who = plc.writes[0]
    assert who == "plc"
    assert sorted((c.area, c.index, c.view, c.value) for c in changes) == [
        ("SA", 3, "bit", 1), ("SK", 2, "BY", 7), ("SYVAR", 1, "IN", -5)]
    plc.scan()  # nothing changes: no write at all
    assert len(plc.writes) == 1
    plc.image.write([("SA", 0, "bit", 1)], "test")  # a fieldbus write between scans
    plc.scan()
    assert [(c.index, c.value) for c in plc.writes[-1][0]] == [(12, 1)]


def test_a_fault_holds_the_outputs_and_names_the_statement() -> None:
    source = program("""
SA[1] := TRUE;
SYVAR[2] := 10 / d;
SA[2] := TRUE;
""", "d : INT := 1;")
    plc = Plc(source)
    plc.scan()
    assert plc.image.read("SYVAR", 2, "IN") == 10
    plc.runtime.programs["MAIN"].v_D = 0
    plc.image.write([("SA", 1, "bit", 0)], "test")
    plc.scan()
    status = plc.runtime.status
    assert status.state is PlcState.FAULT
    assert status.fault is not None and status.fault.span is not None
    # line 5 is the empty line the body starts with: SYVAR[2] := 10 / d is line 7
    assert (status.fault.span.line, status.fault.span.column) == (7, 1)
    assert plc.nc.faults == ["test.st:7:1: division by zero"]
    # Nothing of the faulting scan reached the image; no scan runs while in FAULT.
    assert plc.image.read("SA", 1, "bit") == 0
    plc.scan(3)
    assert plc.image.read("SA", 1, "bit") == 0 and status.scans == 1
    plc.runtime.restart()  # the NC's reset: initial values again (d = 1)
    plc.scan()
    assert status.state is PlcState.RUNNING and plc.image.read("SA", 1, "bit") == 1


@pytest.mark.parametrize(("body", "decls", "line", "column", "words"), [
    ("i := 11;\nv[i] := 1;", "v : ARRAY[1..10] OF INT; i : INT;", 6, 1, "index 11 outside 1..10"),
    ("i := 64;\nSA[i] := TRUE;", "i : INT;", 6, 1, "index 64 outside 0..63"),
    ("WHILE TRUE DO\n  i := i + 1;\nEND_WHILE", "i : INT;", 5, 1, "loop iterations"),
    ("i := 0;\nx := 5 MOD i;", "i, x : INT;", 6, 1, "MOD by zero"),
    ("k := 9;\nx := NC.P[k].STATE;", "k, x : INT;", 6, 1, "index 9 outside 1..5"),
])
def test_runtime_errors_fault_at_their_statement(body: str, decls: str, line: int,
                                                 column: int, words: str) -> None:
    plc = Plc(program(body, decls), loop_limit=1000)
    plc.scan()
    fault = plc.runtime.status.fault
    assert fault is not None and fault.span is not None
    assert (fault.span.line, fault.span.column) == (line, column)
    assert words in fault.message


def test_nc_inputs_and_outputs() -> None:
    source = program("""
        st := NC.P[2].STATE; waiting := NC.P[2].WAITING; ev := NC.EVENTS;
        sender := NC.LAST_SND.SENDER; seq := NC.LAST_SND.SEQ;
        NC.START := SA[0];
        NC.HOLD := SA[2];
        IF SA[1] THEN NC.SEND(4, 2); END_IF
    """, "st, sender : INT; waiting : BOOL; ev, seq : UDINT;")
    plc = Plc(source)
    plc.nc.processes[1] = (3, 40, 8, True, False, 0, False, False)
    plc.nc.event_count, plc.nc.last = 17, (4, 2, 9)
    plc.scan()
    assert (plc["main.st"], plc["main.waiting"], plc["main.ev"], plc["main.sender"],
            plc["main.seq"]) == (3, True, 17, 4, 9)
    plc.image.write([("SA", 0, "bit", 1), ("SA", 1, "bit", 1)], "test")
    plc.scan(3)  # START held TRUE: one cycle start; SEND every scan it is called
    assert plc.nc.commands == [1]
    assert plc.nc.sends == [(4, 2)] * 3
    plc.image.write([("SA", 0, "bit", 0)], "test")
    plc.scan()
    plc.image.write([("SA", 0, "bit", 1)], "test")
    plc.scan()
    assert plc.nc.commands == [1, 1]
    plc.image.write([("SA", 2, "bit", 1)], "test")  # HOLD rises while START stays TRUE:
    plc.scan()                                       # a feed hold, and no new cycle start
    assert plc.nc.commands == [1, 1, 2]
    plc.nc.refuse_sends = True
    plc.scan()
    assert plc.nc.hazards == ["PLC NC.SEND(4, 2): process 2 runs no program"]


def test_nc_commissioning_outputs() -> None:
    """Issue 27's ST names: NC.P[k].START/HOLD/RESET act on a rising edge for process k;
    NC.OPT_STOP and NC.BLOCK_SKIP are switches (8/9, 10/11 as they change); NC.HOLD_LEVEL
    holds as it rises; NC.FEED_OVERRIDE and NC.P[k].FEED_OVERRIDE act as they change."""
    source = program("""
        NC.P[2].START := SA[0];
        NC.P[3].RESET := SA[1];
        NC.OPT_STOP := SA[2];
        NC.BLOCK_SKIP := SA[3];
        NC.HOLD_LEVEL := SA[4];
        NC.FEED_OVERRIDE := SYVAR[1];
        NC.P[2].FEED_OVERRIDE := SYVAR[2];
    """, "")
    plc = Plc(source)
    plc.image.write([("SYVAR", 1, "IN", 100), ("SYVAR", 2, "IN", 100)], "test")
    plc.scan()
    assert plc.nc.commands == [] and plc.nc.overrides == []  # 100 %: nothing changed
    plc.image.write([("SA", 0, "bit", 1), ("SA", 2, "bit", 1), ("SYVAR", 1, "IN", 50)],
                    "test")
    plc.scan(3)  # edges once, levels once, the override once
    assert plc.nc.commands == [8, (1, 2)]  # the cell's outputs, then each process's
    assert plc.nc.overrides == [(50, None)]
    plc.image.write([("SA", 1, "bit", 1), ("SA", 2, "bit", 0), ("SA", 3, "bit", 1),
                     ("SA", 4, "bit", 1), ("SYVAR", 2, "IN", 0)], "test")
    plc.scan()
    assert plc.nc.commands == [8, (1, 2), 9, 10, 2, (3, 3)]
    assert plc.nc.overrides == [(50, None), (0, 2)]
    assert plc.runtime.hold_level


def test_a_refused_nc_command_is_a_hazard_and_the_scan_goes_on() -> None:
    from ncgate.errors import InputRefused, Reason

    plc = Plc(program("NC.START := SA[0]; n := n + 1;", "n : INT;"))

    def refuse(word: int, where: str = "", process: int | None = None) -> None:
        raise InputRefused(Reason.INTERLOCK, "cycle_start: feed hold input SA100 is set")

    plc.nc.command = refuse  # type: ignore[method-assign]
    plc.image.write([("SA", 0, "bit", 1)], "test")
    plc.scan(2)
    assert plc["main.n"] == 2  # it scanned on
    assert len(plc.nc.hazards) == 1 and plc.nc.hazards[0].startswith("PLC command 1 at test.st:")
    assert plc.nc.hazards[0].endswith(": cycle_start: feed hold input SA100 is set")
