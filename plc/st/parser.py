"""Structured Text source -> :mod:`ncgate.plc.st.nodes`, with syntax diagnostics.

The grammar is ``grammar/st.lark`` (LALR, built once per process).  A syntax error is one
diagnostic at the first bad item, with what the grammar expected there.
"""

from __future__ import annotations

import functools
import re
import sys
import time
from decimal import Decimal
from importlib import resources
from pathlib import Path
from typing import Any

from lark import Lark, Token, Tree, v_args
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken
from lark.visitors import Transformer_NonRecursive

from ncgate.plc.st import nodes as n
from ncgate.plc.st.diagnostics import LogicError, StCode, StDiagnostic

_TIME_PART = re.compile(r"([0-9][0-9_]*(?:\.[0-9]+)?)(d|h|ms|m|s|us|ns)_?", re.IGNORECASE)
_NS = {"d": 86_400 * 10**9, "h": 3_600 * 10**9, "m": 60 * 10**9, "s": 10**9, "ms": 10**6,
       "us": 1000, "ns": 1}
_UNITS = ("d", "h", "m", "s", "ms", "us", "ns")  # a duration's units, in IEC's order
_UNIT_LIMIT = {"h": 24, "m": 60, "s": 60, "ms": 1000, "us": 1000, "ns": 1000}  # (6.3.3)
_ESCAPES = {"$": "$", "'": "'", '"': '"', "L": "\n", "N": "\n", "P": "\f", "R": "\r",
            "T": "\t"}
_DATE = re.compile(r"([0-9]+)-([0-9]+)-([0-9]+)")
_TOD = re.compile(r"([0-9]+):([0-9]+)(?::([0-9]+)(\.[0-9]+)?)?")
# IEC 61131-3, 6.3.2: a single '_' between digits (and after the base's '#').
_DECIMAL = re.compile(r"[0-9](_?[0-9])*")
_BASED = {2: re.compile(r"_?[01](_?[01])*"), 8: re.compile(r"_?[0-7](_?[0-7])*"),
          16: re.compile(r"_?[0-9A-Fa-f](_?[0-9A-Fa-f])*")}
# Words that start a construct outside the subset: a syntax error at one is ST031.
UNSUPPORTED_WORDS = {
    "VAR_ACCESS": "VAR_ACCESS", "VAR_CONFIG": "VAR_CONFIG",
    "CONFIGURATION": "CONFIGURATION", "RESOURCE": "RESOURCE",
    "AT": "located variables (AT %I…)", "METHOD": "METHOD", "PROPERTY": "PROPERTY",
    "INTERFACE": "INTERFACE", "ACTION": "ACTION", "REF_TO": "references (REF_TO)",
    "POINTER": "pointers", "JMP": "JMP and labels", "UNION": "UNION",
}
_UNSUPPORTED_CHARS = {"%": "located variables (%IX0.0)"}
_COMMENT_OPEN = re.compile(r"\(\*|/\*|//|\{|'|\"")
_COMMENT_PAIR = {"(*": re.compile(r"\(\*|\*\)"), "/*": re.compile(r"/\*|\*/")}
_STRING_END = {"'": re.compile(r"\$.|'|\n", re.DOTALL), '"': re.compile(r'\$.|"|\n', re.DOTALL)}
_NOT_NEWLINE = re.compile(r"[^\n]")


class UnclosedComment(ValueError):
    def __init__(self, at: int, what: str = "comment") -> None:
        super().__init__(f"a {what} that is never closed")
        self.at = at
        self.what = what


# The pragmas (6.2) whose meaning ignoring them keeps: CODESYS's and TwinCAT's attributes,
# messages, regions and library notes.  Any other -- matiec's inline C {{ ... }}, CODESYS's
# conditional {IF defined(...)} -- changes what the code means where it is honoured: ignored
# too, with a warning (SW004).
KNOWN_PRAGMAS = frozenset({"ATTRIBUTE", "INFO", "WARNING", "ERROR", "TEXT", "REGION",
                           "ENDREGION", "LIBRARY", "MESSAGEGUID", "BITACCESS", "FLAG"})
_PRAGMA_WORD = re.compile(r"\{\s*([A-Za-z_]+)")


