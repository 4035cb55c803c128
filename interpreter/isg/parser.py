"""The ISG (TwinCAT CNC) block parser and the sectioned file (spec 5.1, 5.2).

A hand-written recursive-descent parser, one line (block) at a time: the dialect is small and
line-shaped, and a hand-written parser gives the diagnostics this dialect needs (``#SIGAL`` ->
"did you mean #SIGNAL?") at exact columns.

Comments: ``( … )`` up to ``)`` or the end of the line (the seeds leave some unclosed) and
``;`` to the end of the line -- but only outside square brackets: inside ``[ … ]`` (a
bracketed value, the argument list of ``#SIGNAL``/``#WAIT``) parentheses group, so
``X[(P1+2)*3]`` works.  Outside brackets an expression groups with ``[ ]``.

A file holds one program, or several, each starting with a line ``%<name>`` (a section);
:meth:`IsgFile.program` picks the one for a channel.  Must not import ``plc`` or ``gateway``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from ncgate.interpreter.codes import DiagnosticCode
from ncgate.interpreter.diagnostics import (
    Diagnostic,
    LineError,
    ProgramNotFoundError,
    ProgramSyntaxError,
    Span,
    did_you_mean,
    not_utf8,
    split_lines,
)
from ncgate.interpreter.isg.nodes import (
    Assign,
    Binary,
    Block,
    Call,
    Control,
    Declare,
    Expr,
    ExternalVar,
    Flush,
    Item,
    Num,
    Param,
    Remove,
    Section,
    SelfVar,
    Signal,
    Target,
    Unary,
    VarBlock,
    WaitSignal,
    Word,
)

COMMANDS: Final = ("SIGNAL", "WAIT", "FLUSH", "VAR", "ENDVAR")
CONTROLS: Final = ("IF", "ELSE", "ENDIF", "WHILE", "ENDWHILE")
FUNCTIONS: Final = ("ABS", "SQRT", "SIN", "COS")
WORD_LETTERS: Final = frozenset("GMXYZIJKFST")
_SECTION_CHANNEL: Final = re.compile(r"(?:channel|kanal_?)\s*(\d+)$", re.IGNORECASE)
_NAME: Final = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_NUMBER: Final = re.compile(r"(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_INT: Final = re.compile(r"\d+")
_COMPARE: Final = ("==", "!=", "<>", "<=", ">=", "<", ">")
_SYNC_KEYS: Final = ("IDMIN", "IDMAX", "ID", "COUNT", "CH", "AHEAD")


def blank_comments(text: str) -> str:
    """The line with its comments replaced by spaces (columns stay where they were)."""
    out = list(text)
    depth = 0
    i = 0
    while i < len(text):
        c = text[i]
        if c == "[":
            depth += 1
        elif c == "]" and depth:
            depth -= 1
        elif depth == 0 and c == ";":
            out[i:] = " " * (len(text) - i)
            break
        elif depth == 0 and c == "(":
            close = text.find(")", i)
            stop = len(text) if close < 0 else close + 1
            out[i:stop] = " " * (stop - i)
            i = stop
            continue
        i += 1
    return "".join(out)


class _Line:
    """A cursor over one line (comments blanked)."""

    def __init__(self, text: str, file: str, line: int) -> None:
        self.source = text
        self.text = blank_comments(text)
        self.file = file
        self.line = line
        self.pos = 0

    # -- helpers ---------------------------------------------------------------------------

    def span(self, pos: int | None = None) -> Span:
        return Span(self.file, self.line, (self.pos if pos is None else pos) + 1)

    def error(self, code: DiagnosticCode, message: str, pos: int | None = None) -> LineError:
        return LineError(Diagnostic(code, message, self.span(pos), self.source))

    def ws(self) -> None:
        text, n = self.text, len(self.text)
        while self.pos < n and text[self.pos] in " \t\r":
            self.pos += 1

    def at_end(self) -> bool:
        self.ws()
        return self.pos >= len(self.text)

    def peek(self, k: int = 1) -> str:
        return self.text[self.pos:self.pos + k]

    def take(self, literal: str) -> bool:
        """Case-insensitively take ``literal`` (after white space)."""
        self.ws()
        if self.text[self.pos:self.pos + len(literal)].upper() == literal:
            self.pos += len(literal)
            return True
        return False

    def match(self, pattern: re.Pattern[str]) -> str | None:
        m = pattern.match(self.text, self.pos)
        if m is None:
            return None
        self.pos = m.end()
        return m.group(0)

    def keyword(self, words: Sequence[str]) -> str | None:
        """One of ``words`` as a whole word (not followed by a letter)."""
        self.ws()
        for word in words:
            end = self.pos + len(word)
            if self.text[self.pos:end].upper() == word and not (
                    end < len(self.text) and (self.text[end].isalpha() or self.text[end] == "_")):
                self.pos = end
                return word
        return None

    def expect(self, literal: str, what: str) -> None:
        if not self.take(literal):
            code = (DiagnosticCode.ISG_MISSING_BRACKET if literal == "]"
                    else DiagnosticCode.ISG_SYNTAX)
            raise self.error(code, f"expected {what}, found {self.shown()}")

    def shown(self) -> str:
        self.ws()
        if self.pos >= len(self.text):
            return "the end of the block"
        m = re.match(r"\S+", self.text[self.pos:])
        return repr(m.group(0)[:20]) if m else repr(self.text[self.pos])

    # -- expressions -----------------------------------------------------------------------

    def expr(self, condition: bool = False) -> Expr:
        return self._or(condition)

    def _or(self, condition: bool) -> Expr:
        left = self._and(condition)
        while True:
            start = self.pos
            if self.keyword(("OR",)):
                left = Binary("OR", left, self._and(condition), self.span(start))
            else:
                return left

    def _and(self, condition: bool) -> Expr:
        left = self._compare(condition)
        while True:
            start = self.pos
            if self.keyword(("AND",)):
                left = Binary("AND", left, self._compare(condition), self.span(start))
            else:
                return left

    def _compare(self, condition: bool) -> Expr:
        left = self._add()
        self.ws()
        start = self.pos
        for op in _COMPARE:
            if self.peek(len(op)) == op:
                self.pos += len(op)
                op = "!=" if op == "<>" else op
                return Binary(op, left, self._add(), self.span(start))
        if condition and self.peek() == "=":  # $IF P1 = 2: nothing else could be meant
            self.pos += 1
            return Binary("==", left, self._add(), self.span(start))
        return left

    def _add(self) -> Expr:
        left = self._mul()
        while True:
            self.ws()
            c = self.peek()
            if c in ("+", "-"):
                start = self.pos
                self.pos += 1
                left = Binary(c, left, self._mul(), self.span(start))
            else:
                return left

    def _mul(self) -> Expr:
        left = self._unary()
        while True:
            self.ws()
            c = self.peek()
            if c in ("*", "/"):
                start = self.pos
                self.pos += 1
                left = Binary(c, left, self._unary(), self.span(start))
            else:
                return left

    def _unary(self) -> Expr:
        self.ws()
        start = self.pos
        c = self.peek()
        if c == "-":
            self.pos += 1
            return Unary("-", self._unary(), self.span(start))
        if c == "+":
            self.pos += 1
            return self._unary()
        if self.keyword(("NOT",)):
            return Unary("NOT", self._unary(), self.span(start))
        return self.atom()

    def atom(self) -> Expr:
        self.ws()
        start = self.pos
        c = self.peek()
        if c == "[" or c == "(":
            self.pos += 1
            inner = self.expr(condition=True)
            self.expect("]" if c == "[" else ")", "']'" if c == "[" else "')'")
            return inner
        number = self.match(_NUMBER)
        if number is not None:
            return Num(float(number), self.span(start))
        function = self.keyword(FUNCTIONS)
        if function is not None:
            self.ws()
            if self.peek() not in ("[", "("):
                raise self.error(DiagnosticCode.ISG_SYNTAX,
                                 f"{function} takes its argument in brackets: {function}[…]")
            return Call(function, self.atom(), self.span(start))
        variable = self.variable()
        if variable is not None:
            return variable
        raise self.error(DiagnosticCode.ISG_SYNTAX, f"expected a value, found {self.shown()}")

    def variable(self) -> Target | None:
        """``P<n>``, ``V.P.<NAME>`` or ``V.E.<NAME>`` at the cursor, or None."""
        self.ws()
        start = self.pos
        head = self.peek(4).upper()
        if head in ("V.P.", "V.E."):
            self.pos += 4
            name = self.match(_NAME)
            if name is None:
                raise self.error(DiagnosticCode.ISG_SYNTAX, f"{head} without a name")
            cls = SelfVar if head == "V.P." else ExternalVar
            return cls(name.upper(), self.span(start))
        if head[:1] == "P" and head[1:2].isdigit():
            self.pos += 1
            digits = self.match(_INT)
            assert digits is not None
            return Param(int(digits), self.span(start))
        return None

    def value(self) -> Expr:
        """A word's or an argument's value: a number (signed), a variable or ``[expr]``."""
        self.ws()
        start = self.pos
        sign = self.peek()
        if sign in ("-", "+"):
            self.pos += 1
            inner = self.value()
            return Unary("-", inner, self.span(start)) if sign == "-" else inner
        c = self.peek()
        if c == "[":
            return self.atom()
        number = self.match(_NUMBER)
        if number is not None:
            return Num(float(number), self.span(start))
        variable = self.variable()
        if variable is not None:
            return variable
        raise self.error(DiagnosticCode.ISG_WORD_WITHOUT_VALUE,
                         f"expected a value, found {self.shown()}")


# ---- blocks ---------------------------------------------------------------------------------


def parse_block(text: str, file: str, line: int, in_var: bool = False) -> Block:
    """One line as a :class:`Block`; raises :class:`LineError`.  ``in_var``: the line is
    inside ``#VAR … #ENDVAR``."""
    cur = _Line(text, file, line)
    if cur.at_end():
        return Block(None, (), cur.span(0))
    start = cur.pos
    if cur.peek() == "%":
        cur.pos += 1
        cur.ws()
        name = cur.text[cur.pos:].strip()
        if not name:
            raise cur.error(DiagnosticCode.ISG_SYNTAX, "a section needs a name: %<name>")
        return Block(None, (Section(name.split()[0], cur.span(start)),), cur.span(start))
    number = None
    if cur.peek().upper() == "N" and cur.text[cur.pos + 1:cur.pos + 2].isdigit():
        cur.pos += 1
        digits = cur.match(_INT)
        assert digits is not None
        number = int(digits)
    if in_var and not cur.at_end() and cur.peek() != "#":
        items: list[Item] = [_declaration(cur)]
    elif not cur.at_end() and cur.peek() in ("#", "$"):
        items = [_command(cur)]
    else:
        items = _words(cur)
    if not cur.at_end():
        first = items[0] if items else None
        code = (DiagnosticCode.ISG_COMMAND_NOT_ALONE
                if first is not None and not isinstance(first, Assign | Word)
                else DiagnosticCode.ISG_SYNTAX)
        what = ("a # or $ command stands alone in its block (N aside)"
                if code is DiagnosticCode.ISG_COMMAND_NOT_ALONE else "unexpected")
        raise cur.error(code, f"{what}: {cur.shown()}")
    return Block(number, tuple(items), cur.span(start))


