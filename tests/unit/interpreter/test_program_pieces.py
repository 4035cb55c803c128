"""A long program text is split and searched a line-aligned piece at a time (so that reading a
10 MB program in a thread never holds the interpreter's lock for long): the lines and the
labels come out exactly as one split and one search of the whole text give them."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ncgate.interpreter.diagnostics import LINE_END
from ncgate.interpreter.nc110 import parser

LINES = st.sampled_from(['N1G1X1', '"L"', ' /"A B"', '', 'x\r', '"', 'N2(BNC,L)', '"Q" N5',
                         'N3(EXE,2,P)'])


def whole(text: str) -> tuple[list[str], list[tuple[str, int]]]:
    text = LINE_END.sub("\n", text)  # LF, CR LF and a lone CR each end a line
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    labels = []
    line_no, last = 0, 0
    for m in parser._LABELS.finditer(text):
        line_no += text.count("\n", last, m.start())
        last = m.start()
        labels.append((m.group(1), line_no))
    return lines, labels


@settings(max_examples=300, deadline=None)
@given(st.lists(LINES, max_size=40), st.sampled_from(["", "\n", "\r\n", "\n\n", "\r", "\r\r\n"]))
def test_pieces_give_what_the_whole_text_gives(lines: list[str], end: str) -> None:
    text = "\n".join(lines) + end
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(parser, "_PIECE", 7)  # many pieces, and some cut mid-line
        program = parser.Program("T", "T.nc", text)
    expected_lines, expected_labels = whole(text)
    assert list(program.lines) == expected_lines
    assert program.label_lines == expected_labels