def blank_comments(text: str, unknown_pragmas: list[int] | None = None) -> str:
    """The text with every comment and pragma turned into spaces (newlines kept, so every
    position is unchanged).  ``(* *)`` and ``/* */`` nest in themselves, as IEC 61131-3
    (6.1.5) allows: ``(* a (* b *) c *)`` is one comment.  A pragma ``{attribute …}``
    (6.2) is accepted and ignored, and matiec's ``{{ inline C }}`` is one pragma; where a
    pragma ncgate does not know starts is added to ``unknown_pragmas``.  String literals
    are skipped: ``'(*'`` is text.  UnclosedComment at the opening of one that the file
    never closes."""
    if not any(mark in text for mark in ("(*", "/*", "//", "{")):
        return text
    pieces = []
    pos = 0
    search = 0
    while (found := _COMMENT_OPEN.search(text, search)) is not None:
        start, opener = found.start(), found.group()
        if opener in ("'", '"'):  # a string literal: step over it
            end = found.end()
            while (mark := _STRING_END[opener].search(text, end)) is not None and \
                    mark.group().startswith("$"):
                end = mark.end()
            search = mark.end() if mark is not None else len(text)
            continue
        if opener == "//":
            end = text.find("\n", start)
            end = len(text) if end < 0 else end
        elif opener == "{":
            inline_c = text.startswith("{{", start)
            end = text.find("}}" if inline_c else "}", start)
            if end < 0:
                raise UnclosedComment(start, "pragma")
            end += 2 if inline_c else 1
            word = _PRAGMA_WORD.match(text, start)
            if unknown_pragmas is not None and (inline_c or word is None or
                                                word.group(1).upper() not in KNOWN_PRAGMAS):
                unknown_pragmas.append(start)
        else:
            depth, end = 1, found.end()
            pair = _COMMENT_PAIR[opener]
            while depth:
                mark = pair.search(text, end)
                if mark is None:
                    raise UnclosedComment(start)
                depth += 1 if mark.group() == opener else -1
                end = mark.end()
        pieces += [text[pos:start], _NOT_NEWLINE.sub(" ", text[start:end])]
        pos = search = end
    pieces.append(text[pos:])
    return "".join(pieces)


def _position(text: str, at: int) -> tuple[int, int]:
    line = text.count("\n", 0, at) + 1
    return line, at - (text.rfind("\n", 0, at) + 1) + 1


def _unsupported(text: str, at: int) -> tuple[str, int] | None:
    """What is outside the subset at ``at`` (or in the word before it: ``VAR_IN_OUT x``
    lexes as VAR, then a name), if that is why the syntax failed there, and where."""
    char = text[at:at + 1]
    if char == "%" and text[:at].rstrip().endswith("."):
        return "bit access (w.%X3)", at
    if char in _UNSUPPORTED_CHARS:
        return _UNSUPPORTED_CHARS[char], at
    word = re.match(r"[A-Za-z_][A-Za-z0-9_]*", text[at:])
    if word is not None and word.group().upper() in UNSUPPORTED_WORDS:
        return UNSUPPORTED_WORDS[word.group().upper()], at
    before = text[:at].rstrip()
    previous = re.search(r"[A-Za-z_][A-Za-z0-9_]*$", before)
    if previous is not None and previous.group().upper() in UNSUPPORTED_WORDS:
        return UNSUPPORTED_WORDS[previous.group().upper()], previous.start()
    return None


_WORD = r"[A-Za-z_][A-Za-z0-9_]*"
# A POU's access specifier or modifier (CODESYS, TwinCAT): FUNCTION_BLOCK PUBLIC FB_Axis.
_SPECIFIER = re.compile(r"\b(?:FUNCTION_BLOCK|FUNCTION|PROGRAM)\s+((?:PUBLIC|PRIVATE|PROTECTED|"
                        r"INTERNAL|ABSTRACT|FINAL)\b)", re.IGNORECASE)
_INHERITS = re.compile(rf"\bFUNCTION_BLOCK\s+{_WORD}\s+((?:EXTENDS|IMPLEMENTS)\b)",
                       re.IGNORECASE)
_POU_HEAD = re.compile(rf"\b(?:FUNCTION_BLOCK|PROGRAM)\s+{_WORD}\s*(;)\s*$|"
                       rf"\bFUNCTION\s+{_WORD}\s*:\s*{_WORD}\s*(;)\s*$", re.IGNORECASE)
_SECTION = re.compile(r"\b(TYPE|END_TYPE|STRUCT|END_STRUCT|END_VAR|VAR(?:_INPUT|_OUTPUT|"
                      r"_IN_OUT|_TEMP|_EXTERNAL|_GLOBAL)?)\b", re.IGNORECASE)


