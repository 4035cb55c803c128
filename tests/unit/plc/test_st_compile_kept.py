"""A compilation is kept for the next load of the same parse (a suite of scenarios compiles
one logic again and again), and shares nothing that changes: each Logic has its own
namespace, program instances and variables' tables.  Big logic is not kept."""

from __future__ import annotations

from ncgate.plc.st import logic
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.parser import parse_source

from .st_harness import program


def test_the_same_parse_is_compiled_once_and_each_logic_has_its_own_state() -> None:
    parsed = parse_source(program("n := n + 1;", "n : DINT;"), "kept.st")
    first = compile_logic([parsed], Context())
    second = compile_logic([parsed], Context())
    assert first.python_source is second.python_source  # the kept compilation
    assert first.namespace is not second.namespace
    run = first.namespace["P_MAIN"]()
    run()
    run()
    assert run.v_N == 2
    assert second.namespace["P_MAIN"]().v_N == 0  # nothing of the first one's run
    assert first.programs["MAIN"] is not second.programs["MAIN"]
    other = compile_logic([parsed], Context(processes=2))  # another context: compiled anew
    assert other.python_source is not first.python_source


def test_a_big_logic_is_compiled_anew_each_time() -> None:
    body = "".join(f"x := x * 3 + {k};\n" for k in range(3000))
    parsed = parse_source(program(body, "x : DINT;"), "big.st")
    first = compile_logic([parsed], Context())
    assert len(first.python_source) > logic.KEPT_SOURCE_MAX
    assert compile_logic([parsed], Context()).python_source is not first.python_source
