"""The part-program parser: one lark LALR grammar, one line (block) at a time.

Speed without a second parser
-----------------------------
Every terminal of ``grammar/nc110.lark`` treats a run of digits the same whatever its length
or value, so the token boundaries of a line -- and therefore the LALR parse -- depend only on
the line with each digit run collapsed to ``0`` (its *shape*).  ``N10G1X12.5F300`` and
``N20G1X7.25F1200`` share one shape.  The first line of a shape is parsed by lark; the parse
tree is compiled into a *recipe* that rebuilds the typed AST from the digit runs of any line of
that shape.  Lark stays the only parser (every shape goes through it); the recipe only replays
its result.  A line whose shape does not parse is parsed again as written, so diagnostics
always come from lark on the real text.

Programs are parsed lazily: :class:`Program` pre-scans the text for labels with one regular
expression and parses a block only when it is asked for (:meth:`Program.block`).

Must not import ``plc`` or ``gateway``.
"""

from __future__ import annotations

import codecs
import re
from array import array
from bisect import bisect_right
from collections.abc import Callable, Iterator, Sequence
from functools import cache
from importlib import resources
from itertools import accumulate
from pathlib import Path
from typing import Any, Final, overload

from lark import Lark, Token, Tree
from lark.exceptions import UnexpectedCharacters, UnexpectedInput, UnexpectedToken