def _field_construct(text: str, at: int, token: Token) -> tuple[StCode, str, int] | None:
    """What CODESYS, TwinCAT or matiec wrote at a syntax error at ``at`` (``text`` with its
    comments blanked), if it is one of the constructs outside the subset that has its own
    code: (code, message, where it starts)."""
    for pattern, code, what in (
            (_SPECIFIER, StCode.ACCESS_SPECIFIER, "an access specifier or modifier"),
            (_INHERITS, StCode.INHERITANCE, "inheritance")):
        found = next((m for m in pattern.finditer(text, 0, at)), None)
        if found is not None:
            return (code, f"{found.group(1).upper()}: {what} (object-oriented ST) is not "
                    "supported by ncgate's Structured Text", found.start(1))
    before = text[:at]
    sections = _SECTION.findall(before)
    section = sections[-1].upper() if sections else ""
    kind = str(token.type)
    head = _POU_HEAD.search(before)
    if head is not None:
        where = head.start(1) if head.group(1) is not None else head.start(2)
        return (StCode.STRAY_SEMICOLON, "a ';' after the POU's name: its declarations "
                "follow the name directly", where)
    if kind == "SEMICOLON" and re.search(r"(;|\bEND_[A-Za-z_]+)\s*$", before):
        return (StCode.STRAY_SEMICOLON, "a ';' where none may stand (delete it)", at)
    if section == "TYPE" and re.search(r"\)\s*$", before) and kind == "NAME":
        return (StCode.TYPED_ENUM, f"an enumeration with a base type ({token}): ncgate's "
                "enumerations are of their own type; delete the base type", at)
    if section == "TYPE" and re.search(rf":\s*{_WORD}\s*\([^;()]*$", before):
        start = before.rfind("(")
        name_at = re.search(rf"{_WORD}\s*\($", before[:start + 1])
        return (StCode.TYPED_ENUM, "an enumeration with a base type (INT (A := 1, B)): "
                "write (A := 1, B)", name_at.start() if name_at else start)
    if section.startswith("VAR") or section == "STRUCT":  # declarations
        if kind == "DOT" and re.search(rf":\s*(?:ARRAY\s*\[[^;]*\]\s*OF\s*)?{_WORD}\s*$",
                                       before, re.IGNORECASE):
            name = re.search(rf"{_WORD}\s*$", before)
            assert name is not None
            return (StCode.QUALIFIED_TYPE, f"{name.group().strip()}.…: a namespace-qualified "
                    "type; name the type alone", name.start())
        array = re.search(rf"\bOF\s*{_WORD}\s*(\[)\s*\([^;]*$", before, re.IGNORECASE)
        if array is not None:
            return (StCode.FB_ARRAY_INIT, "FB_init arguments for an array of function "
                    "blocks: not supported (set the inputs at the first call)",
                    array.start(1))
        init = re.search(rf":\s*{_WORD}\s*(\()[^;()]*$", before)
        if init is not None and str(token) in (",", ":="):
            return (StCode.FB_INIT, "arguments for the instance's FB_init: not supported "
                    "(set the inputs at the first call)", init.start(1))
    return None


# What people call the grammar's punctuation, for "expected ..." in a syntax error.
_SHOWN = {"SEMICOLON": "';'", "COLON": "':'", "LPAR": "'('", "RPAR": "')'", "COMMA": "','",
          "LSQB": "'['", "RSQB": "']'", "DOT": "'.'", "NAME": "a name", "INT": "a number"}


@functools.cache
def _parser() -> Lark:
    text = resources.files("ncgate.plc.st").joinpath("grammar/st.lark").read_text("utf-8")
    return Lark(text, parser="lalr", propagate_positions=True, maybe_placeholders=False)


class _Dots:
    """A dimension written ``ARRAY[..]`` (logi.CAD's ``ARRAY[*]``), until array_type."""


class BadLiteral(ValueError):
    def __init__(self, token: Token, message: str) -> None:
        super().__init__(message)
        self.token = token


def parse_number(text: str) -> int:
    """``1_000``, ``16#FF``, ``2#1010`` -> int; ValueError for ``1__000``, ``1_``, ``2#102``."""
    if "#" in text:
        base, digits = text.split("#", 1)
        pattern = _BASED.get(int(base)) if base.isdigit() else None
        if pattern is None or not pattern.fullmatch(digits):
            raise ValueError(f"{text} is not a base-{base} number (one '_' at most between "
                             "digits)")
        return int(digits.replace("_", ""), int(base))
    if not _DECIMAL.fullmatch(text):
        raise ValueError(f"{text} is not a number (one '_' at most between digits)")
    return int(text.replace("_", ""))


def parse_string(text: str) -> str:
    """``'it$'s$N'`` -> "it's\\n" (IEC 61131-3, 6.3.3: $$ $' $" $L $N $P $R $T, $hh in a
    STRING, $hhhh in a WSTRING).  A STRING holds one byte a character: ValueError for one
    beyond Latin-1."""
    wide = text[0] == '"'
    body = text[1:-1]
    out = []
    i = 0
    while i < len(body):
        char = body[i]
        if char != "$":
            out.append(char)
            i += 1
            continue
        nxt = body[i + 1]
        if nxt.upper() in _ESCAPES:
            out.append(_ESCAPES[nxt.upper()])
            i += 2
        else:
            width = 4 if wide else 2
            out.append(chr(int(body[i + 1:i + 1 + width], 16)))
            i += 1 + width
    value = "".join(out)
    if not wide and any(ord(c) > 255 for c in value):
        raise ValueError("a STRING holds one byte a character (Latin-1): write a WSTRING "
                         "\"…\" for this text")
    return value