def _declaration(cur: _Line) -> Declare:
    start = cur.pos
    target = cur.variable()
    if not isinstance(target, SelfVar):
        raise cur.error(DiagnosticCode.ISG_SYNTAX,
                        f"#VAR declares V.P. variables: expected V.P.<NAME>, found {cur.shown()}",
                        start)
    value = cur.expr() if cur.take("=") else None
    return Declare(target.name, value, cur.span(start))


def _words(cur: _Line) -> list[Item]:
    items: list[Item] = []
    while not cur.at_end():
        start = cur.pos
        target = cur.variable()
        if target is not None:
            cur.ws()
            if cur.peek() == "=" and cur.peek(2) != "==":
                cur.pos += 1
                items.append(Assign(target, cur.expr(), cur.span(start)))
                continue
            raise cur.error(DiagnosticCode.ISG_SYNTAX,
                            "a variable on its own: assign it (P1 = …) or give it to a word "
                            "(XP1)", start)
        letter = cur.peek().upper()
        if letter in WORD_LETTERS:
            cur.pos += 1
            cur.ws()
            if cur.at_end() or not (cur.peek() in "[-+.V" or cur.peek().isdigit()
                                    or cur.peek().upper() == "P"):
                raise cur.error(DiagnosticCode.ISG_WORD_WITHOUT_VALUE,
                                f"the address {letter} has no value", start)
            items.append(Word(letter, cur.value(), cur.span(start)))
            continue
        raise cur.error(DiagnosticCode.ISG_SYNTAX, f"unexpected {cur.shown()}")
    return items


