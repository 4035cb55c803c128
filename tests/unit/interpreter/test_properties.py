"""Property-based tests of the parser: random valid blocks parse to what they say and
round-trip through the formatter; random junk never crashes the parser."""

from __future__ import annotations

import dataclasses
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ncgate.interpreter.diagnostics import LineError
from ncgate.interpreter.nc110.formatter import format_block
from ncgate.interpreter.nc110.nodes import Span, VarRef, Word
from ncgate.interpreter.nc110.parser import WORD_LETTERS, parse_block, parse_block_uncached

SETTINGS = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])

spaces = st.sampled_from(["", "", " ", "  ", "\t"])
digits = st.integers(min_value=0, max_value=99999).map(str)


def cased(word: str) -> st.SearchStrategy[str]:
    return st.sampled_from([word.upper(), word.lower(), word.capitalize()])


@st.composite
def numbers(draw: st.DrawFn) -> tuple[str, float]:
    whole = draw(st.integers(min_value=0, max_value=9999))
    frac = draw(st.one_of(st.just(""), st.integers(min_value=0, max_value=999).map(str)))
    text = f"{whole}.{frac}" if frac else str(whole)
    return text, float(text)


@st.composite
def words(draw: st.DrawFn) -> tuple[str, tuple[str, Any]]:
    letter = draw(st.sampled_from(sorted(WORD_LETTERS)))
    if draw(st.booleans()):
        index = draw(st.integers(min_value=0, max_value=999))
        return f"{letter}E{index}", ("word", (letter, ("E", index)))
    sign = draw(st.sampled_from(["", "-", "+"]))
    text, value = draw(numbers())
    value = -value if sign == "-" else value
    return f"{draw(cased(letter))}{sign}{text}", ("word", (letter, value))


variables = st.one_of(
    st.integers(0, 999).map(lambda i: f"E{i}"),
    st.integers(0, 255).map(lambda i: f"SYVAR{i}"),
    st.integers(0, 1023).map(lambda i: f"SA{i}"),
    st.integers(0, 127).map(lambda i: f"SA{i}.BY"),
    st.integers(0, 511).map(lambda i: f"SK{i}"),
    st.integers(0, 510).map(lambda i: f"SK{i}.IN"),
)


def expressions() -> st.SearchStrategy[str]:
    leaf = st.one_of(numbers().map(lambda n: n[0]), variables)

    def extend(inner: st.SearchStrategy[str]) -> st.SearchStrategy[str]:
        return st.one_of(
            st.tuples(inner, st.sampled_from("+-*/"), inner).map(lambda t: f"{t[0]}{t[1]}{t[2]}"),
            inner.map(lambda e: f"({e})"),
            inner.map(lambda e: f"-{e}"),
            st.tuples(st.sampled_from(["SIN", "COS", "TAN", "ATN", "SQR", "ABS", "INT"]),
                      inner).map(lambda t: f"{t[0]}({t[1]})"),
        )

    return st.recursive(leaf, extend, max_leaves=6)


names = st.from_regex(r"[A-Z][A-Z0-9_]{0,7}", fullmatch=True).filter(
    lambda n: not n.startswith(("E", "SYVAR", "SA", "SK")) or n.isalpha())
procs = st.one_of(st.integers(1, 5).map(str), st.integers(0, 99).map(lambda i: f"E{i}"))


@st.composite
def codes(draw: st.DrawFn) -> tuple[str, tuple[str, Any]]:
    kind = draw(st.sampled_from(
        ["EXE", "REL", "WAIP", "WAIC", "SND", "BNC", "BRANCH", "RPT", "ERP", "DLY", "DIS", "ASSIGN",
         "INERT"]))
    sp = draw(spaces)
    if kind == "EXE":
        device = draw(st.sampled_from(["", "/MP0", "/MP2"]))
        text = f"(EXE,{sp}{draw(procs)},{draw(names)}{device})"
    elif kind == "REL":
        text = f"({draw(cased('REL'))})"
    elif kind == "WAIP":
        text = f"({draw(cased('WAI'))},{sp}{draw(procs)}{sp})"
    elif kind == "WAIC":
        var = draw(variables.filter(lambda v: not v.startswith("E")))
        op = draw(st.sampled_from("=#") if var.startswith("SA") and "." not in var
                  else st.sampled_from("=#<>"))
        value = draw(st.one_of(st.integers(-50, 255).map(str),
                               st.integers(0, 99).map(lambda i: f"E{i}")))
        text = f"(WAI,{var}{sp}{op}{sp}{value})"
    elif kind == "SND":
        text = f"(SND,{draw(procs)})"
    elif kind == "BNC":
        text = f"(BNC,{draw(names)})"
    elif kind == "BRANCH":
        op = draw(st.sampled_from(["BEQ", "BNE", "BGT", "BGE", "BLT", "BLE"]))
        text = f"({op},{draw(expressions())},{draw(expressions())},{draw(names)})"
    elif kind == "RPT":
        text = f"(RPT,{draw(expressions())})"
    elif kind == "ERP":
        text = "(ERP)"
    elif kind == "DLY":
        text = f"(DLY,{draw(expressions())})"
    elif kind == "DIS":
        args = "".join(f",{e}" for e in draw(st.lists(expressions(), max_size=3)))
        text = f'(DIS,"{draw(st.from_regex(r"[a-z ]{0,12}", fullmatch=True))}"{args})'
    elif kind == "ASSIGN":
        target = draw(st.one_of(st.integers(0, 999).map(lambda i: f"E{i}"),
                                st.integers(0, 255).map(lambda i: f"SYVAR{i}")))
        text = f"{target}{sp}={sp}{draw(expressions())}"
    else:
        code = draw(st.sampled_from(["UAO", "MIR", "UCG", "SCF"]))
        raw = draw(st.lists(st.from_regex(r"[A-Z0-9.]{1,5}", fullmatch=True), max_size=3))
        text = f"({code}{''.join(',' + r for r in raw)})"
    return text, ("code", kind)