def parse_date(text: str) -> tuple[str, int]:
    """``D#2024-01-31`` -> ("DATE", seconds since 1970-01-01), ``TOD#12:30:15.5`` -> ("TOD",
    ms since midnight), ``DT#2024-01-31-12:30:15`` -> ("DT", seconds since 1970) -- the
    representation of CODESYS and TwinCAT (docs/plc.md).  ValueError for a day that is not."""
    import calendar
    import datetime

    kind, body = text.split("#", 1)
    kind = {"D": "DATE", "TIME_OF_DAY": "TOD", "DATE_AND_TIME": "DT"}.get(kind.upper(),
                                                                        kind.upper())
    seconds = 0
    if kind in ("DATE", "DT"):
        found = _DATE.match(body)
        assert found is not None
        y, mo, d = (int(g) for g in found.groups())
        try:
            day = datetime.date(y, mo, d)
        except ValueError as exc:
            raise ValueError(f"{text}: {exc}") from None
        seconds = calendar.timegm(day.timetuple())
        if kind == "DATE":
            if not 0 <= seconds < 1 << 32:
                raise ValueError(f"{text} is outside DATE's range (1970-01-01..2106-02-07)")
            return kind, seconds
        body = body[found.end() + 1:]
    found = _TOD.fullmatch(body)
    if found is None:
        raise ValueError(f"{text} is not a time of day")
    h, m, sec = int(found.group(1)), int(found.group(2)), int(found.group(3) or 0)
    fraction = found.group(4) or ""
    if h > 23 or m > 59 or sec > 59:
        raise ValueError(f"{text}: hours 0..23, minutes and seconds 0..59")
    if kind == "TOD":
        return kind, (h * 3600 + m * 60 + sec) * 1000 + round(float("0" + fraction) * 1000)
    if fraction.strip(".0"):
        raise ValueError(f"{text}: DT holds whole seconds")
    seconds += h * 3600 + m * 60 + sec
    if not 0 <= seconds < 1 << 32:
        raise ValueError(f"{text} is outside DT's range (1970..2106)")
    return kind, seconds


def parse_time(text: str, long: bool = False) -> int:
    """``T#1s500ms`` -> 1500 (milliseconds, rounded; ``long``: an LTIME, in nanoseconds).
    IEC 61131-3, 6.3.3: the units in the order d h m s ms us ns, each once; only the last
    may have a fraction; only the first may overflow (``T#25h`` but not ``T#1h75m``).
    ValueError otherwise."""
    body = text.split("#", 1)[1]
    sign = -1 if body.startswith("-") else 1
    body = body.lstrip("+-")
    parts = _TIME_PART.findall(body)
    total = Decimal(0)
    last = -1
    for i, (value, unit) in enumerate(parts):
        unit = unit.lower()
        order = _UNITS.index(unit)
        if order <= last:
            raise ValueError(f"{text}: the units go d, h, m, s, ms, each once")
        if not _DECIMAL.fullmatch(value.split(".")[0]):
            raise ValueError(f"{text}: one '_' at most between digits")
        if "." in value and i != len(parts) - 1:
            raise ValueError(f"{text}: only the last unit may have a fraction")
        number = Decimal(value.replace("_", ""))
        if i > 0 and unit in _UNIT_LIMIT and number >= _UNIT_LIMIT[unit]:
            raise ValueError(f"{text}: {value}{unit} overflows into the unit before it")
        last = order
        total += number * _NS[unit]
    return sign * round(total if long else total / 10**6)


def parse_typed(text: str) -> tuple[str, bool | int | float]:
    """``INT#-5`` -> ("INT", -5); ``REAL#1.5``; ``BOOL#TRUE``; ``WORD#16#FF``."""
    type_name, raw = text.split("#", 1)
    type_name = type_name.upper()
    if type_name == "BOOL":
        value: bool | int | float = raw.upper() in ("TRUE", "1")
        if raw.upper() not in ("TRUE", "FALSE", "0", "1"):
            raise ValueError(f"BOOL# takes TRUE, FALSE, 0 or 1, not {raw}")
        return type_name, value
    sign = -1 if raw.startswith("-") else 1
    if raw[:1] in "+-" and "#" in raw:
        raise ValueError(f"{text}: a based number takes no sign (IEC 61131-3, 6.3.2)")
    raw = raw.lstrip("+-")
    if type_name in ("REAL", "LREAL"):
        return type_name, sign * (float(raw.replace("_", "")) if "#" not in raw
                                  else parse_number(raw))
    if "." in raw:
        raise ValueError(f"{type_name}# takes a whole number, not {raw}")
    return type_name, sign * parse_number(raw)


def _span(file: str, item: Any) -> n.Span:
    return n.Span(file, getattr(item, "line", 1) or 1, getattr(item, "column", 1) or 1)


