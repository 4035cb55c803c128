"""``ncgate check`` for the ISG dialect: each diagnostic's stable code at its position (spec
5.2, 1.6), and a program with errors never starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway.cli.main import main
from ncgate.gateway.sim import run_sim
from ncgate.gateway.wiring import external_bindings
from ncgate.interpreter.diagnostics import ProgramSyntaxError
from ncgate.interpreter.isg.checker import IsgCheckContext, check_file
from ncgate.interpreter.isg.parser import IsgFile

VE = {"IN1": {"map": "SYVAR5", "sync": True}, "LAMP": {"map": "SA10", "sync": False}}


def check(text: str, processes: int = 3) -> list[tuple[str, int, int]]:
    config = load_config(None, {"nc.ve": VE, "nc.processes": processes})
    context = IsgCheckContext(processes, config.nc.e_params, config.nc.isg.signal_params,
                              external_bindings(config))
    return [(d.code.code, d.span.line, d.span.column)
            for d in check_file(IsgFile.from_text(text, "p.nc"), context)]


@pytest.mark.parametrize(("text", "expected"), [
    ("#SIGAL [ID1]", ("IS002", 1, 1)),
    ("N10 $IFF P1 == 2", ("IS002", 1, 5)),
    ("G01 X F300", ("IS003", 1, 5)),
    ("G01 X[P1 + 2 F300", ("IS004", 1, 14)),  # where the ] was expected
    ("#WAIT [ID1 FOO]", ("IS005", 1, 12)),
    ("#WAIT [ID1 COUNT2 CH2]", ("IS005", 1, 12)),
    ("#WAIT SYN [ID1 P[0]=P1 CH2]", ("IS006", 1, 1)),
    ("P1 = V.E.IN2", ("IS007", 1, 6)),
    ("P1 = V.P.NEVER", ("IS008", 1, 6)),
    ("#SIGNAL [ID1 CH4]", ("IS009", 1, 16)),
    ("#SIGNAL [ID1 P[10]=1 CH2]", ("IS010", 1, 20)),
    ("$IF P1 == 1\nG01 X1 F1", ("IS011", 1, 1)),
    ("$ENDWHILE", ("IS011", 1, 1)),
    ("#VAR\nV.P.A = 1", ("IS011", 1, 1)),
    ("V.E.LAMP = 1", ("IS012", 1, 1)),
    ("#FLUSH G01 X1", ("IS013", 1, 8)),
    ("#SIGNAL [ID1.5 CH2]", ("IS014", 1, 12)),
    ("#SIGNAL [ID1 COUNT0 CH2]", ("IS014", 1, 19)),
    ("P1000 = 1", ("IS015", 1, 1)),
    ("#SIGNAL REMOVE [IDMAX 5]", ("IS016", 1, 1)),
    ("%channel4\nM30", ("IS009", 1, 1)),
])
def test_each_mistake_has_its_code_at_its_position(text: str,
                                                   expected: tuple[str, int, int]) -> None:
    assert check(text) == [expected]


def test_did_you_mean_for_commands_and_names() -> None:
    config = load_config(None, {"nc.ve": VE})
    context = IsgCheckContext(5, 1000, 10, external_bindings(config))
    source = IsgFile.from_text("#SIGAL [ID1]\nP1 = V.E.IN\nV.P.COUNT = 1\nP2 = V.P.CONT\n",
                               "p.nc")
    messages = [d.message for d in check_file(source, context)]
    assert "did you mean #SIGNAL?" in messages[0]
    assert "did you mean V.E.IN1?" in messages[1]
    assert "did you mean V.P.COUNT?" in messages[2]


def test_the_seeds_own_blocks_check_clean() -> None:
    text = """N200 #WAIT [ID4711]
