"""The parser against the spec's syntax (1.2-1.5): expected nodes and positions."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ncgate.interpreter.codes import DiagnosticCode
from ncgate.interpreter.diagnostics import LineError, ProgramSyntaxError, split_lines
from ncgate.interpreter.nc110.nodes import (
    Assign,
    Binary,
    Branch,
    BranchOp,
    Call,
    CompareOp,
    Display,
    Dwell,
    EndRepeat,
    Exe,
    InertCode,
    Jump,
    Num,
    Rel,
    Repeat,
    Snd,
    Span,
    Unary,
    VarKind,
    VarRef,
    View,
    WaitCond,
    WaitProc,
    Word,
)
from ncgate.interpreter.nc110.parser import Program, parse_block


def test_words_run_together_with_columns() -> None:
    block = parse_block("N3T1.1M6S1000F500", "p.nc", 7)
    assert block.number == 3
    assert [(w.letter, w.value, w.text, w.span.column) for w in block.items] == [  # type: ignore[union-attr]
        ("T", 1.1, "1.1", 3), ("M", 6.0, "6", 7), ("S", 1000.0, "1000", 9),
        ("F", 500.0, "500", 14),
    ]
    assert block.items[0].span == Span("p.nc", 7, 3)


def test_shared_shape_keeps_its_own_values_and_columns() -> None:
    # Same shape as the test above but other digit-run lengths: values and columns must follow.
    first = parse_block("N10G1X12.5F300")
    second = parse_block("N2000G1X7.125F12000")
    assert [(w.letter, w.value, w.span.column) for w in first.items] == [  # type: ignore[union-attr]
        ("G", 1.0, 4), ("X", 12.5, 6), ("F", 300.0, 11)]
    assert [(w.letter, w.value, w.span.column) for w in second.items] == [  # type: ignore[union-attr]
        ("G", 1.0, 6), ("X", 7.125, 8), ("F", 12000.0, 14)]
    assert second.number == 2000


def test_axis_value_from_e_parameter_and_signs() -> None:
    block = parse_block("N2G1XE12Y-3.25Z+.5")
    x, y, z = block.items[1:]
    e12 = VarRef(VarKind.E, 12, View.REAL, Span("<string>", 1, 6))
    assert isinstance(x, Word) and x.value == e12
    assert isinstance(y, Word) and y.value == -3.25
    assert isinstance(z, Word) and z.value == 0.5


def test_block_prefix_delete_label_number_sync_comment() -> None:
    block = parse_block('/"START"N25#(SND,2) ; sync with motion')
    assert block.deleted and block.label == "START" and block.number == 25 and block.synced
    assert block.comment == "sync with motion"
    (snd,) = block.items
    assert isinstance(snd, Snd) and snd.process == Num(2.0, Span("<string>", 1, 18))


def test_label_alone_and_empty_and_comment_lines() -> None:
    assert parse_block('"START"').label == "START"
    assert parse_block("").items == ()
    assert parse_block("   ; only a comment").comment == "only a comment"


def test_codes_and_argument_forms() -> None:
    exe = parse_block("(EXE,E4,Progl/MP2)").items[0]
    assert isinstance(exe, Exe) and exe.program == "Progl" and exe.device == "MP2"
    assert exe.process == VarRef(VarKind.E, 4, View.REAL, Span("<string>", 1, 6))
    assert isinstance(parse_block("( exe , 2 , PROG92 )").items[0], Exe)
    assert isinstance(parse_block("(REL)").items[0], Rel)
    wai = parse_block("(WAI,E1)").items[0]
    assert isinstance(wai, WaitProc)
    assert isinstance(parse_block("(BNC,START)").items[0], Jump)
    branch = parse_block("(BLT,E1,2,START)").items[0]
    assert isinstance(branch, Branch) and branch.op is BranchOp.LT and branch.label == "START"
    assert isinstance(parse_block("(RPT,3)").items[0], Repeat)
    assert isinstance(parse_block("(ERP)").items[0], EndRepeat)
    dly = parse_block("(DLY,0.5)").items[0]
    assert isinstance(dly, Dwell) and dly.seconds == Num(0.5, Span("<string>", 1, 6))
    dis = parse_block('(DIS,"part done",E1,E2)').items[0]
    assert isinstance(dis, Display) and dis.text == "part done" and len(dis.args) == 2


@pytest.mark.parametrize(
    ("text", "kind", "index", "view", "op", "value"),
    [
        ("(WAI,SA10=1)", VarKind.SA, 10, View.BIT, CompareOp.EQ, 1.0),
        ("(WAI,SA10.BY=2)", VarKind.SA, 10, View.BYTE, CompareOp.EQ, 2.0),
        ("(WAI,SA4.IN#-7)", VarKind.SA, 4, View.INT16, CompareOp.NE, -7.0),
        ("(WAI,SK250=8)", VarKind.SK, 250, View.BYTE, CompareOp.EQ, 8.0),
        ("(WAI,SK2.IN<300)", VarKind.SK, 2, View.INT16, CompareOp.LT, 300.0),
        ("(WAI,SYVAR2=31)", VarKind.SYVAR, 2, View.INT16, CompareOp.EQ, 31.0),
        ("(wai,syvar>5)", VarKind.SYVAR, 0, View.INT16, CompareOp.GT, 5.0),
    ],
)
def test_wait_conditions(text: str, kind: VarKind, index: int, view: View, op: CompareOp,
                         value: float) -> None:
    item = parse_block(text).items[0]
    assert isinstance(item, WaitCond)
    assert (item.var.kind, item.var.index, item.var.view, item.op) == (kind, index, view, op)
    assert isinstance(item.value, Num) and item.value.value == value


def test_wait_condition_with_e_parameter_value() -> None:
    item = parse_block("(WAI,SK2.IN=E11)").items[0]
    assert isinstance(item, WaitCond) and isinstance(item.value, VarRef)
    assert item.value.kind is VarKind.E and item.value.index == 11


def test_expressions_precedence_and_functions() -> None:
    item = parse_block("E8=10.3+20.7*SIN(30)-E2").items[0]
    assert isinstance(item, Assign)
    # ((10.3 + (20.7 * SIN(30))) - E2)
    top = item.expr
    assert isinstance(top, Binary) and top.op == "-"
    assert isinstance(top.left, Binary) and top.left.op == "+"
    mul = top.left.right
    assert isinstance(mul, Binary) and mul.op == "*"
    assert isinstance(mul.right, Call) and mul.right.func == "SIN"
    neg = parse_block("E1=-(E2+1)/2").items[0]
    assert isinstance(neg, Assign) and isinstance(neg.expr, Binary)
    assert isinstance(neg.expr.left, Unary)


def test_items_of_one_block_and_m100_rel() -> None:
    items = parse_block("M100(REL)").items
    assert isinstance(items[0], Word) and items[0].value == 100.0
    assert isinstance(items[1], Rel)
    items = parse_block("N60SYVAR1=E5 G1X3 (SND,2)").items
    assert [type(i) for i in items] == [Assign, Word, Word, Snd]


def test_unmodelled_code_is_kept_inert() -> None:
    item = parse_block("(UCG,2,X0,,X100)").items[0]
    assert item == InertCode("UCG", ("2", "X0", "", "X100"), Span("<string>", 1, 1))


@pytest.mark.parametrize(
    ("text", "code", "column", "fragment"),
    [
        ("(SDN,2)", DiagnosticCode.UNKNOWN_CODE, 2, "did you mean SND?"),
        ("(EXEC,2,P)", DiagnosticCode.UNKNOWN_CODE, 2, "did you mean EXE?"),
        ("N131(WAI,SA12=1", DiagnosticCode.MISSING_CLOSE_PAREN, 16, "to close (WAI"),
        ("N1(WAI,1 ; c", DiagnosticCode.MISSING_CLOSE_PAREN, 10, "to close (WAI"),
        ("N76GXY", DiagnosticCode.WORD_WITHOUT_VALUE, 4, "G needs a value"),
        ("N1G", DiagnosticCode.WORD_WITHOUT_VALUE, 3, "G needs a value"),
        ("N20(WAI,SYVAR,1)", DiagnosticCode.MISSING_COMPARISON, 14, "missing after SYVAR"),
        ('"START', DiagnosticCode.UNTERMINATED_STRING, 1, "closing"),
        ("N1 G1 X1 ?", DiagnosticCode.UNEXPECTED_TOKEN, 10, "'?'"),
        ("N1(WAI,1,2)", DiagnosticCode.UNEXPECTED_TOKEN, 9, "expected ')'"),
        ("(BNC)", DiagnosticCode.UNEXPECTED_TOKEN, 5, "expected ','"),
        ("N1 N2", DiagnosticCode.UNEXPECTED_TOKEN, 4, "'N2'"),
    ],
)
def test_syntax_errors_give_code_and_column(text: str, code: DiagnosticCode, column: int,
                                            fragment: str) -> None:
    with pytest.raises(LineError) as caught:
        parse_block(text, "bad.nc", 4)
    diagnostic = caught.value.diagnostic
    assert (diagnostic.code, diagnostic.span.line, diagnostic.span.column) == (code, 4, column)
    assert fragment in diagnostic.message
    rendered = diagnostic.render().splitlines()
    assert rendered[0] == f"bad.nc:4:{column}: error {code.code}: {diagnostic.message}"
    assert rendered[1] == f"  {text}"
    assert rendered[2] == "  " + " " * (column - 1) + "^"


def test_program_labels_prescan_and_lazy_blocks() -> None:
    text = 'N1G1X1F100\r\n"START"\r\nN2(BNC,START)\r\n/ "SKIP" N3\r\n'
    program = Program("P", "p.nc", text)
    assert program.labels == {"START": 1, "SKIP": 3}
    assert len(program) == 4
    assert program._blocks == [None] * 4  # nothing parsed yet
    assert program.block(2).number == 2
    assert program._blocks[0] is None and program._blocks[2] is not None


def test_program_reports_every_bad_line() -> None:
    program = Program("P", "p.nc", "N1GXY\nN2G1X1\nN3(SDN,1)\nN4(WAI,2\n")
    _, diagnostics = program.parse_all()
    assert [(d.code, d.span.line) for d in diagnostics] == [
        (DiagnosticCode.WORD_WITHOUT_VALUE, 1),
        (DiagnosticCode.UNKNOWN_CODE, 3),
        (DiagnosticCode.MISSING_CLOSE_PAREN, 4),
    ]


@pytest.mark.parametrize("end", ["\r", "\r\n", "\n"])
def test_cr_crlf_and_lf_each_end_a_block(end: str) -> None:
    # The file: with CR-only line ends it was one block, (WAI,...) swallowed into it.
    text = end.join(['E1=5', 'G1XE1F100', '"AGAIN"', '(WAI,SA1=1)', 'N5GXY', 'M30']) + end
    program = Program("P", "p.nc", text)
    assert list(program.lines) == ["E1=5", "G1XE1F100", '"AGAIN"', "(WAI,SA1=1)", "N5GXY", "M30"]
    assert program.labels == {"AGAIN": 2}
    _, diagnostics = program.parse_all()
    assert [(d.code, d.span.line, d.span.column, d.source_line) for d in diagnostics] == [
        (DiagnosticCode.WORD_WITHOUT_VALUE, 5, 3, "N5GXY")]


def test_a_mix_of_line_ends_counts_each_once() -> None:
    program = Program("P", "p.nc", "N1\r\nN2\rN3\nN4\r\r\nN6")
    assert list(program.lines) == ["N1", "N2", "N3", "N4", "", "N6"]


def test_a_bad_byte_in_a_cr_only_file_is_nc015_at_its_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "A.nc"
    path.write_bytes(b"N1G1X10F600\rN2(DIS,\"ok\")\r\nN3E1=1\xff\rN4M30\r")
    with pytest.raises(ProgramSyntaxError) as caught:
        Program.from_path(path, "A.nc")
    (d,) = caught.value.diagnostics
    assert (d.code, d.span.line, d.span.column, d.source_line) == (
        DiagnosticCode.NOT_UTF8, 3, 7, "N3E1=1\ufffd")


def test_line_ends_are_unified_piece_by_piece_without_cutting_a_crlf(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # Pieces of 3 characters: every CR LF of this text straddles a piece boundary somewhere.
    monkeypatch.setattr("ncgate.interpreter.nc110.parser._PIECE", 3)
    text = "N1\r\nN2\r\r\nN3\rN4\n\r\nN5\r"
    assert list(Program("P", "p.nc", text).lines) == split_lines(text) == [
        "N1", "N2", "", "N3", "N4", "", "N5"]


@given(st.lists(st.sampled_from(["a", "N1", "\r", "\n", "\r\n", " "]), max_size=40).map("".join),
       st.integers(min_value=1, max_value=9))
def test_split_lines_in_pieces_agrees_with_one_split(text: str, piece: int) -> None:
    """A long text is split a piece at a time (a 10 MB split was one 90 ms call into C):
    the lines are those of one split of the whole text at any piece size -- a CR LF across
    a piece's end is one line end, a line longer than a piece stays whole."""
    lines = re.split(r"\r\n?|\n", text)
    if lines[-1] == "":
        lines.pop()
    assert split_lines(text, piece) == lines
