"""Issue 9.2 and 9.3: deep nesting, huge blocks and numbers at the edge give positioned
diagnostics or alarms at their block -- never a traceback, never inf in a trace."""

from __future__ import annotations

import json

import pytest

from ncgate.interpreter.diagnostics import LineError, ProgramSyntaxError
from ncgate.interpreter.engine.trace import write_jsonl
from ncgate.interpreter.nc110 import parser as parser_module
from ncgate.interpreter.nc110.checker import CheckContext, check_program
from ncgate.interpreter.nc110.parser import MAX_DEPTH, Program, parse_block

from ...helpers import simulate


def codes(text: str) -> list[tuple[str, int, int]]:
    program = Program("T", "T.nc", text)
    found = check_program(program, CheckContext())
    return [(d.code.code, d.span.line, d.span.column) for d in found]


# -- nesting ------------------------------------------------------------------------------

NESTINGS = {
    # name: (expression nested n deep, column of level n's token in "N1E1=" + expression)
    "sum": (lambda n: "+".join(["1"] * (n + 1)), lambda n: 6 + 2 * (n + 1) - 1 - 2 * (n - 1)),
    "parentheses": (lambda n: "(" * n + "1" + ")" * n, lambda n: 6 + n - 1),
    "signs": (lambda n: "-" * n + "1", lambda n: 6 + n - 1),
    "functions": (lambda n: "SIN(" * n + "1" + ")" * n, lambda n: 6 + 4 * (n - 1)),
}


@pytest.mark.parametrize("kind", sorted(NESTINGS))
def test_nesting_up_to_the_limit_parses_and_one_more_is_nc013_at_that_level(kind: str) -> None:
    make, _ = NESTINGS[kind]
    assert codes(f"N1E1={make(MAX_DEPTH)}\n") == []
    found = codes(f"N1E1={make(MAX_DEPTH + 1)}\n")
    assert [c[:2] for c in found] == [("NC013", 1)]


def test_the_caret_points_at_the_level_past_the_limit() -> None:
    # 65 parentheses: the 65th opens at column 6 + 64.
    assert codes("N1E1=" + "(" * 65 + "1" + ")" * 65 + "\n") == [("NC013", 1, 70)]
    assert codes("N1E1=" + "-" * 65 + "1\n") == [("NC013", 1, 70)]
    assert codes("N1E1=" + "SIN(" * 65 + "1" + ")" * 65 + "\n") == [("NC013", 1, 6 + 4 * 64)]


@pytest.mark.parametrize("depth", [99, 500, 5000])
def test_any_depth_is_a_diagnostic_not_a_traceback(depth: int) -> None:
    for make, _ in NESTINGS.values():
        found = codes(f'N1E1={make(depth)}\nN2(DIS,"a",{make(depth)})\n')
        assert [c[:2] for c in found] == [("NC013", 1), ("NC013", 2)]


def test_a_deep_sum_fits_when_written_with_a_second_parameter() -> None:
    """The documented way round the limit: split the sum."""
    text = "N1E1=" + "+".join(["1"] * 60) + "\nN2E1=E1+" + "+".join(["1"] * 60) + "\nN3M30\n"
    sim = simulate({"A": text + ""})
    assert sim.engine.processes[1].E[1] == 120