@v_args(meta=True)
class _Build(Transformer_NonRecursive[Token, Any]):
    """The tree -> nodes.  Non-recursive: a chain of 10,000 operators is a tree 10,000 deep
    (lark's LALR parser builds it without recursion; the default Transformer would not)."""

    def __init__(self, file: str) -> None:
        super().__init__()
        self.file = file

    def _s(self, meta: Any, children: list[Any] | None = None) -> n.Span:
        if not getattr(meta, "empty", True):
            return n.Span(self.file, meta.line, meta.column)
        for child in children or ():
            span = getattr(child, "span", None) or (
                _span(self.file, child) if isinstance(child, Token) else None)
            if span is not None:
                return span
        return n.Span(self.file, 1, 1)

    # -- POUs --------------------------------------------------------------------------------

    def start(self, meta: Any, children: list[Any]
              ) -> tuple[tuple[n.Pou, ...], tuple[n.TypeDecl, ...], tuple[n.VarDecl, ...]]:
        pous = tuple(c for c in children if isinstance(c, n.Pou))
        types = tuple(t for c in children if isinstance(c, tuple) and c and c[0] == "TYPE"
                      for t in c[1])
        globals_ = tuple(d for c in children if isinstance(c, list) for d in c)
        return pous, types, globals_

    # -- data types and globals ----------------------------------------------------------------

    def type_decl(self, meta: Any, children: list[Any]) -> tuple[str, list[n.TypeDecl]]:
        return ("TYPE", [c for c in children if isinstance(c, n.TypeDecl)])

    def type_def(self, meta: Any, children: list[Any]) -> n.TypeDecl:
        name, (kind, fields, items, base, initial) = children
        return n.TypeDecl(str(name), kind, fields, items, base, initial,
                          _span(self.file, name))

    def struct_spec(self, meta: Any, children: list[Any]) -> tuple[Any, ...]:
        fields = tuple(d for c in children if isinstance(c, list) for d in c)
        return ("STRUCT", fields, (), None, None)

    def enum_spec(self, meta: Any, children: list[Any]) -> tuple[Any, ...]:
        items = tuple(c for c in children if isinstance(c, tuple))
        default = next((str(c) for c in children if isinstance(c, Token)), None)
        return ("ENUM", (), items, None, default)

    def enum_item(self, meta: Any, children: list[Any]) -> tuple[str, n.Expr | None, n.Span]:
        return (str(children[0]), children[1] if len(children) > 1 else None,
                _span(self.file, children[0]))

    def alias_spec(self, meta: Any, children: list[Any]) -> tuple[Any, ...]:
        return ("ALIAS", (), (), children[0], children[1] if len(children) > 1 else None)

    def global_block(self, meta: Any, children: list[Any]) -> list[n.VarDecl]:
        return self.var_block(meta, children)

    def _pou(self, kind: str, meta: Any, children: list[Any]) -> n.Pou:
        name = children[1]
        result = None
        rest = children[2:-1]
        if kind == "FUNCTION" and isinstance(rest[0], n.NamedType | n.SubrangeType |
                                             n.ArrayType):
            result, rest = rest[0], rest[1:]  # none: a FUNCTION without a result (6.6.2.2)
        decls = tuple(d for block in rest[:-1] for d in block)
        return n.Pou(kind, str(name), result, decls, rest[-1], self._s(meta, children))

    def program(self, meta: Any, children: list[Any]) -> n.Pou:
        return self._pou("PROGRAM", meta, children)

    def function_block(self, meta: Any, children: list[Any]) -> n.Pou:
        return self._pou("FUNCTION_BLOCK", meta, children)

    def function(self, meta: Any, children: list[Any]) -> n.Pou:
        return self._pou("FUNCTION", meta, children)

    def var_block(self, meta: Any, children: list[Any]) -> list[n.VarDecl]:
        section = str(children[0]).upper()
        qualifier = None
        items = children[1:-1]
        while items and isinstance(items[0], Token):
            word = str(items[0]).upper()
            if word == "PERSISTENT":  # CODESYS, TwinCAT: kept over a restart and a
                word = "RETAIN"       # download; ncgate's RETAIN store does both
            if word != "NON_RETAIN":  # the default: nothing is kept over a restart
                qualifier = word
            items = items[1:]
        return [n.VarDecl(d.name, d.type, d.initial, section, qualifier, d.span, d.located)
                for decl in items for d in decl]

    def var_decl(self, meta: Any, children: list[Any]) -> list[n.VarDecl]:
        names = [c for c in children if isinstance(c, Token) and c.type == "NAME"]
        located = next((c for c in children if isinstance(c, n.Span)), None)
        rest = [c for c in children if not (isinstance(c, Token) and c.type == "NAME")
                and not isinstance(c, n.Span)]
        type_ref = rest[0]
        initial = rest[1] if len(rest) > 1 else None
        return [n.VarDecl(str(t), type_ref, initial, "VAR", None, _span(self.file, t),
                          located) for t in names]

    def located(self, meta: Any, children: list[Token]) -> n.Span:
        return _span(self.file, children[0])

    def named_type(self, meta: Any, children: list[Token]) -> n.NamedType:
        return n.NamedType(str(children[0]), _span(self.file, children[0]))

    def sized_type(self, meta: Any, children: list[Any]) -> n.NamedType:
        return n.NamedType(str(children[0]), _span(self.file, children[0]), children[1])

    def subrange_type(self, meta: Any, children: list[Any]) -> n.SubrangeType:
        return n.SubrangeType(str(children[0]), children[1], children[2],
                              _span(self.file, children[0]))

    def array_type(self, meta: Any, children: list[Any]) -> n.ArrayType:
        dims = tuple(None if isinstance(c, _Dots) else c for c in children
                     if isinstance(c, tuple | _Dots) or c is None)
        return n.ArrayType(dims, children[-1], _span(self.file, children[0]),
                           dots=any(isinstance(c, _Dots) for c in children))

    def dim_dots(self, meta: Any, children: list[Any]) -> _Dots:
        return _Dots()

    def dim(self, meta: Any, children: list[Any]) -> tuple[n.Expr, n.Expr] | None:
        if len(children) == 1:  # '*'
            return None
        return (children[0], children[1])

    def _number(self, token: Token) -> int:
        try:
            return parse_number(str(token))
        except ValueError as exc:
            raise BadLiteral(token, str(exc)) from None

    def array_init(self, meta: Any, children: list[tuple[int, n.Initial | None]]
                   ) -> n.ArrayInit:
        return n.ArrayInit(tuple(children), self._s(meta, []))

    def init_one(self, meta: Any, children: list[n.Initial]) -> tuple[int, n.Initial]:
        return (1, children[0])

    def init_repeat(self, meta: Any, children: list[Any]) -> tuple[int, n.Initial | None]:
        return (self._number(children[0]), children[1] if len(children) > 1 else None)

    def struct_init(self, meta: Any, children: list[tuple[str, n.Span, n.Initial]]
                    ) -> n.StructInit:
        return n.StructInit(tuple(children), children[0][1])

    def field_init(self, meta: Any, children: list[Any]) -> tuple[str, n.Span, n.Initial]:
        return (str(children[0]), _span(self.file, children[0]), children[1])

    # -- statements --------------------------------------------------------------------------

    def stmts(self, meta: Any, children: list[Any]) -> tuple[n.Stmt, ...]:
        return tuple(c for c in children if not isinstance(c, Token))

    def assign(self, meta: Any, children: list[Any]) -> n.Assign:
        return n.Assign(children[0], children[1], children[0].span)

    def call_stmt(self, meta: Any, children: list[Any]) -> n.CallStmt:
        return n.CallStmt(children[0], tuple(children[1:]), children[0].span)

    def in_arg(self, meta: Any, children: list[Any]) -> n.Arg:
        return n.Arg(str(children[0]), children[1], None, _span(self.file, children[0]))

    def out_arg(self, meta: Any, children: list[Any]) -> n.Arg:
        return n.Arg(str(children[0]), None, children[1], _span(self.file, children[0]))

    def pos_arg(self, meta: Any, children: list[Any]) -> n.Arg:
        return n.Arg(None, children[0], None, children[0].span)

    def if_stmt(self, meta: Any, children: list[Any]) -> n.If:
        parts = [c for c in children if not isinstance(c, Token)]
        branches = [(parts[0], parts[1])]
        otherwise = None
        for part in parts[2:]:
            if isinstance(part, tuple) and len(part) == 2 and part[0] == "ELSIF":
                branches.append(part[1])
            else:
                otherwise = part
        return n.If(tuple(branches), otherwise, self._s(meta, children))

    def elsif(self, meta: Any, children: list[Any]) -> tuple[str, tuple[n.Expr, Any]]:
        return ("ELSIF", (children[1], children[3]))

    def else_part(self, meta: Any, children: list[Any]) -> tuple[n.Stmt, ...]:
        body: tuple[n.Stmt, ...] = children[1]
        return body

    def case_stmt(self, meta: Any, children: list[Any]) -> n.Case:
        parts = [c for c in children if not isinstance(c, Token)]
        selector, rest = parts[0], parts[1:]
        arms = tuple(p for p in rest if isinstance(p, tuple) and p and p[0] == "ARM")
        otherwise = next((p for p in rest if not (isinstance(p, tuple) and p
                                                   and p[0] == "ARM")), None)
        return n.Case(selector, tuple((a[1], a[2]) for a in arms), otherwise,
                      self._s(meta, children))

    def case_arm(self, meta: Any, children: list[Any]) -> tuple[str, Any, Any]:
        return ("ARM", tuple(children[:-1]), children[-1])

    def label_one(self, meta: Any, children: list[n.Literal]) -> n.CaseLabel:
        return n.CaseLabel(children[0], None, children[0].span)

    def label_range(self, meta: Any, children: list[n.Literal]) -> n.CaseLabel:
        return n.CaseLabel(children[0], children[1], children[0].span)

    def case_value(self, meta: Any, children: list[Token]) -> n.Literal | n.Var | n.EnumLit:
        token = children[-1]
        negative = len(children) == 2
        span = _span(self.file, children[0])
        if token.type == "CASE_NAME":
            first, _, member = str(token).partition(".")
            return n.Var(first, (n.Field(member, span),) if member else (), span)
        if token.type == "ENUM_LIT":
            return self.enum_lit(meta, [token])
        if token.type == "TYPED_LIT":
            type_name, value = self._typed(token)
        else:
            type_name, value = None, self._number(token)
        if isinstance(value, bool | float):
            raise BadLiteral(token, f"a CASE label is a whole number, not {token}")
        return n.Literal(-value if negative else value, type_name, span)

    def for_stmt(self, meta: Any, children: list[Any]) -> n.For:
        parts = [c for c in children if not (isinstance(c, Token) and c.type != "NAME")]
        var, start, end = parts[0], parts[1], parts[2]
        step = parts[3] if len(parts) == 5 else None
        return n.For(str(var), _span(self.file, var), start, end, step, parts[-1],
                     self._s(meta, children))

    def while_stmt(self, meta: Any, children: list[Any]) -> n.While:
        return n.While(children[1], children[3], self._s(meta, children))

    def repeat_stmt(self, meta: Any, children: list[Any]) -> n.Repeat:
        return n.Repeat(children[1], children[3], self._s(meta, children))

    def exit_stmt(self, meta: Any, children: list[Token]) -> n.Exit:
        return n.Exit(_span(self.file, children[0]))

    def continue_stmt(self, meta: Any, children: list[Token]) -> n.Continue:
        return n.Continue(_span(self.file, children[0]))

    def return_stmt(self, meta: Any, children: list[Token]) -> n.Return:
        return n.Return(_span(self.file, children[0]))

    # -- expressions -------------------------------------------------------------------------

    def binary(self, meta: Any, children: list[Any]) -> n.Binary:
        left, op, right = children
        name = str(op).upper()
        return n.Binary("AND" if name == "&" else name, left, right, _span(self.file, op))

    def unary(self, meta: Any, children: list[Any]) -> n.Unary:
        op, operand = children
        return n.Unary(str(op).upper(), operand, _span(self.file, op))

    def call(self, meta: Any, children: list[Any]) -> n.Call:
        return n.Call(str(children[0]), tuple(children[1:]), _span(self.file, children[0]))

    def variable(self, meta: Any, children: list[Any]) -> n.Var:
        selectors = []
        for c in children[1:]:  # a[i, j] is a[i][j]
            selectors += c if isinstance(c, list) else [c]
        return n.Var(str(children[0]), tuple(selectors), _span(self.file, children[0]))

    def field(self, meta: Any, children: list[Token]) -> n.Field:
        return n.Field(str(children[0]), _span(self.file, children[0]))

    def bit(self, meta: Any, children: list[Token]) -> n.Bit:
        token = children[0]
        if token.type == "BIT_X":  # w.%X3
            return n.Bit(int(str(token)[2:]), _span(self.file, token), codesys=True)
        return n.Bit(self._number(token), _span(self.file, token))

    def index(self, meta: Any, children: list[Any]) -> list[n.Index]:
        return [n.Index(c, c.span) for c in children]

    def int_lit(self, meta: Any, children: list[Token]) -> n.Literal:
        return n.Literal(self._number(children[0]), None, _span(self.file, children[0]))

    def real_lit(self, meta: Any, children: list[Token]) -> n.Literal:
        text = str(children[0])
        mantissa = text.split("e")[0].split("E")[0]
        whole, _, fraction = mantissa.partition(".")
        if not (_DECIMAL.fullmatch(whole) and _DECIMAL.fullmatch(fraction)):
            raise BadLiteral(children[0], f"{text} is not a number (one '_' at most between "
                             "digits)")
        return n.Literal(float(text.replace("_", "")), None, _span(self.file, children[0]))

    def _typed(self, token: Token) -> tuple[str, bool | int | float]:
        try:
            return parse_typed(str(token))
        except ValueError as exc:
            raise BadLiteral(token, str(exc)) from None

    def typed_lit(self, meta: Any, children: list[Token]) -> n.Literal:
        type_name, value = self._typed(children[0])
        return n.Literal(value, type_name, _span(self.file, children[0]))

    def time_lit(self, meta: Any, children: list[Token]) -> n.Literal:
        text = str(children[0])
        long = text.upper().startswith("L")
        try:
            value = parse_time(text, long)
        except ValueError as exc:
            raise BadLiteral(children[0], str(exc)) from None
        return n.Literal(value, "LTIME" if long else "TIME", _span(self.file, children[0]))

    def date_lit(self, meta: Any, children: list[Token]) -> n.Literal:
        try:
            type_name, value = parse_date(str(children[0]))
        except ValueError as exc:
            raise BadLiteral(children[0], str(exc)) from None
        return n.Literal(value, type_name, _span(self.file, children[0]))

    def string_lit(self, meta: Any, children: list[Token]) -> n.Literal:
        token = children[0]
        text = str(token)
        wide = token.type == "WSTRING_LIT"
        kind = "STRING"
        if token.type == "TYPED_STRING":  # STRING#'…', WCHAR#"…": the type names it
            prefix, _, text = text.partition("#")
            wide = prefix.upper().startswith("W")
            kind = prefix.upper().lstrip("W")
        try:
            value = parse_string(text)
            if not wide and any(ord(c) > 255 for c in value):
                raise ValueError("a STRING holds one byte a character (Latin-1)")
            if kind == "CHAR" and len(value) != 1:
                raise ValueError(f"a {prefix.upper()} literal is one character, not "
                                 f"{len(value)}")
        except ValueError as exc:
            raise BadLiteral(token, str(exc)) from None
        return n.Literal(value, ("W" if wide else "") + kind, _span(self.file, token))

    def enum_lit(self, meta: Any, children: list[Token]) -> n.EnumLit:
        type_name, _, name = str(children[0]).partition("#")
        return n.EnumLit(type_name, name, _span(self.file, children[0]))

    def bool_lit(self, meta: Any, children: list[Token]) -> n.Literal:
        return n.Literal(str(children[0]).upper() == "TRUE", "BOOL",
                         _span(self.file, children[0]))