from ncgate.interpreter.batch import gc_paused
from ncgate.interpreter.cache import BlockCache, block_table
from ncgate.interpreter.codes import MODELLED_CODES, UNMODELLED_CODES, DiagnosticCode
from ncgate.interpreter.diagnostics import (
    LINE_END,
    Diagnostic,
    LineError,
    ProgramSyntaxError,
    did_you_mean,
    not_utf8,
)
from ncgate.interpreter.nc110.nodes import (
    Assign,
    Binary,
    Block,
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
from ncgate.interpreter.storage import program_name as program_name  # (spec 1.1)

WORD_LETTERS: Final = frozenset("ABCDFGHIJKLMOPQRSTUVWXYZ")


@cache
def lark_parser() -> Lark:
    """The LALR parser of one block (built once per process)."""
    grammar = resources.files("ncgate.interpreter.nc110").joinpath("grammar/nc110.lark")
    return Lark(grammar.read_text("utf-8"), parser="lalr", lexer="contextual",
                maybe_placeholders=False)


# ---- building nodes from tokens ---------------------------------------------------------
# A token during a build is (type, text, column).  Callbacks get the children of a rule.

Tok = tuple[str, str, int]
Child = Any  # a Tok or a node built by a callback
_Ctx = tuple[str, int, str]  # file, line number, source text


_new_tuple = tuple.__new__


def _span(ctx: _Ctx, col: int) -> Span:
    # tuple.__new__ skips the NamedTuple's Python-level __new__: one Span per node adds up.
    return _new_tuple(Span, (ctx[0], ctx[1], col))


def _error(ctx: _Ctx, col: int, code: DiagnosticCode, message: str) -> LineError:
    return LineError(Diagnostic(code, message, _span(ctx, col), ctx[2]))


def _var_from_token(tok: Tok, ctx: _Ctx) -> VarRef:
    kind_name, text, col = tok
    span = _span(ctx, col)
    upper = text.upper()
    if kind_name == "EPARAM":
        return VarRef(VarKind.E, int(upper[1:]), View.REAL, span)
    if kind_name == "SYVAR":
        digits = upper[5:]
        return VarRef(VarKind.SYVAR, int(digits or 0), View.INT16, span, not digits)
    kind = VarKind.SA if kind_name == "SAVAR" else VarKind.SK
    index_text, _, suffix = upper[2:].partition(".")
    if suffix == "IN":
        view = View.INT16
    elif suffix == "BY" or kind is VarKind.SK:
        view = View.BYTE
    else:
        view = View.BIT
    return VarRef(kind, int(index_text), view, span)


# The builders call these two directly: a word's letter and kind are the same in every line
# of a shape, so only the value text varies.
_INF: Final = float("inf")


def _float(text: str, col: int, ctx: _Ctx) -> float:
    """A literal's value; one that is too large for a double is a diagnostic, not inf."""
    value = float(text)
    if value == _INF:
        raise _error(ctx, col, DiagnosticCode.NUMBER_OUT_OF_RANGE,
                     f"a number of {len(text)} characters is too large (at most about 1.8e308)")
    return value


def _number_word(letter: str, value: str, col: int, ctx: _Ctx) -> Word:
    number = float(value)
    if number == _INF:  # inline: this is the commonest node of all
        number = _float(value, col + 1, ctx)
    return Word(letter, number, value, _new_tuple(Span, (ctx[0], ctx[1], col)))


def _e_word(letter: str, value: str, col: int, ctx: _Ctx) -> Word:
    var = VarRef(VarKind.E, int(value[1:]), View.REAL, _span(ctx, col + 1))
    return Word(letter, var, value, _span(ctx, col))


def _cb_var(ch: list[Child], ctx: _Ctx) -> VarRef:
    return _var_from_token(ch[0], ctx)


def _cb_assign(ch: list[Child], ctx: _Ctx) -> Assign:
    target: VarRef = ch[0]
    return Assign(target, ch[2], target.span)


def _cb_exe(ch: list[Child], ctx: _Ctx) -> Exe:
    device = ch[7][1].upper() if len(ch) > 7 else None
    return Exe(ch[3], ch[5][1], device, _span(ctx, ch[0][2]))


def _cb_rel(ch: list[Child], ctx: _Ctx) -> Rel:
    return Rel(_span(ctx, ch[0][2]))


def _cb_wai_proc(ch: list[Child], ctx: _Ctx) -> WaitProc:
    return WaitProc(ch[3], _span(ctx, ch[0][2]))


def _cb_wai_cond(ch: list[Child], ctx: _Ctx) -> WaitCond:
    return WaitCond(ch[3], CompareOp(ch[4][1]), ch[5], _span(ctx, ch[0][2]))


def _cb_snd(ch: list[Child], ctx: _Ctx) -> Snd:
    return Snd(ch[3], _span(ctx, ch[0][2]))


def _cb_bnc(ch: list[Child], ctx: _Ctx) -> Jump:
    return Jump(ch[3][1], _span(ctx, ch[0][2]))


def _cb_bcond(ch: list[Child], ctx: _Ctx) -> Branch:
    return Branch(BranchOp(ch[1][1].upper()), ch[3], ch[5], ch[7][1], _span(ctx, ch[0][2]))


def _cb_rpt(ch: list[Child], ctx: _Ctx) -> Repeat:
    return Repeat(ch[3], _span(ctx, ch[0][2]))


def _cb_erp(ch: list[Child], ctx: _Ctx) -> EndRepeat:
    return EndRepeat(_span(ctx, ch[0][2]))


def _cb_dly(ch: list[Child], ctx: _Ctx) -> Dwell:
    return Dwell(ch[3], _span(ctx, ch[0][2]))


def _cb_dis(ch: list[Child], ctx: _Ctx) -> Display:
    args = tuple(c for c in ch[5:-1] if type(c) is not tuple)
    return Display(ch[3][1][1:-1], args, _span(ctx, ch[0][2]))


def _cb_other_code(ch: list[Child], ctx: _Ctx) -> InertCode:
    _, name, col = ch[1]
    code = name.upper()
    if code not in UNMODELLED_CODES:
        hint = did_you_mean(code, sorted(MODELLED_CODES | UNMODELLED_CODES))
        suffix = f" (did you mean {hint}?)" if hint else ""
        raise _error(ctx, col, DiagnosticCode.UNKNOWN_CODE,
                     f"({name} is not a code of the language{suffix}")
    raw: list[str] = []
    expect_value = False
    for c in ch[2:-1]:
        if c[0] == "COMMA":
            if expect_value:
                raw.append("")
            expect_value = True
        else:
            raw.append(c[1].strip())
            expect_value = False
    if expect_value:
        raw.append("")
    return InertCode(code, tuple(raw), _span(ctx, ch[0][2]))


def _cb_number(ch: list[Child], ctx: _Ctx) -> Num:
    return Num(_float(ch[0][1], ch[0][2], ctx), _span(ctx, ch[0][2]))


def _cb_neg_number(ch: list[Child], ctx: _Ctx) -> Num:
    return Num(-_float(ch[1][1], ch[1][2], ctx), _span(ctx, ch[0][2]))


def _cb_number_plus(ch: list[Child], ctx: _Ctx) -> Num:
    return Num(_float(ch[1][1], ch[1][2], ctx), _span(ctx, ch[0][2]))


def _cb_binop(ch: list[Child], ctx: _Ctx) -> Binary:
    left = ch[0]
    return Binary(ch[1][1], left, ch[2], left.span)


def _cb_neg(ch: list[Child], ctx: _Ctx) -> Unary:
    return Unary("-", ch[1], _span(ctx, ch[0][2]))


def _cb_pos(ch: list[Child], ctx: _Ctx) -> Unary:
    return Unary("+", ch[1], _span(ctx, ch[0][2]))


def _cb_call(ch: list[Child], ctx: _Ctx) -> Call:
    return Call(ch[0][1].upper(), ch[2], _span(ctx, ch[0][2]))


def _cb_paren(ch: list[Child], ctx: _Ctx) -> Child:
    return ch[1]


_CALLBACKS: Final[dict[str, Callable[[list[Child], _Ctx], Any]]] = {
    # "start" and "word" have no callback: the builders construct them directly
    # (_start_source, _number_word, _e_word).
    "var": _cb_var,
    "eparam": _cb_var,
    "assign": _cb_assign,
    "exe": _cb_exe,
    "rel": _cb_rel,
    "wai_proc": _cb_wai_proc,
    "wai_cond": _cb_wai_cond,
    "snd": _cb_snd,
    "bnc": _cb_bnc,
    "bcond": _cb_bcond,
    "rpt": _cb_rpt,
    "erp": _cb_erp,
    "dly": _cb_dly,
    "dis": _cb_dis,
    "other_code": _cb_other_code,
    "const_int": _cb_number,
    "number": _cb_number,
    "neg_number": _cb_neg_number,
    "number_plus": _cb_number_plus,
    "binop": _cb_binop,
    "neg": _cb_neg,
    "pos": _cb_pos,
    "call": _cb_call,
    "paren": _cb_paren,
}

# ---- builders: a compiled parse of one shape ----------------------------------------------
# The lark tree of a shape is turned into the source of one Python function that rebuilds the
# same tree from the digit runs of any line of that shape, calling the callbacks above.  A token
# becomes ``(type, text, column)``: its text is the shape's text with the runs spliced back in,
# its column the shape's column shifted by the lengths of the runs before it.

Builder = Callable[[Sequence[str], Sequence[int], _Ctx], Any]
_CALLBACK_NAMES: Final = {cb: f"_cb_{name}" for name, cb in _CALLBACKS.items()}


def _token_parts(token: Token, runs_before: Sequence[int], split: bool,
                 skip: int = 0) -> tuple[str, str]:
    """Source of the token's text (less its first ``skip`` characters) and of its column.
    ``runs_before[i]``: how many digit runs (each a "0" in the shape) come before column i."""
    pos = token.start_pos or 0
    if not split:
        return repr(token.value[skip:]), str(pos + 1)
    pieces = token.value.split("0")
    pieces[0] = pieces[0][skip:]
    k = runs_before[pos]
    text = " + ".join(
        part for i, piece in enumerate(pieces)
        for part in ((repr(piece),) if i == 0 else (f"runs[{k + i - 1}]", repr(piece)))
        if part != "''"
    ) or "''"
    # Each run of n digits stood as one "0" in the shape: shift by the runs before the token.
    col = f"{pos + 1 - k} + lens[{k}]" if k else str(pos + 1)
    return text, col


def _tree_source(tree: Tree[Token] | Token, runs_before: Sequence[int], split: bool) -> str:
    if isinstance(tree, Token):
        text, col = _token_parts(tree, runs_before, split)
        return f"({tree.type!r}, {text}, {col})"
    rule = tree.data if isinstance(tree.data, str) else tree.data.value
    if rule == "start":
        return _start_source(tree, runs_before, split)
    if rule == "word":  # the commonest node: no child list, no token tuple
        token = tree.children[0]
        assert isinstance(token, Token)
        value, col = _token_parts(token, runs_before, split, skip=1)
        make = "_e_word" if token.value[1] in "eE" else "_number_word"
        return f"{make}({token.value[0].upper()!r}, {value}, {col}, ctx)"
    children = ", ".join(_tree_source(c, runs_before, split) for c in tree.children)
    return f"{_CALLBACK_NAMES[_CALLBACKS[rule]]}([{children}], ctx)"


def _start_source(tree: Tree[Token], runs_before: Sequence[int], split: bool) -> str:
    """The Block of a shape, built in one call: its prefix and items are known statically."""
    fields = {"deleted": "False", "label": "None", "number": "None", "synced": "False",
              "comment": "None"}
    items: list[str] = []
    for child in tree.children:
        if not isinstance(child, Token):
            items.append(_tree_source(child, runs_before, split))
            continue
        text, _ = _token_parts(child, runs_before, split)
        if child.type == "NWORD":
            fields["number"] = f"int(({text})[1:])"
        elif child.type == "SLASH":
            fields["deleted"] = "True"
        elif child.type == "STRING":
            fields["label"] = f"({text})[1:-1]"
        elif child.type == "HASH":
            fields["synced"] = "True"
        else:  # COMMENT
            fields["comment"] = f"({text})[1:].strip()"
    tail = "," if len(items) == 1 else ""
    return (f"_Block(_span(ctx, 1), {fields['deleted']}, {fields['label']}, "
            f"{fields['number']}, {fields['synced']}, ({', '.join(items)}{tail}), "
            f"{fields['comment']})")


def _compile(tree: Tree[Token], shape: str, split: bool) -> Builder:
    runs_before = list(accumulate((c == "0" for c in shape), initial=0))
    source = f"def build(runs, lens, ctx):\n    return {_tree_source(tree, runs_before, split)}\n"
    namespace: dict[str, Any] = {name: cb for cb, name in _CALLBACK_NAMES.items()}
    namespace.update(_number_word=_number_word, _e_word=_e_word, _Block=Block, _span=_span)
    exec(compile(source, f"<shape {shape!r}>", "exec"), namespace)
    builder: Builder = namespace["build"]
    return builder


def _failed(runs: Sequence[str], lens: Sequence[int], ctx: _Ctx) -> Any:
    return _parse_as_written(ctx[2], ctx)


# ---- limits: nesting and long blocks --------------------------------------------------------
# An expression nests at most MAX_DEPTH levels: each operator, sign, pair of parentheses and
# function call counts one (``1+2+3`` is two levels, ``-(SIN(E1))`` three).  Deeper input is
# diagnosed (NC013) before anything recursive sees it.  A block longer than LONG_BLOCK
# characters is built straight from lark's tree, without a recipe: recipes pay off for the
# short blocks programs repeat, and compiling one for a huge block costs more than it saves.

MAX_DEPTH: Final = 64
LONG_BLOCK: Final = 1000
_NESTING_RULES: Final = frozenset({"binop", "neg", "pos", "call", "paren"})


def _rule(tree: Tree[Token]) -> str:
    return tree.data if isinstance(tree.data, str) else tree.data.value


def _too_deep(tree: Tree[Token]) -> Token | None:
    """The operator, sign or opening token where nesting first passes MAX_DEPTH, if it does."""
    stack: list[tuple[Tree[Token], int]] = [(tree, 0)]
    while stack:
        node, depth = stack.pop()
        if _rule(node) in _NESTING_RULES:
            depth += 1
            if depth > MAX_DEPTH:
                children = node.children
                token = children[1] if _rule(node) == "binop" else children[0]
                return token if isinstance(token, Token) else None
        stack.extend((c, depth) for c in node.children if isinstance(c, Tree))
    return None


def _check_depth(tree: Tree[Token], ctx: _Ctx) -> None:
    token = _too_deep(tree)
    if token is not None:
        raise _error(ctx, (token.start_pos or 0) + 1, DiagnosticCode.EXPRESSION_TOO_DEEP,
                     f"expression nested deeper than {MAX_DEPTH} levels (each operator, sign, "
                     "parenthesis and function counts one)")


def _build_direct(tree: Tree[Token], ctx: _Ctx) -> Block:
    """The Block of a parse tree, built without recursion and without a recipe."""
    stack: list[tuple[Tree[Token], list[Child], Iterator[Tree[Token] | Token]]] = [
        (tree, [], iter(tree.children))]
    while True:
        node, built, children = stack[-1]
        child = next(children, None)
        if child is None:
            stack.pop()
            value = _finish(node, built, ctx)
            if not stack:
                block: Block = value
                return block
            stack[-1][1].append(value)
        elif isinstance(child, Token):
            built.append((child.type, child.value, (child.start_pos or 0) + 1))
        elif _rule(child) == "word":
            token = child.children[0]
            assert isinstance(token, Token)
            make = _e_word if token.value[1] in "eE" else _number_word
            built.append(make(token.value[0].upper(), token.value[1:],
                              (token.start_pos or 0) + 1, ctx))
        else:
            stack.append((child, [], iter(child.children)))


def _finish(node: Tree[Token], built: list[Child], ctx: _Ctx) -> Any:
    rule = _rule(node)
    if rule != "start":
        return _CALLBACKS[rule](built, ctx)
    deleted, synced = False, False
    label: str | None = None
    number: int | None = None
    comment: str | None = None
    items = []
    for c in built:
        if type(c) is not tuple:
            items.append(c)
            continue
        kind, text, _ = c
        if kind == "NWORD":
            number = int(text[1:])
        elif kind == "SLASH":
            deleted = True
        elif kind == "STRING":
            label = text[1:-1]
        elif kind == "HASH":
            synced = True
        else:  # COMMENT
            comment = text[1:].strip()
    return Block(_span(ctx, 1), deleted, label, number, synced, tuple(items), comment)


def parse_block_uncached(text: str, file: str = "<string>", line: int = 1) -> Block:
    """Parse one line with lark as written, bypassing the shape cache (for tests, debugging)."""
    ctx = (file, line, text)
    try:
        tree = lark_parser().parse(text)
    except UnexpectedInput as exc:
        raise LineError(_diagnose(exc, ctx)) from None
    _check_depth(tree, ctx)
    block: Block = _compile(tree, text, split=False)((), _NO_RUNS, ctx)
    return block


_DIGIT_RUNS: Final = re.compile(r"(\d+)")
_SHAPES: dict[str, Builder] = {}
_SHAPES_MAX: Final = 100_000


def parse_block(text: str, file: str = "<string>", line: int = 1) -> Block:
    """Parse one line into a :class:`Block`; raise :class:`LineError` if it does not parse."""
    if len(text) > LONG_BLOCK:
        return _parse_as_written(text, (file, line, text))
    parts = _DIGIT_RUNS.split(text)
    shape = "0".join(parts[0::2])
    builder = _SHAPES.get(shape)
    if builder is None:
        builder = _learn(shape)
    runs = parts[1::2]
    lens = list(accumulate(map(len, runs), initial=0)) if runs else _NO_RUNS
    block: Block = builder(runs, lens, (file, line, text))
    return block


_NO_RUNS: Final = (0,)


def _learn(shape: str) -> Builder:
    try:
        tree = lark_parser().parse(shape)
    except UnexpectedInput:
        builder: Builder = _failed
    else:
        # Too deep: the line as written gives the diagnostic, at its own columns.
        builder = _failed if _too_deep(tree) else _compile(tree, shape, split=True)
    if len(_SHAPES) >= _SHAPES_MAX:
        _SHAPES.clear()
    _SHAPES[shape] = builder
    return builder


def _parse_as_written(text: str, ctx: _Ctx) -> Block:
    """Lark on the line as written (a long line, or one whose shape did not parse)."""
    try:
        tree = lark_parser().parse(text)
    except UnexpectedInput as exc:
        raise LineError(_diagnose(exc, ctx)) from None
    _check_depth(tree, ctx)
    return _build_direct(tree, ctx)


# ---- turning lark's errors into diagnostics ------------------------------------------------

_TERMINAL_NAMES: Final = {
    "RPAR": "')'", "LPAR": "'('", "COMMA": "','", "EQ": "'='", "HASH": "'#'", "GT": "'>'",
    "LT": "'<'", "PLUS": "'+'", "MINUS": "'-'", "STAR": "'*'", "SLASH": "'/'",
    "NAME": "a name", "INT": "a number", "NUMBER": "a number", "EPARAM": "an E parameter",
    "SYVAR": "SYVAR", "SAVAR": "an SA variable", "SKVAR": "an SK variable", "WORD": "a word",
    "NWORD": "an N number", "STRING": "a quoted text", "FUNC": "a function", "RAW": "a value",
    "COMMENT": "a comment", "$END": "the end of the block", "BCOND": "a branch code",
}
_LAST_VAR: Final = re.compile(r"(SYVAR\d*|S[AK]\d+(?:\.(?:BY|IN))?)\s*$", re.IGNORECASE)
_OPEN_CODE: Final = re.compile(r"\(\s*([A-Za-z]*)")


def _describe(terminal: str) -> str:
    return _TERMINAL_NAMES.get(terminal, terminal)


def _diagnose(exc: UnexpectedInput, ctx: _Ctx) -> Diagnostic:
    text = ctx[2]
    end_col = len(text.rstrip(" \t\r")) + 1
    if isinstance(exc, UnexpectedCharacters):
        col = exc.column if isinstance(exc.column, int) and exc.column > 0 else end_col
        char = exc.char
        if char == '"':
            code, message = DiagnosticCode.UNTERMINATED_STRING, "text without its closing '\"'"
        elif char.upper() in WORD_LETTERS and "WORD" in exc.allowed:
            code, message = DiagnosticCode.WORD_WITHOUT_VALUE, f"{char.upper()} needs a value"
        else:
            code, message = DiagnosticCode.UNEXPECTED_CHARACTER, f"unexpected character {char!r}"
        return Diagnostic(code, message, _span(ctx, col), text)
    assert isinstance(exc, UnexpectedToken)
    token = exc.token
    expected = set(exc.expected)
    at_end = token.type == "$END"
    col = end_col if at_end or not token.column else token.column
    value = str(token.value)
    if not at_end and value[:1].upper() in WORD_LETTERS and "WORD" in expected:
        # The root lexer took a letter with no value (GXY) for a name.
        return Diagnostic(DiagnosticCode.WORD_WITHOUT_VALUE, f"{value[0].upper()} needs a value",
                          _span(ctx, col), text)
    if not at_end and value.startswith('"') and value.count('"') == 1:
        return Diagnostic(DiagnosticCode.UNTERMINATED_STRING, "text without its closing '\"'",
                          _span(ctx, col), text)
    if "RPAR" in expected and (at_end or token.type == "COMMENT"):
        pos = col - 1
        opened = [m for m in _OPEN_CODE.finditer(text, 0, pos)]
        code_name = opened[-1].group(1).upper() if opened else ""
        return Diagnostic(DiagnosticCode.MISSING_CLOSE_PAREN,
                          f"expected ')' to close ({code_name}", _span(ctx, col), text)
    if {"EQ", "GT", "LT", "HASH"} <= expected:
        found = _LAST_VAR.search(text, 0, col - 1)
        if found:
            return Diagnostic(
                DiagnosticCode.MISSING_COMPARISON,
                f"a comparison (= > < #) is missing after {found.group(1).upper()}",
                _span(ctx, col), text,
            )
    before = text[:col - 1].rstrip(" \t")
    if not at_end and before[-1:] in ("=", "<", ">", "#") and value[:1] in ("=", "<", ">"):
        # >=, <=, <>, ==: a comparison of another language; the parser took its first
        # character and stumbles on the second.
        op = before[-1] + value[0]
        return Diagnostic(DiagnosticCode.UNEXPECTED_TOKEN,
                          f"'{op}' is no comparison of NC-110: it has = (equal), # (not "
                          "equal), > and <", _span(ctx, len(before)), text)
    shown = "the end of the block" if at_end else repr(str(token.value))
    wanted = ", ".join(sorted({_describe(t) for t in expected}))
    return Diagnostic(DiagnosticCode.UNEXPECTED_TOKEN, f"unexpected {shown}; expected {wanted}",
                      _span(ctx, col), text)


# ---- programs ------------------------------------------------------------------------------

_LOOKALIKE_CHARS: Final = "\u0410\u0412\u0415\u041a\u041c\u041d\u041e\u0420\u0421\u0422\u0425" \
    "\u0430\u0432\u0435\u043a\u043c\u043d\u043e\u0440\u0441\u0442\u0445"  # АВЕКМНОРСТХ, lower
_LOOKALIKES: Final = str.maketrans(_LOOKALIKE_CHARS, "ABEKMHOPCTXabekmhopctx")
_CYRILLIC: Final = re.compile(f"[{_LOOKALIKE_CHARS}]")
_LABELS: Final = re.compile(r'^[ \t]*(?:/[ \t]*)?"([^"\n]*)"', re.MULTILINE)
_PIECE: Final = 1 << 16  # characters of a text split or searched in one call


def _spans(text: str) -> Iterator[tuple[int, int]]:
    """``text`` in line-aligned pieces of about _PIECE characters: (start, end) each."""
    start, size = 0, len(text)
    while start < size:
        end = text.find("\n", min(start + _PIECE, size))
        end = size if end < 0 else end + 1
        yield start, end
        start = end


def _decoded_pieces(data: bytes) -> list[str]:
    """``data`` as UTF-8, in line-aligned pieces of about _PIECE bytes, decoded a piece at
    a time: one decode of a 10 MB file held the interpreter 6 ms, and joining pieces again 7
    ms, beside the fieldbus's threads."""
    if len(data) <= _PIECE:
        return [data.decode("utf-8")] if data else []
    decoder = codecs.getincrementaldecoder("utf-8")()
    view = memoryview(data)
    pieces: list[str] = []
    rest = ""
    for start in range(0, len(data), _PIECE):
        text = rest + decoder.decode(view[start:start + _PIECE])
        cut = text.rfind("\n") + 1  # the rest of a line goes on with the next piece
        if cut:
            pieces.append(text[:cut])
        rest = text[cut:]
    rest += decoder.decode(b"", final=True)
    if rest:
        pieces.append(rest)
    return pieces


def _lf_only(text: str) -> str:
    """``text`` with each CR LF and each lone CR made one LF (diagnostics.LINE_END), so that the
    splitting, the label scan and the line counts below see LF alone.  Piece by piece, a CR LF
    never cut in two: no one call into C holds the interpreter long on a long file."""
    pieces: list[str] = []
    start, size = 0, len(text)
    while start < size:
        end = min(start + _PIECE, size)
        if end < size and text[end - 1] == "\r" and text[end] == "\n":
            end += 1
        pieces.append(LINE_END.sub("\n", text[start:end]))
        start = end
    return "".join(pieces)


class Lines(Sequence[str]):
    """A program's lines: its text's line-aligned pieces (LF line ends) and where each line
    starts in its piece, one number a line -- not a string object a line.  A 10 MB
    program's 489,000 lines as strings were ~35 MB more, a list (then a tuple) the garbage
    collector walked, and one long call into C to make; here a line is cut from its piece
    when asked for.  ``lines[i] = text`` (the Cyrillic look-alikes read as Latin) keeps the
    new text beside the old."""

    __slots__ = ("_changed", "_count", "_pieces", "_starts", "first_lines")

    def __init__(self, pieces: Sequence[str]) -> None:
        self._pieces = list(pieces)
        # starts[k][j]: where piece k's line j starts; starts[k][j + 1] - 1: where it ends
        # (its newline, or the piece's end for a last line without one) -- made the first
        # time a line of the piece is asked for (a parse of the whole reads them in order).
        self._starts: list[array[int] | None] = [None] * len(self._pieces)
        self.first_lines: list[int] = []  # the index of each piece's first line
        count = 0
        for piece in self._pieces:
            self.first_lines.append(count)
            count += piece.count("\n") + (not piece.endswith("\n"))
        self._count = count
        self._changed: dict[int, str] = {}

    def _piece_starts(self, k: int) -> array[int]:
        starts = self._starts[k]
        if starts is None:
            plus_newline = (1).__add__
            starts = self._starts[k] = array("l", accumulate(
                map(plus_newline, map(len, self._piece_lines(k, False))), initial=0))
        return starts

    def __len__(self) -> int:
        return self._count

    @overload
    def __getitem__(self, index: int) -> str: ...

    @overload
    def __getitem__(self, index: slice) -> list[str]: ...

    def __getitem__(self, index: int | slice) -> str | list[str]:
        if isinstance(index, slice):
            start, stop, step = index.indices(len(self))
            if step != 1:
                return [self[i] for i in range(start, stop, step)]
            out: list[str] = []  # a piece split once for all its lines asked for
            k = bisect_right(self.first_lines, start) - 1
            while start < stop:
                lines, first = self._piece_lines(k), self.first_lines[k]
                out += lines[start - first:stop - first]
                start, k = first + len(lines), k + 1
            return out
        if index < 0:
            index += len(self)
        if self._changed and index in self._changed:
            return self._changed[index]
        if not 0 <= index < len(self):
            raise IndexError("line index out of range")
        k = bisect_right(self.first_lines, index) - 1
        starts, j = self._piece_starts(k), index - self.first_lines[k]
        return self._pieces[k][starts[j]:starts[j + 1] - 1]

    def __setitem__(self, index: int, text: str) -> None:
        if not 0 <= index < len(self):
            raise IndexError("line index out of range")
        self._changed[index] = text

    def __iter__(self) -> Iterator[str]:
        for k in range(len(self._pieces)):  # one split a piece (a whole parse reads them all)
            yield from self._piece_lines(k)

    def _piece_lines(self, k: int, changed: bool = True) -> list[str]:
        piece, first = self._pieces[k], self.first_lines[k]
        lines = piece.split("\n")
        if piece.endswith("\n"):
            lines.pop()
        for index, line in self._changed.items() if changed else ():
            if first <= index < first + len(lines):
                lines[index - first] = line
        return lines


class Program:
    """A program's text, parsed block by block on demand.

    ``labels`` maps an upper-cased label to the 0-based index of its line; it comes from a
    fast pre-scan, so a decoder can jump before the blocks in between were ever parsed.
    """

    __slots__ = ("_blocks", "exe_scan", "file", "label_lines", "labels", "lines", "name",
                 "notes")

    def __init__(self, name: str, file: str, text: str | list[str]) -> None:
        """``text``: the program's text, or its line-aligned pieces (each but the last
        ending in a newline: from_data)."""
        self.name = name
        self.file = file
        # The processes its EXEs name, and whether one is not a constant: read from the text
        # once (the compiler's exe_targets), where the program is read (off the loop).
        self.exe_scan: tuple[frozenset[int], bool, frozenset[tuple[int, str]]] | None = None
        # A long text is split, searched and kept a line-aligned piece at a time: no single
        # call into C holds the interpreter long while the loop serves the fieldbus beside
        # the thread that reads the program.
        pieces = [text[a:b] for a, b in _spans(text)] if isinstance(text, str) else text
        if pieces and pieces[0].startswith("\ufeff"):  # a UTF-8 byte-order mark
            pieces[0] = pieces[0][1:]
        pieces = [_lf_only(piece) if "\r" in piece else piece for piece in pieces]
        self.lines = lines = Lines(pieces)
        # Diagnostics of the file as a whole, found before any block is parsed.
        self.notes: list[Diagnostic] = []
        if any(_CYRILLIC.search(piece) for piece in pieces):
            self._latinise(lines)
        self.labels: dict[str, int] = {}
        self.label_lines: list[tuple[str, int]] = []  # every definition, duplicates too
        for piece, first in zip(pieces, lines.first_lines, strict=True):
            line_no, last = first, 0
            for m in _LABELS.finditer(piece):
                line_no += piece.count("\n", last, m.start())
                last = m.start()
                self.label_lines.append((m.group(1), line_no))
                # A jump's name had its look-alikes read as Latin: so has the label it names.
                self.labels.setdefault(m.group(1).upper().translate(_LOOKALIKES), line_no)
        # Every block of a short program, the last ones parsed of a long one (cache.py).
        self._blocks: list[Block | None] | BlockCache[Block] = block_table(len(self.lines))

    def _latinise(self, lines: Lines) -> None:
        """Read the Cyrillic look-alikes of address letters as their Latin twins, outside
        quotes and comments (operators type Е4 for E4), with a warning naming them."""
        for i, line in enumerate(lines):
            if not _CYRILLIC.search(line):
                continue
            out: list[str] = []
            found: list[tuple[int, str]] = []
            quoted = False
            for col, ch in enumerate(line, start=1):
                if ch == '"':
                    quoted = not quoted
                elif ch == ";" and not quoted:
                    out.append(line[col - 1:])
                    break
                elif not quoted and ch in _LOOKALIKE_CHARS:
                    found.append((col, ch))
                    ch = ch.translate(_LOOKALIKES)
                out.append(ch)
            if found:
                lines[i] = "".join(out)
                letters = ", ".join(sorted({f"{ch}\u2192{ch.translate(_LOOKALIKES)}"
                                            for _, ch in found}))
                self.notes.append(Diagnostic(
                    DiagnosticCode.CYRILLIC_LOOKALIKE,
                    f"Cyrillic letters read as their Latin twins: {letters}",
                    _new_tuple(Span, (self.file, i + 1, found[0][0])), line))

    @classmethod
    def from_path(cls, path: Path | str, display: str | None = None) -> Program:
        """Read a program file (UTF-8, with or without a byte-order mark).  A file that is not
        UTF-8 is a diagnostic at its first bad byte (NC015), with the file's name."""
        p = Path(path)
        return cls.from_data(p.read_bytes(), program_name(p),
                             display if display is not None else str(path))

    @classmethod
    def from_data(cls, data: bytes, name: str, display: str) -> Program:
        """A program file's bytes, as :meth:`from_path` reads them."""
        try:
            text = _decoded_pieces(data)
        except UnicodeDecodeError:
            try:  # again in one piece, for the error's position in the whole file
                data.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise ProgramSyntaxError([not_utf8(data, exc, display)]) from None
            raise
        return cls(name, display, text)

    def __len__(self) -> int:
        return len(self.lines)

    def block(self, index: int) -> Block:
        """The block on 0-based line ``index``; raises :class:`ProgramSyntaxError`."""
        block = self._blocks[index]
        if block is None:
            try:
                block = parse_block(self.lines[index], self.file, index + 1)
            except LineError as exc:
                raise ProgramSyntaxError([exc.diagnostic]) from None
            self._blocks[index] = block
        return block

    def parse_all(self) -> tuple[list[Block | None], list[Diagnostic]]:
        """Every block (None where a line does not parse) and every syntax diagnostic."""
        diagnostics: list[Diagnostic] = list(self.notes)
        kept = self._blocks
        # A long program's table keeps its last blocks only: the whole answer is a list.
        blocks: list[Block | None] = (kept if isinstance(kept, list)
                                      else [kept[i] for i in range(len(self.lines))])
        file = self.file
        with gc_paused():
            for i, text in enumerate(self.lines):
                if blocks[i] is None:
                    try:
                        blocks[i] = parse_block(text, file, i + 1)
                    except LineError as exc:
                        diagnostics.append(exc.diagnostic)
        return blocks, diagnostics