def _command(cur: _Line) -> Item:
    start = cur.pos
    sigil = cur.peek()
    cur.pos += 1
    name = (cur.match(_NAME) or "").upper()
    known = COMMANDS if sigil == "#" else CONTROLS
    if name not in known:
        guess = did_you_mean(name, known) if name else None
        hint = f"; did you mean {sigil}{guess}?" if guess else ""
        listed = ", ".join(sigil + k for k in known)
        raise cur.error(DiagnosticCode.ISG_UNKNOWN_COMMAND,
                        f"unknown {sigil}{name or ''}{hint} (the dialect knows {listed})", start)
    span = cur.span(start)
    if sigil == "$":
        condition = cur.expr(condition=True) if name in ("IF", "WHILE") else None
        return Control(name, condition, span)
    if name == "FLUSH":
        cur.keyword(("WAIT",))
        return Flush(span)
    if name in ("VAR", "ENDVAR"):
        return VarBlock(name == "ENDVAR", span)
    syn = cur.keyword(("SYN",)) is not None
    remove = name == "SIGNAL" and not syn and cur.keyword(("REMOVE",)) is not None
    args = _sync_args(cur, name, remove)
    if remove:
        return _remove(cur, args, span)
    if name == "SIGNAL":
        return Signal(syn, args.id or Num(0.0, span), args.count, tuple(args.params),
                      tuple(args.channels), span)
    targets: list[tuple[int, Target]] = []
    for index, value in args.params:
        if not isinstance(value, Param | SelfVar | ExternalVar):
            raise cur.error(DiagnosticCode.ISG_BAD_SYNC_ARGUMENT,
                            f"#WAIT assigns P[{index}] to a variable (P200, V.P.NAME), not "
                            "to a value", value.span.column - 1)
        targets.append((index, value))
    return WaitSignal(syn, args.id or Num(0.0, span), tuple(targets), tuple(args.channels),
                      args.ahead, span)