@st.composite
def blocks(draw: st.DrawFn) -> tuple[str, list[tuple[str, Any]]]:
    prefix = ""
    if draw(st.booleans()):
        prefix += "/"
    if draw(st.integers(0, 4)) == 0:
        prefix += f'"{draw(names)}"'
    if draw(st.booleans()):
        prefix += f"N{draw(digits)}"
    if draw(st.integers(0, 3)) == 0:
        prefix += "#"
    items = draw(st.lists(st.one_of(words(), codes()), max_size=6))
    text = prefix
    for item_text, _ in items:
        # a word after a word or number needs no space, but a space is always allowed
        text += draw(spaces) + item_text
    if draw(st.booleans()):
        text += draw(spaces) + "; " + draw(st.from_regex(r"[ -~]{0,20}", fullmatch=True))
    return text, [expected for _, expected in items]


def without_spans(node: Any) -> Any:
    if isinstance(node, Span):
        return None
    if dataclasses.is_dataclass(node) and not isinstance(node, type):
        values = [without_spans(getattr(node, f.name)) for f in dataclasses.fields(node)
                  if f.name != "span"]
        return (type(node).__name__, *values)
    if isinstance(node, tuple):
        return tuple(without_spans(n) for n in node)
    return node




@SETTINGS
@given(blocks())
def test_random_valid_blocks_parse_to_what_they_say(case: tuple[str, list[Any]]) -> None:
    text, expected = case
    block = parse_block(text, "gen.nc", 1)
    assert len(block.items) == len(expected)
    for item, (kind, detail) in zip(block.items, expected, strict=True):
        if kind == "word":
            assert isinstance(item, Word)
            letter, value = detail
            assert item.letter == letter
            if isinstance(value, tuple):
                assert isinstance(item.value, VarRef) and item.value.index == value[1]
            else:
                assert item.value == value
        assert 1 <= item.span.column <= len(text)


@SETTINGS
@given(blocks())
def test_random_valid_blocks_round_trip_through_the_formatter(
    case: tuple[str, list[Any]],
) -> None:
    text, _ = case
    block = parse_block(text, "gen.nc", 1)
    canonical = format_block(block)
    again = parse_block(canonical, "gen.nc", 1)
    assert without_spans(again) == without_spans(block)
    assert format_block(again) == canonical


junk_alphabet = st.sampled_from(list('NGXYZEFSMT0123456789.,()=#<>+-*/"; \tABCDIJKLPQRUVW_&?'))


@SETTINGS
@given(st.lists(junk_alphabet, max_size=40).map("".join))
def test_random_junk_never_crashes_the_parser(text: str) -> None:
    try:
        parse_block(text, "junk.nc", 3)
    except LineError as exc:
        d = exc.diagnostic
        assert d.span.line == 3
        assert 1 <= d.span.column <= len(text) + 1
        assert d.code.code.startswith("NC")
        assert d.render().splitlines()[1] == "  " + text.replace("\t", " ")


@SETTINGS
@given(st.text(max_size=60))
def test_random_unicode_never_crashes_the_parser(text: str) -> None:
    text = text.replace("\n", " ")
    try:
        parse_block(text, "junk.nc", 1)
    except LineError as exc:
        assert 1 <= exc.diagnostic.span.column <= len(text) + 1


@settings(max_examples=500, deadline=None)
@given(expressions())
def test_random_expressions_round_trip_with_their_grouping(expr: str) -> None:
    block = parse_block(f"E1={expr}", "gen.nc", 1)
    canonical = format_block(block)
    again = parse_block(canonical, "gen.nc", 1)
    assert without_spans(again) == without_spans(block)


@SETTINGS
@given(blocks())
def test_shape_cache_builds_exactly_what_lark_builds_from_the_line(
    case: tuple[str, list[Any]],
) -> None:
    text, _ = case
    assert parse_block(text, "gen.nc", 9) == parse_block_uncached(text, "gen.nc", 9)