def _expected(exc: UnexpectedToken | UnexpectedEOF) -> str:
    parser = _parser()
    shown = []
    for name in sorted(exc.expected):
        if name in _SHOWN:
            shown.append(_SHOWN[name])
            continue
        try:
            pattern = parser.get_terminal(name).pattern
        except KeyError:
            continue
        if pattern.type == "str":
            shown.append(f"'{pattern.value}'" if not pattern.value.isalpha()
                         else pattern.value.upper())
        else:
            shown.append(name.lower().replace("_", " "))
    shown = sorted(set(shown))
    if len(shown) > 8:
        shown = [*shown[:8], "…"]
    return ", ".join(shown)


def parse_source(text: str, file: str) -> n.SourceFile:
    """Parse one file; raises :class:`LogicError` with a diagnostic on a syntax error."""
    lines = text.splitlines()

    def fail(code: StCode, message: str, line: int, column: int) -> LogicError:
        source = lines[line - 1] if 0 < line <= len(lines) else ""
        return LogicError([StDiagnostic(code, message, n.Span(file, line, column), source)])

    def not_supported(at: int) -> LogicError | None:
        found = _unsupported(text, at)
        if found is None:
            return None
        what, where = found
        line, column = _position(text, where)
        return fail(StCode.UNSUPPORTED, f"{what}: not supported by ncgate's Structured Text "
                    "(docs/plc.md lists what is)", line, column)

    unknown: list[int] = []
    blanked = text
    try:
        blanked = blank_comments(text, unknown)
        tree = _parser().parse(blanked)
    except UnclosedComment as exc:
        line, column = _position(text, exc.at)
        raise fail(StCode.UNEXPECTED_END, f"the file ends inside this {exc.what} (it is "
                   "never closed)", line, column) from None
    except UnexpectedCharacters as exc:
        unsupported = not_supported(exc.pos_in_stream or 0)
        if unsupported is not None:
            raise unsupported from None
        pos = exc.pos_in_stream or 0
        char = text[pos] if pos < len(text) else ""
        raise fail(StCode.UNEXPECTED_CHARACTER, f"unexpected character {char!r}",
                   exc.line, exc.column) from None
    except UnexpectedEOF as exc:
        line = len(lines) or 1
        raise fail(StCode.UNEXPECTED_END, f"the file ends here; expected {_expected(exc)}",
                   line, len(lines[-1]) + 1 if lines else 1) from None
    except UnexpectedToken as exc:
        token = exc.token
        unsupported = not_supported(token.start_pos) if token.start_pos is not None else None
        if unsupported is not None:
            raise unsupported from None
        if token.type == "$END":
            line = len(lines) or 1
            raise fail(StCode.UNEXPECTED_END, f"the file ends here; expected "
                       f"{_expected(exc)}", line, len(lines[-1]) + 1 if lines else 1) from None
        construct = _field_construct(blanked, token.start_pos, token) \
            if token.start_pos is not None else None
        if construct is not None:
            code, message, where = construct
            line, column = _position(text, where)
            raise fail(code, message, line, column) from None
        keyword = " (a keyword, not a name)" if "NAME" in exc.expected and \
            str(token).upper() == token.type else ""
        raise fail(StCode.UNEXPECTED_TOKEN, f"unexpected {str(token)!r}{keyword}; expected "
                   f"{_expected(exc)}", token.line or 1, token.column or 1) from None
    except UnexpectedInput as exc:  # pragma: no cover - the three above are all lark raises
        raise fail(StCode.UNEXPECTED_TOKEN, str(exc), exc.line, exc.column) from None
    try:
        pous, types, globals_ = _Build(file).transform(tree)
    except Exception as exc:  # lark wraps a transformer's error in VisitError
        cause = getattr(exc, "orig_exc", exc)
        if isinstance(cause, BadLiteral):
            raise fail(StCode.BAD_LITERAL, str(cause), cause.token.line or 1,
                       cause.token.column or 1) from None
        raise
    _dismantle(tree)
    warnings = []
    for at in unknown:
        line, column = _position(text, at)
        warnings.append(StDiagnostic(StCode.UNKNOWN_PRAGMA, "a pragma ncgate does not know: "
                                     "ignored (what it asks for is not done)",
                                     n.Span(file, line, column), lines[line - 1]))
    return n.SourceFile(file, text, pous, types, globals_, tuple(warnings))


def _dismantle(tree: Tree[Any]) -> None:
    """Free a parse tree a few thousand nodes at a time.  Dropped whole, its last reference
    frees every node in one cascade inside C: 146 ms for 20,000 statements, holding the
    interpreter while the loop beside the reloading thread serves the fieldbus.  A node the
    syntax tree built from it still holds is left as it is."""
    stack = [child for child in tree.children if isinstance(child, Tree)]
    tree.children.clear()
    freed = 0
    while stack:
        node = stack.pop()
        if sys.getrefcount(node) > 2:  # ``node`` and the call's own: held elsewhere too
            continue
        children = node.children
        stack.extend(child for child in children if isinstance(child, Tree))
        children.clear()
        freed += 1
        if freed % 4096 == 0:
            time.sleep(0)  # (a thread waiting for the interpreter gets it now)


def parse_file(path: str | Path) -> n.SourceFile:
    path = Path(path)
    data = path.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise LogicError([StDiagnostic(StCode.NOT_UTF8, f"byte 0x{data[exc.start]:02X} is not "
                                       "UTF-8 (save the file as UTF-8)",
                                       n.Span(str(path), line, column), "")]) from None
    return parse_source(text.removeprefix("\ufeff"), str(path))