@dataclass
class _Args:
    id: Expr | None = None
    id_min: Expr | None = None
    id_max: Expr | None = None
    count: Expr | None = None
    params: list[tuple[int, Expr]] = field(default_factory=list)
    channels: list[Expr] = field(default_factory=list)
    ahead: bool = False


def _sync_args(cur: _Line, command: str, remove: bool) -> _Args:
    args = _Args()
    if not cur.take("["):
        return args
    while True:
        cur.ws()
        if cur.take("]"):
            return args
        if cur.at_end():
            raise cur.error(DiagnosticCode.ISG_MISSING_BRACKET,
                            f"#{command} [ … without its closing ]")
        start = cur.pos
        if cur.peek().upper() == "P" and cur.text[cur.pos + 1:].lstrip()[:1] == "[":
            cur.pos += 1
            cur.expect("[", "'['")
            cur.ws()
            digits = cur.match(_INT)
            if digits is None:
                raise cur.error(DiagnosticCode.ISG_BAD_SYNC_ARGUMENT,
                                "a signal parameter's index is a constant: P[0], P[1], …")
            cur.expect("]", "']'")
            cur.expect("=", "'=' after P[…]")
            value = cur.expr() if command == "SIGNAL" else (cur.variable() or cur.value())
            if any(i == int(digits) for i, _ in args.params):
                raise cur.error(DiagnosticCode.ISG_BAD_SYNC_ARGUMENT,
                                f"P[{digits}] is given twice", start)
            args.params.append((int(digits), value))
            continue
        key = cur.keyword(_SYNC_KEYS) or _glued_key(cur)
        if key is None:
            allowed = ("ID IDMIN IDMAX CH" if remove else
                       "ID COUNT P[i]= CH" if command == "SIGNAL" else "ID P[i]= CH AHEAD")
            raise cur.error(DiagnosticCode.ISG_BAD_SYNC_ARGUMENT,
                            f"#{command}{' REMOVE' if remove else ''} takes {allowed}; found "
                            f"{cur.shown()}")
        if key == "AHEAD":
            if command != "WAIT":
                raise cur.error(DiagnosticCode.ISG_BAD_SYNC_ARGUMENT,
                                "AHEAD belongs to #WAIT", start)
            args.ahead = True
            continue
        if (key in ("IDMIN", "IDMAX") and not remove) or (key == "COUNT" and (
                remove or command == "WAIT")):
            raise cur.error(DiagnosticCode.ISG_BAD_SYNC_ARGUMENT,
                            f"{key} does not belong to #{command}"
                            f"{' REMOVE' if remove else ''}", start)
        cur.take("=")
        value = cur.value()
        if key == "CH":
            args.channels.append(value)
            continue
        slot = {"ID": "id", "IDMIN": "id_min", "IDMAX": "id_max", "COUNT": "count"}[key]
        if getattr(args, slot) is not None:
            raise cur.error(DiagnosticCode.ISG_BAD_SYNC_ARGUMENT, f"{key} is given twice", start)
        setattr(args, slot, value)


