"""Diagnostics and the package's exceptions (spec 1.6).

A diagnostic renders as ``file:line:col: error CODE: message``, then the source line and a
caret under the column, like a compiler.  Must not import ``plc`` or ``gateway``.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Final, NamedTuple

from ncgate.errors import NcgateError, render_diagnostic
from ncgate.interpreter.codes import AlarmCode, DiagnosticCode, Severity


class Span(NamedTuple):
    """Where a node stands: file, line and column, 1-based.

    A NamedTuple rather than a dataclass: one is built for every node of every line, and a
    tuple builds fastest; it is immutable all the same.
    """

    file: str
    line: int
    column: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"


@dataclass(frozen=True, slots=True)
class Diagnostic:
    code: DiagnosticCode
    message: str
    span: Span
    source_line: str

    @property
    def severity(self) -> Severity:
        return self.code.severity

    @property
    def is_error(self) -> bool:
        return self.code.severity is Severity.ERROR

    def render(self) -> str:
        span = self.span
        return render_diagnostic(span.file, span.line, span.column, self.severity.value,
                                 self.code.code, self.message, self.source_line)

    def __str__(self) -> str:
        return self.render()


def render_all(diagnostics: Iterable[Diagnostic]) -> str:
    return "\n".join(d.render() for d in diagnostics)


def fmt_number(value: float | None) -> str:
    """A value as a message shows it: whole numbers without a point, and at most six
    significant digits once it is that large (1e+300, never its 301 digits; inf, nan)."""
    if value is None:
        return "?"
    if abs(value) < 1e15 and value == int(value):
        return str(int(value))
    return f"{value:g}"


# A line of a program ends at LF, CR LF or a lone CR, in both dialects: files from old
# controls and some DOS-era editors end lines with CR alone, and a file read as one long
# block would hide every block after the first.  Only these three: a form feed or U+2028 in
# a comment does not start a line, so line numbers agree with what an editor shows.
LINE_END: Final = re.compile(r"\r\n?|\n")


# split_lines splits a long text this many characters at a time: one split of 10 MB is one
# call into C that held the interpreter's lock ~90 ms (a reading thread's, the loop waiting).
SPLIT_PIECE: Final = 1 << 16


def split_lines(text: str, piece: int = SPLIT_PIECE) -> list[str]:
    """The lines of a program text; a line end at the very end opens no empty line.  A long
    text is split in pieces that end at a line end, a short call into C each."""
    if len(text) <= piece:
        lines = LINE_END.split(text)
    else:
        lines = []
        start, size = 0, len(text)
        while start < size:
            end = start + piece
            if end >= size:
                lines.extend(LINE_END.split(text[start:]))
                break
            cut = max(text.rfind("\n", start, end), text.rfind("\r", start, end))
            if cut < start:  # a line longer than a piece: up to its own end
                found = LINE_END.search(text, end)
                if found is None:
                    lines.extend(LINE_END.split(text[start:]))
                    break
                cut = found.end() - 1
            elif text[cut] == "\r" and cut + 1 < size and text[cut + 1] == "\n":
                cut += 1  # a CR LF is one line end, never cut in two
            lines.extend(LINE_END.split(text[start:cut + 1])[:-1])  # ends in a line end
            start = cut + 1
        else:
            lines.append("")  # the text ended with a piece's line end
    if lines[-1] == "":
        lines.pop()
    return lines


def not_utf8(data: bytes, exc: UnicodeDecodeError, file: str) -> Diagnostic:
    """NC015 at the first byte that is not UTF-8: its line (LF, CR LF or CR ends one), its
    column in characters, and its line as the text shows it (the bad bytes as U+FFFD)."""
    pos = exc.start
    head = data[:pos]
    start = max(head.rfind(b"\n"), head.rfind(b"\r")) + 1
    found = re.compile(rb"[\r\n]").search(data, pos)
    end = found.start() if found else len(data)
    line = head.count(b"\n") + head.count(b"\r") - head.count(b"\r\n") + 1
    column = len(data[start:pos].decode("utf-8", "replace")) + 1
    return Diagnostic(DiagnosticCode.NOT_UTF8,
                      f"byte 0x{data[pos]:02x} is not UTF-8: save the program as UTF-8",
                      Span(file, line, column), data[start:end].decode("utf-8", "replace"))


def did_you_mean(word: str, candidates: Iterable[str]) -> str | None:
    """The closest candidate to a misspelt name, or None when nothing is close."""
    pool = list(candidates)
    upper = {c.upper(): c for c in pool}
    found = difflib.get_close_matches(word.upper(), list(upper), n=1, cutoff=0.5)
    if found:
        return upper[found[0]]
    # A transposition of two letters scores low with difflib on short words (SDN/SND).
    for cand in pool:
        if len(cand) == len(word) and sorted(cand.upper()) == sorted(word.upper()):
            return cand
    return None


class WordUse(NamedTuple):
    """A word of a block as the repeat rule sees it: its letter, its value when the text
    gives it (None when a variable or an expression does), and where it stands."""

    letter: str
    number: float | None
    text: str  # the word as written: X10, XE1, G01
    span: Span


def word_clashes(words: Sequence[WordUse], groups: Mapping[str, Mapping[float, str]],
                 ) -> Iterator[tuple[WordUse, WordUse, str | None]]:
    """The words of one block that a control refuses: ``(word, the earlier one, group)``.

    A letter that is not in ``groups`` (X, F, T, ...) stands once a block: its second word is a
    repeat (group None), as on every control -- rs274ngc refuses "multiple X words", and a
    last-wins reading would move to X20 where the programmer may have meant X10.  G and M
    words may stand several times (G90 G1 G17), but not twice with one code, nor two codes of
    one modal group (``groups[letter][code]`` names it): those clash with their group's name.
    A G or M word whose value a variable gives is not known here and clashes with nothing.
    Each letter and each group is reported once, at its second word, so a block of 80,000 X
    words gives one diagnostic, not 79,999."""
    first: dict[object, WordUse] = {}
    reported: set[object] = set()
    for word in words:
        table = groups.get(word.letter)
        if table is None:
            key: object = word.letter
            group = None
        elif word.number is None:
            continue
        else:
            group = table.get(word.number)
            key = (word.letter, group if group is not None else word.number)
            earlier = first.get(key)
            if earlier is not None and earlier.number == word.number:
                group = None  # the same code twice: a repeat, whatever its group
        earlier = first.setdefault(key, word)
        if earlier is not word and key not in reported:
            reported.add(key)
            yield word, earlier, group


class InterpreterError(NcgateError):
    """Root of the interpreter's exceptions."""