N100 #WAIT SYN [ID815 CH2 CH3]
N250 P100 = 911
N300 #WAIT [IDP100 P[0]=V.P.SIGNAL P[1]=P200 CH3]
N350 P20 = 10 * P200
V.P.SYNC = 1000
#SIGNAL [IDP100 P[0]= V.P.SYNC CH3]
#SIGNAL [ID 110014 P[1] = 200 CH3] (unclosed comment
#WAIT [ID=5 CH 2 AHEAD]
#SIGNAL SYN [ID88 CH1]
#FLUSH WAIT
#SIGNAL REMOVE [IDMIN 5 IDMAX 9 CH2]
"""
    assert check(text) == []


def test_check_cli_renders_file_line_col_code_and_caret(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    program = tmp_path / "P.nc"
    program.write_text("G01 X10 F300\n#SIGAL [ID1]\n", encoding="utf-8")
    assert main(["check", "--dialect", "isg", str(program)]) == 1
    out = capsys.readouterr().out
    assert f"{program}:2:1: error IS002: unknown #SIGAL; did you mean #SIGNAL?" in out
    assert "\n  #SIGAL [ID1]\n  ^" in out
    # Without --dialect the built-in config's NC-110 reads it, and fails differently.
    assert main(["check", str(program)]) == 1
    assert "IS002" not in capsys.readouterr().out


def test_a_program_with_errors_never_starts(tmp_path: Path) -> None:
    (tmp_path / "BAD.nc").write_text("%channel1\nG01 X10 F300\n#WAIT SYN [ID1 P[0]=P1 CH2]\n"
                                     "%channel2\nM30\n", encoding="utf-8")
    (tmp_path / "ncgate.toml").write_text('[nc]\ndialect = "isg"\nmain = "BAD"\n')
    config = load_config(tmp_path / "ncgate.toml")
    with pytest.raises(ProgramSyntaxError) as raised:
        run_sim(config, "BAD", load_script(None))
    assert raised.value.diagnostics[0].code.code == "IS006"
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 2


def test_a_cr_only_file_has_one_block_a_line_and_only_cr_lf_and_crlf_end_lines() -> None:
    text = ("%channel1\rP1 = 5\rG01 X10 F300\r\n#SIGAL [ID1]\r"
            "M30 (a form feed \f or \u2028 ends no line)\r")
    source = IsgFile.from_text(text, "p.nc")
    assert len(source.lines) == 5
    assert [(d.code.code, d.span.line, d.span.column) for d in source.diagnostics] == [
        ("IS002", 4, 1)]


def test_a_bad_byte_in_a_cr_only_isg_file_is_nc015_at_its_line_and_column(
        tmp_path: Path) -> None:
    path = tmp_path / "P.nc"
    path.write_bytes(b"%channel1\rG01 X10 F300\rP1 = 2 (\xff)\rM30\r")
    with pytest.raises(ProgramSyntaxError) as raised:
        IsgFile.from_path(path, "P.nc")
    (d,) = raised.value.diagnostics
    assert (d.code.code, d.span.line, d.span.column, d.source_line) == (
        "NC015", 3, 9, "P1 = 2 (\ufffd)")


@pytest.mark.parametrize(("text", "expected"), [
    ("G01 X10 X20 F300", [("IS017", 1, 9)]),
    ("G01 X10 F100 F5000", [("IS017", 1, 14)]),
    ("G01 G00 X10 F300", [("IS018", 1, 5)]),
    ("G01 G01 X10 F300", [("IS017", 1, 5)]),
    ("G90 G91 XP1", [("IS018", 1, 5)]),
    ("X[P1 + 1] X[P2]", [("IS017", 1, 11)]),
    ("M03 M05", [("IS018", 1, 5)]),
    # G codes of different groups, M codes of different groups or the machine's own.
    ("G90 G01 X10 Y5 F300 M03 M08 M100", []),
])
def test_a_block_takes_one_word_an_address_and_one_code_a_modal_group(
        text: str, expected: list[tuple[str, int, int]]) -> None:
    assert check(text) == expected


@pytest.mark.parametrize(("text", "column"), [("G999 X1", 1), ("N10 G41 X1 F300", 5),
                                              ("G17", 1), ("M1.5", 1)])
def test_a_g_code_the_subset_does_not_implement_is_a_warning(text: str, column: int) -> None:
    assert check(text) == [("IW002", 1, column)]


def test_a_synchronous_read_under_cutter_compensation_is_the_controls_error_20651() -> None:
    text = ("%channel1\nN10 P1 = V.E.IN1\nN20 G42 G01 X10 F300\nN30 P2 = V.E.IN1 + 1\n"
            "N35 $IF V.E.IN1 == 1\nN36 $ENDIF\nN40 P3 = V.E.LAMP\nN50 G40 X0\n"
            "N60 P4 = V.E.IN1\nM30\n")
    assert check(text) == [("IW002", 3, 5), ("IS019", 4, 10), ("IS019", 5, 9)]
    message = next(d.message for d in check_file(
        IsgFile.from_text(text, "p.nc"),
        IsgCheckContext(3, 1000, 10, external_bindings(load_config(None, {"nc.ve": VE}))))
        if d.code.code == "IS019")
    assert "20651" in message and "line 3" in message