def _glued_key(cur: _Line) -> str | None:
    """``ID4711``, ``IDP100``, ``CH3``, ``COUNT2``: a key glued to its value."""
    cur.ws()
    rest = cur.text[cur.pos:].upper()
    for key in _SYNC_KEYS:
        if key == "AHEAD" or not rest.startswith(key):
            continue
        after = rest[len(key):len(key) + 1]
        if after.isdigit() or after in ("P", "V", "[", "=", "-", "+"):
            # "IDMIN5" must not be read as ID + "MIN5": longer keys come first in _SYNC_KEYS.
            cur.pos += len(key)
            return key
    return None


def _remove(cur: _Line, args: _Args, span: Span) -> Remove:
    if args.params or args.ahead:
        raise cur.error(DiagnosticCode.ISG_BAD_SYNC_ARGUMENT,
                        "#SIGNAL REMOVE takes ID, IDMIN, IDMAX and CH only", span.column - 1)
    if args.id is not None and (args.id_min is not None or args.id_max is not None):
        raise cur.error(DiagnosticCode.ISG_BAD_REMOVE,
                        "#SIGNAL REMOVE takes ID or a range IDMIN..IDMAX, not both",
                        span.column - 1)
    if args.id_max is not None and args.id_min is None:
        raise cur.error(DiagnosticCode.ISG_BAD_REMOVE, "IDMAX without IDMIN", span.column - 1)
    if args.id is not None:
        return Remove(args.id, args.id, tuple(args.channels), span)
    return Remove(args.id_min, args.id_max, tuple(args.channels), span)


# ---- files and sections ---------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SectionInfo:
    name: str
    channel: int  # the channel it runs in (named, or by position)
    header: int  # index of its %line
    end: int  # index of the next %line, or the file's length


@dataclass
class IsgFile:
    """A parsed ISG file: its blocks (None where a line does not parse), its sections, every
    syntax diagnostic, and the control-flow partners of $IF/$ELSE/$ENDIF/$WHILE/$ENDWHILE."""

    name: str  # the program name: the file name without its extension
    file: str  # display name
    lines: list[str]
    blocks: list[Block | None]
    sections: list[SectionInfo]
    diagnostics: list[Diagnostic]
    partner: dict[int, int]  # IF -> ELSE/ENDIF, ELSE -> ENDIF, WHILE -> ENDWHILE and back

    @classmethod
    def from_path(cls, path: Path, display: str | None = None) -> IsgFile:
        raw = path.read_bytes()
        name = display or path.name
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ProgramSyntaxError([not_utf8(raw, exc, name)]) from None
        return cls.from_text(text, name, path.stem)

    @classmethod
    def from_text(cls, text: str, file: str, name: str | None = None) -> IsgFile:
        lines = split_lines(text)
        blocks: list[Block | None] = []
        diagnostics: list[Diagnostic] = []
        in_var: Span | None = None
        for i, line in enumerate(lines):
            try:
                block = parse_block(line, file, i + 1, in_var is not None)
            except LineError as exc:
                diagnostics.append(exc.diagnostic)
                blocks.append(None)
                continue
            command = block.command
            if isinstance(command, VarBlock):
                if command.end and in_var is None:
                    diagnostics.append(Diagnostic(DiagnosticCode.ISG_UNBALANCED,
                                                  "#ENDVAR without #VAR", command.span, line))
                elif not command.end and in_var is not None:
                    diagnostics.append(Diagnostic(DiagnosticCode.ISG_UNBALANCED,
                                                  f"#VAR inside the #VAR of line {in_var.line}",
                                                  command.span, line))
                in_var = None if command.end else command.span
            elif isinstance(command, Section) and in_var is not None:
                diagnostics.append(_unbalanced(in_var, lines, "#VAR without #ENDVAR"))
                in_var = None
            blocks.append(block)
        if in_var is not None:
            diagnostics.append(_unbalanced(in_var, lines, "#VAR without #ENDVAR"))
        sections = _sections(blocks, len(lines))
        partner = _control_flow(blocks, sections, lines, diagnostics)
        diagnostics.sort(key=lambda d: (d.span.line, d.span.column))
        return cls(name or file.rsplit(".", 1)[0], file, lines, blocks, sections, diagnostics,
                   partner)

    def program(self, channel: int) -> IsgProgram:
        """The program channel ``channel`` runs (spec 5.1); a file without sections runs in
        any channel."""
        if not self.sections:
            return IsgProgram(self, None, 0, len(self.lines))
        for section in self.sections:
            if section.channel == channel:
                return IsgProgram(self, section, section.header + 1, section.end)
        names = ", ".join(f"%{s.name} (channel {s.channel})" for s in self.sections)
        raise ProgramNotFoundError(f"{self.name} has no section for channel {channel}: {names}")