class LineError(InterpreterError):
    """A block that does not parse (either dialect's parser); carries its diagnostic."""

    def __init__(self, diagnostic: Diagnostic) -> None:
        super().__init__(diagnostic.render())
        self.diagnostic = diagnostic


class ProgramError(InterpreterError):
    """A program that cannot start: it carries every diagnostic found."""

    def __init__(self, diagnostics: Sequence[Diagnostic]) -> None:
        self.diagnostics = tuple(diagnostics)
        super().__init__(render_all(self.diagnostics))


class ProgramSyntaxError(ProgramError, SyntaxError):
    """A program with syntax or check-time errors (also a :class:`SyntaxError`)."""

    def __init__(self, diagnostics: Sequence[Diagnostic]) -> None:
        ProgramError.__init__(self, diagnostics)
        first = self.diagnostics[0] if self.diagnostics else None
        self.msg = first.message if first else "invalid program"
        if first is not None:
            self.filename = first.span.file
            self.lineno = first.span.line
            self.offset = first.span.column
            self.text = first.source_line

    def __str__(self) -> str:
        return render_all(self.diagnostics)


class ProgramNotFoundError(InterpreterError, FileNotFoundError):
    """A program name that no storage device holds."""


class RuntimeAlarm(InterpreterError):
    """A runtime error in a process (spec 2.6): it becomes an alarm with a stable code."""

    def __init__(self, code: AlarmCode, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


def clash_message(word: WordUse, earlier: WordUse, group: str | None) -> str:
    """The message of one of :func:`word_clashes`' findings (the same in both dialects)."""
    where = f"{earlier.text} at column {earlier.span.column}"
    if group is None and word.number is not None and word.number == earlier.number:
        return f"{word.text} is already in this block ({where}): write it once"
    if group is None:
        return (f"{word.text}: {word.letter} is already in this block ({where}); a block "
                f"takes one {word.letter} word")
    return (f"{word.text} and {earlier.text} (column {earlier.span.column}) are both {group} "
            "codes; a block takes one code of each modal group")
