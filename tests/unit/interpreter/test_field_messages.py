"""What the field found in the interpreter's messages (the issue "What the field found",
item 10): each names what is wrong in the terms the program was written in."""

from __future__ import annotations

import pytest

from ncgate.interpreter.codes import AlarmCode

from ...helpers import simulate


@pytest.mark.parametrize(("value", "shown"), [("32767.5", "not 32768 (32767.5 rounded)"),
                                              ("-32768.5", "not -32769 (-32768.5 rounded)"),
                                              ("40000", "not 40000")])
def test_a_syvar_out_of_range_names_the_rounded_value(value: str, shown: str) -> None:
    sim = simulate({"A": f"N1SYVAR5=1\nN2SYVAR5={value}\nN3M30\n"})
    alarm = sim.first("alarm", proc=1)
    assert (alarm["code"], alarm["line"], alarm["n"]) == (AlarmCode.VALUE_OUT_OF_RANGE.label,
                                                         2, 2)
    assert alarm["message"].endswith(f"SYVAR5 holds -32768..32767, {shown}")


def test_a_syvar_just_inside_the_range_is_stored() -> None:
    sim = simulate({"A": "N1SYVAR5=32766.5\nN2M30\n"})  # rounds half away: 32767
    assert sim.events("alarm") == [] and sim.image.read("SYVAR", 5, "IN") == 32767


@pytest.mark.parametrize("op", [">=", "<=", "<>", "=="])
def test_a_comparison_of_another_language_is_named_with_nc110s(op: str) -> None:
    from ncgate.interpreter.codes import DiagnosticCode
    from ncgate.interpreter.nc110.parser import Program

    program = Program("A", "A.nc", f"N1(WAI,SYVAR2{op}5)\nN2M30\n")
    _, diagnostics = program.parse_all()
    (d,) = diagnostics
    assert (d.code, d.span.line, d.span.column) == (DiagnosticCode.UNEXPECTED_TOKEN, 1, 14)
    assert d.message == (f"'{op}' is no comparison of NC-110: it has = (equal), # (not equal), "
                         "> and <")