def _unbalanced(span: Span, lines: list[str], message: str) -> Diagnostic:
    return Diagnostic(DiagnosticCode.ISG_UNBALANCED, message, span, lines[span.line - 1])


def _sections(blocks: list[Block | None], count: int) -> list[SectionInfo]:
    headers = [(i, b.items[0]) for i, b in enumerate(blocks)
               if b is not None and b.items and isinstance(b.items[0], Section)]
    out = []
    for position, (i, section) in enumerate(headers):
        assert isinstance(section, Section)
        m = _SECTION_CHANNEL.match(section.name)
        channel = int(m.group(1)) if m else position + 1
        end = headers[position + 1][0] if position + 1 < len(headers) else count
        out.append(SectionInfo(section.name, channel, i, end))
    return out


def _control_flow(blocks: list[Block | None], sections: list[SectionInfo], lines: list[str],
                  diagnostics: list[Diagnostic]) -> dict[int, int]:
    partner: dict[int, int] = {}
    ranges = [(s.header + 1, s.end) for s in sections] or [(0, len(blocks))]
    for first, end in ranges:
        stack: list[tuple[int, Control]] = []
        for i in range(first, end):
            block = blocks[i]
            command = block.command if block is not None else None
            if not isinstance(command, Control):
                continue
            word = command.word
            if word in ("IF", "WHILE"):
                stack.append((i, command))
                continue
            opener = "WHILE" if word == "ENDWHILE" else "IF"
            if not stack or stack[-1][1].word != opener or (
                    word == "ELSE" and -1 - stack[-1][0] in partner):  # a second $ELSE
                diagnostics.append(Diagnostic(DiagnosticCode.ISG_UNBALANCED,
                                              f"${word} without its ${opener}", command.span,
                                              lines[i]))
                continue
            j = stack[-1][0]
            if word == "ELSE":
                partner[j] = i  # $IF false: on after the $ELSE
                stack[-1] = (i, stack[-1][1])  # the $ELSE now waits for its $ENDIF
                partner[-1 - i] = j  # marks the $ELSE (negative keys go at the end)
                continue
            stack.pop()
            partner[j] = i
            if word == "ENDWHILE":
                partner[i] = j
        for i, command in stack:
            closer = "$ENDWHILE" if command.word == "WHILE" else "$ENDIF"
            diagnostics.append(Diagnostic(DiagnosticCode.ISG_UNBALANCED,
                                          f"${command.word} without its {closer}", command.span,
                                          lines[i]))
    return {k: v for k, v in partner.items() if k >= 0}


@dataclass
class IsgProgram:
    """One program of an ISG file, as the engine runs it (a
    :class:`~ncgate.interpreter.engine.ports.ProgramText`): the file's lines, of which only
    ``first .. end-1`` are its own (the lines outside decode to nothing, so that messages and
    the trace give the file's true line numbers)."""

    source: IsgFile
    section: SectionInfo | None
    first: int
    end: int

    @property
    def name(self) -> str:
        return self.source.name

    @property
    def file(self) -> str:
        return self.source.file

    @property
    def lines(self) -> Sequence[str]:
        return self.source.lines

    def __len__(self) -> int:
        return self.end

    def block(self, index: int) -> Block | None:
        return self.source.blocks[index]