def test_a_huge_block_is_built_without_a_recipe_and_checked_whole() -> None:
    words = 160_000
    line = "N1G1F600" + "X1Y2" * (words // 2)
    shapes_before = len(parser_module._SHAPES)
    block = parse_block(line)
    assert len(block.items) == 2 + words
    assert len(parser_module._SHAPES) == shapes_before  # no recipe compiled for it
    bad = line + "Y"  # the last word has no value: found at its column
    with pytest.raises(LineError) as info:
        parse_block(bad)
    assert (info.value.diagnostic.code.code, info.value.diagnostic.span.column) == (
        "NC003", len(bad))


def test_long_and_short_blocks_build_the_same_nodes() -> None:
    short = '/N7#G1X-1.5YE3F600(WAI,SA3=1)(SND,2)SYVAR4=-(E1+2)*SIN(30)/4(DIS,"a",E1) ;c'
    # The same items, padded past the long-block limit with a comment.
    padded = short + " " * (parser_module.LONG_BLOCK + 10)
    a, b = parse_block(short), parse_block(padded)
    assert a.items == b.items and (a.number, a.deleted, a.synced) == (b.number, b.deleted,
                                                                      b.synced)


# -- numbers --------------------------------------------------------------------------------

HUGE = "9" * 401


@pytest.mark.parametrize(("text", "col"), [
    (f"N1E1={HUGE}", 6), (f"N1X{HUGE}", 4), (f"N1(WAI,{HUGE})", 8), (f"N1(SND,{HUGE})", 8),
    (f'N1(DIS,"a",{HUGE})', 12), (f"N1SYVAR1={HUGE}", 10), (f"N1(WAI,SYVAR1={HUGE})", 15),
    (f"N1(WAI,SYVAR1=-{HUGE})", 16), (f"N1(DLY,{HUGE})", 8), (f"N1(RPT,{HUGE})", 8),
])
def test_a_literal_too_large_for_a_double_is_nc014_where_it_stands(text: str, col: int) -> None:
    assert codes(text + "\n") == [("NC014", 1, col)]


BIG = "1" + "0" * 300  # 1e300: finite, but its square is not

OVERFLOWS = [
    "N2E2=E1*E1",
    "N2SYVAR1=E1*E1-E1*E1",  # inf - inf: not a number
    'N2(DIS,"x",E1*E1)',
    "N2(DLY,E1*E1)",
    "N2(BLT,E1*E1,0,L)",
    "N2#SYVAR1=E1*E1",
]


@pytest.mark.parametrize("block", OVERFLOWS)
def test_a_computed_overflow_is_an_alarm_at_its_block(block: str) -> None:
    sim = simulate({"A": f'"L"\nN1E1={BIG}\n{block}\nN3M30\n'})
    alarm = sim.first("alarm")
    assert (alarm["code"], alarm["line"], alarm["n"]) == ("AL103", 3, 2)
    assert "too large" in alarm["message"] or "not a number" in alarm["message"]
    out = __import__("io").StringIO()
    write_jsonl(sim.engine.trace.events, out)
    for line in out.getvalue().splitlines():
        json.loads(line, parse_constant=lambda c: pytest.fail(f"{c} in the trace"))


def test_a_move_too_long_to_represent_is_an_alarm() -> None:
    # Past the soft travel limit first (AL131); with no limits it is AL103 (test_limits.py).
    sim = simulate({"A": f"N1E1={'1' + '0' * 307}\nN2G1XE1F1\nN3M30\n"})
    alarm = sim.first("alarm")
    assert (alarm["code"], alarm["line"]) == ("AL131", 2)


def test_a_feed_of_zero_or_less_is_nc034_or_an_alarm() -> None:
    assert codes("N1G1X10F-100\nN2G1X5F0\nN3G1X1F100\n") == [("NC034", 1, 8), ("NC034", 2, 7)]
    sim = simulate({"A": "N1E1=-5\nN2G1X10FE1\nN3M30\n"})
    alarm = sim.first("alarm")
    assert (alarm["code"], alarm["line"]) == ("AL104", 2)
    assert alarm["message"] == "F-5: a feed must be positive"


def test_an_arc_whose_end_is_not_on_its_circle_is_an_alarm() -> None:
    sim = simulate({"A": "N1G2X10Y0I3J0F100\nN2M30\n"})
    alarm = sim.first("alarm")
    assert (alarm["code"], alarm["line"]) == ("AL104", 1)
    assert "radius 3.0000 mm at the start, 7.0000 mm at the end" in alarm["message"]
    # On the circle, within 0.002 mm: a half circle of radius 5.
    sim = simulate({"A": "N1G2X10.001Y0I5J0F100\nN2M30\n"})
    assert not sim.events("alarm")
    assert sim.first("end")["how"] == "M30"


def test_a_program_never_starts_with_a_syntax_error_anywhere() -> None:
    with pytest.raises(ProgramSyntaxError):
        simulate({"A": f"N1G1X1F100\nN2E1={'(' * 70}1{')' * 70}\n"})
