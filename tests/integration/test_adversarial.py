"""Issue 9: the runtime under any program.  Hypothesis writes programs as an adversary would --
valid blocks and loops with and without motion, garbage, deep nesting, huge numbers, odd
encodings -- for three processes, and runs them through `check` and `sim --until`.

Whatever the input: no exception escapes (a program that cannot start is a ProgramError with
its diagnostics), every run ends (the runaway limit and --until bound it), the simulated time
never passes --until, every trace line is valid JSON with finite numbers, and a second run
writes the same trace byte for byte.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway.cli.check import check_files
from ncgate.gateway.sim import run_sim, write_trace
from ncgate.interpreter.diagnostics import ProgramError, ProgramNotFoundError

UNTIL = 30.0
SETTINGS = settings(max_examples=200, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])

small = st.integers(min_value=-3, max_value=400).map(str)
process = st.sampled_from(["1", "2", "3", "4", "9", "0", "E1"])
label = st.sampled_from(["L1", "L2", "L3"])
huge = st.integers(min_value=300, max_value=450).map(lambda n: "9" * n)


@st.composite
def expression(draw: st.DrawFn) -> str:
    kind = draw(st.sampled_from(["plain"] * 12 + ["deep", "huge", "overflow"]))
    if kind == "plain":
        return draw(st.sampled_from(["E1+1", "E2*0.5+E1", "SIN(E1)*3", "E1/E2", "SQR(E1-2)",
                                     "-(E1)", "SYVAR1+1", "SA3", "SK2.IN*2", "INT(E3/7)"]))
    if kind == "deep":
        depth = draw(st.integers(min_value=40, max_value=150))
        shape = draw(st.sampled_from(["(", "-", "SIN(", "+"]))
        if shape == "+":
            return "+".join(["1"] * depth)
        closing = ")" * depth if shape.endswith("(") else ""
        return shape * depth + "1" + closing
    if kind == "huge":
        return draw(huge)
    return "E1*" + "1" + "0" * 200 + "*" + "1" + "0" * 200  # finite literals, an inf product


@st.composite
def block(draw: st.DrawFn) -> str:
    # Mostly blocks that can run, so that most runs start; the rest is what users get wrong.
    kind = draw(st.sampled_from(3 * ["move", "assign", "syvar", "wai", "snd", "exe", "dis",
                                     "label", "jump", "branch", "rpt", "erp", "dly", "end",
                                     "hash"] + ["arc", "garbage", "cyrillic", "feed"]))
    n = f"N{draw(st.integers(min_value=1, max_value=99))}"
    if kind == "move":
        axis = draw(st.sampled_from("XYZ"))
        return f"{n}G{draw(st.sampled_from(['0', '1']))}{axis}{draw(small)}F{draw(small)}"
    if kind == "arc":
        return f"{n}G2X{draw(small)}Y{draw(small)}I{draw(small)}J0F500"
    if kind == "assign":
        return f"{n}E{draw(st.integers(min_value=0, max_value=3))}={draw(expression())}"
    if kind == "syvar":
        return f"{n}SYVAR{draw(st.integers(min_value=0, max_value=3))}={draw(expression())}"
    if kind == "wai":
        return draw(st.sampled_from([f"{n}(WAI,{draw(process)})",
                                     f"{n}(WAI,SYVAR1={draw(small)})", f"{n}(WAI,SA3=1)"]))
    if kind == "snd":
        return f"{n}(SND,{draw(process)})"
    if kind == "exe":
        return f"{n}(EXE,{draw(process)},{draw(st.sampled_from(['B', 'C', 'NOPE']))})"
    if kind == "dis":
        return f'{n}(DIS,"x",{draw(expression())})'
    if kind == "label":
        return f'"{draw(label)}"'
    if kind == "jump":
        return f"{n}(BNC,{draw(label)})"
    if kind == "branch":
        return f"{n}(BLT,E1,{draw(small)},{draw(label)})"
    if kind == "rpt":
        return f"{n}(RPT,{draw(st.sampled_from(['0', '2', '100000', 'E1', '-1']))})"
    if kind == "erp":
        return f"{n}(ERP)"
    if kind == "dly":
        return f"{n}(DLY,{draw(st.sampled_from(['0', '0.5', '2', '-1', 'E1']))})"
    if kind == "end":
        return f"{n}{draw(st.sampled_from(['M30', '(REL)', 'M02']))}"
    if kind == "hash":
        return f"{n}#SYVAR2={draw(small)}(SND,{draw(process)})"
    if kind == "feed":
        return f"{n}G1X5F{draw(st.sampled_from(['-100', '0', 'E1', '1e4']))}"
    if kind == "cyrillic":
        return f"{n}\u0415{draw(st.integers(min_value=0, max_value=3))}=\u04151+1"
    return draw(st.text(alphabet='GXN0123456789()=,#;".-+*/ \u0415\u041b\tSYVARWAIEXE',
                        max_size=40))


@st.composite
def program(draw: st.DrawFn) -> bytes:
    lines = draw(st.lists(block(), min_size=1, max_size=10))
    text = "\n".join(lines) + "\n"
    data = text.encode("utf-8")
    encoding = draw(st.sampled_from(8 * ["plain"] + ["bom", "crlf", "latin1", "bad-byte"]))
    if encoding == "bom":
        data = b"\xef\xbb\xbf" + data
    elif encoding == "crlf":
        data = data.replace(b"\n", b"\r\n")
    elif encoding == "latin1":
        data = text.encode("latin-1", "replace") + "\u00e9".encode("latin-1")
    elif encoding == "bad-byte":
        data = data[: len(data) // 2] + b"\xff" + data[len(data) // 2:]
    return data


def valid_trace(text: str) -> None:
    def no_constant(name: str) -> None:
        raise AssertionError(f"{name} in the trace")

    for line in text.splitlines():
        json.loads(line, parse_constant=no_constant)


@SETTINGS
@given(a=program(), b=program(), c=program(), lookahead=st.sampled_from([0, 16]),
       block_time=st.sampled_from([0, 0, 5]))
def test_any_program_is_a_diagnostic_an_alarm_or_a_run_never_a_crash(
        tmp_path_factory: object, a: bytes, b: bytes, c: bytes, lookahead: int,
        block_time: int) -> None:
    folder: Path = tmp_path_factory.mktemp("adv")  # type: ignore[attr-defined]
    for name, data in (("A", a), ("B", b), ("C", c)):
        (folder / f"{name}.nc").write_bytes(data)
    (folder / "ncgate.toml").write_text(
        f'[nc]\nmain = "A"\nprocesses = 3\nlookahead = {lookahead}\nrunaway_blocks = 3000\n'
        f'block_time_ms = {block_time}\n[nc.storage]\nMP0 = "."\n')
    config = load_config(folder / "ncgate.toml")

    files = [folder / "A.nc", folder / "B.nc", folder / "C.nc"]
    for _ in range(4):  # check; then drop the lines in error, so that most runs start
        errors = False
        for report in check_files(files, config):
            bad = set()
            for d in report.diagnostics:
                assert d.span.line >= 1 and d.span.column >= 1 and d.render()
                if d.is_error:
                    bad.add(d.span.line)
            if bad:
                errors = True
                lines = report.path.read_bytes().split(b"\n")
                report.path.write_bytes(b"\n".join(
                    line for i, line in enumerate(lines, start=1) if i not in bad))
        if not errors:
            break

    try:
        result = run_sim(config, ["A", "B", "C"], load_script(None), until=UNTIL)
    except (ProgramError, ProgramNotFoundError) as exc:  # the programs never start
        assert str(exc)
        event(f"not started: {str(exc).splitlines()[0][:60]}")
        return
    event(f"outcome {result.outcome}")
    assert result.outcome in {"idle", "until", "stall", "alarm"}
    assert result.runtime.engine.now <= UNTIL
    out = io.StringIO()
    write_trace(result, out)
    valid_trace(out.getvalue())
    again = io.StringIO()  # and deterministic: the same trace, byte for byte
    write_trace(run_sim(config, ["A", "B", "C"], load_script(None), until=UNTIL), again)
    assert again.getvalue() == out.getvalue()
