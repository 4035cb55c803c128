"""Structured Text as real libraries write it (OSCAT, blark's TwinCAT samples): the issue
"What the field found".  Each test failed before its fix."""

from __future__ import annotations

import random
from collections.abc import Iterator

import pytest

from ncgate.plc.image import IOImage
from ncgate.plc.scan import PlcRuntime, PlcState
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.diagnostics import LogicError
from ncgate.plc.st.parser import parse_source
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
z := 1 + MAX(EN := SA[0], 3, 9) + LIMIT(EN := SA[1], 0, 50, 20);
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
