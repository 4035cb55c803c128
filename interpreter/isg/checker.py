"""Check-time rules of the ISG dialect (spec 5.2-5.5), per program (section).

Syntax errors come from the parser; this adds what needs the configuration or the whole
program: channels and parameter indices in range, ``V.E.`` names declared in ``[nc.ve]`` and
not PLC-owned when written, ``V.P.`` variables read but never given a value, ``#WAIT SYN`` with
parameters, constant signal numbers and counts, the buffer-effect warning, a repeated address
or two codes of one modal group in a block, G codes the subset does not implement, and a
synchronous ``V.E.`` read under cutter compensation.  Must not import ``plc`` or ``gateway``.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Final

from ncgate.interpreter.codes import DiagnosticCode
from ncgate.interpreter.diagnostics import (
    Diagnostic,
    Span,
    WordUse,
    clash_message,
    did_you_mean,
    word_clashes,
)
from ncgate.interpreter.dialect import ExternalBinding
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
    Num,
    Param,
    Remove,
    SelfVar,
    Signal,
    Unary,
    WaitSignal,
    Word,
)
from ncgate.interpreter.isg.parser import IsgFile

# The subset's G codes (docs/isg.md) by modal group, and G40-G42: the control's tool radius
# compensation, which ncgate does not model (G41/G42 warn IW002; G40, which switches it off,
# needs no word) but whose state decides IS019.
_TRC_ON: Final = frozenset((41, 42))
G_GROUPS: Final[Mapping[float, str]] = {
    **dict.fromkeys((0, 1, 2, 3), "motion"),
    **dict.fromkeys((90, 91), "distance (G90/G91)"),
    **dict.fromkeys((40, 41, 42), "cutter compensation"),
}
G_IMPLEMENTED: Final = frozenset((0, 1, 2, 3, 90, 91))
M_GROUPS: Final[Mapping[float, str]] = {
    **dict.fromkeys((0, 1, 2, 30), "program stop and end"),
    **dict.fromkeys((3, 4, 5), "spindle"),
    6: "tool change",
}
WORD_GROUPS: Final[Mapping[str, Mapping[float, str]]] = {"G": G_GROUPS, "M": M_GROUPS}
_WORD_TEXT: Final = re.compile(r"[A-Za-z]\s*(?:\[[^\]]*\]?|[-+]?(?:V\.[A-Za-z]\.\w+|P\d+|[\d.]+))")


@dataclass(frozen=True, slots=True)
class IsgCheckContext:
    processes: int = 5
    e_params: int = 1000
    signal_params: int = 10
    external: Mapping[str, ExternalBinding] = field(default_factory=dict)


def check_file(source: IsgFile, context: IsgCheckContext,
               channel: int | None = None) -> list[Diagnostic]:
    """Every diagnostic of the file: syntax first, then each program's rules.  ``channel``:
    the one a file without sections runs in, when known (the main program's: 1)."""
    out = list(source.diagnostics)
    for section in source.sections:
        if not 1 <= section.channel <= context.processes:
            block = source.blocks[section.header]
            assert block is not None
            out.append(Diagnostic(DiagnosticCode.ISG_CHANNEL_OUT_OF_RANGE,
                                  f"%{section.name} runs in channel {section.channel}, but "
                                  f"nc.processes is {context.processes}", block.span,
                                  source.lines[section.header]))
    ranges: list[tuple[int, int, int | None]] = (
        [(s.header + 1, s.end, s.channel) for s in source.sections]
        or [(0, len(source.lines), channel)])
    for first, end, channel in ranges:
        out.extend(_Checker(source, context, channel).run(first, end))
    out.sort(key=lambda d: (d.span.line, d.span.column))
    return out


class _Checker:
    def __init__(self, source: IsgFile, context: IsgCheckContext, channel: int | None) -> None:
        self.source = source
        self.context = context
        self.channel = channel
        self.out: list[Diagnostic] = []

    def diag(self, code: DiagnosticCode, message: str, span: Span) -> None:
        self.out.append(Diagnostic(code, message, span, self.source.lines[span.line - 1]))

    def run(self, first: int, end: int) -> list[Diagnostic]:
        blocks = [b for b in self.source.blocks[first:end] if b is not None]
        given = self._given(blocks)
        buffered: dict[int, Span] = {}  # #SIGNAL SYN to this channel since the last #FLUSH
        # The G41/G42 that switched cutter compensation on, in the order the blocks are
        # written (a G40 switches it off); None while it is off.
        trc: Word | None = None
        for block in blocks:
            words: list[Word] = []
            for item in block.items:
                self._item(item, given)
                self._buffer(item, buffered)
                if isinstance(item, Word):
                    words.append(item)
            if trc is not None:
                self._sync_reads(block, trc)
            if words:
                trc = self._words(words, trc)
        return self.out

    def _words(self, words: list[Word], trc: Word | None) -> Word | None:
        """IW002, IS017, IS018 for a block's words; the cutter compensation after it."""
        uses: list[WordUse] = []
        for w in words:
            number = w.value.value if isinstance(w.value, Num) else None
            line = self.source.lines[w.span.line - 1]
            found = _WORD_TEXT.match(line, w.span.column - 1)
            uses.append(WordUse(w.letter, number, found.group() if found else w.letter, w.span))
            if number is None:
                continue
            if w.letter == "G" and number not in G_IMPLEMENTED and number != 40:
                what = ("cutter compensation is not modelled: the tool centre follows the "
                        "programmed contour" if number in _TRC_ON else
                        "not a G code of the subset (G00 G01 G02 G03 G90 G91): it has no effect")
                self.diag(DiagnosticCode.ISG_UNKNOWN_G_OR_M, f"{uses[-1].text}: {what}", w.span)
            elif w.letter == "M" and number != int(number):
                self.diag(DiagnosticCode.ISG_UNKNOWN_G_OR_M,
                          f"{uses[-1].text} is not an M code: M takes a whole number", w.span)
            if w.letter == "G" and number in _TRC_ON:
                trc = w
            elif w.letter == "G" and number == 40:
                trc = None
        for word, earlier, group in word_clashes(uses, WORD_GROUPS):
            code = (DiagnosticCode.ISG_REPEATED_WORD if group is None
                    else DiagnosticCode.ISG_MODAL_CONFLICT)
            self.diag(code, clash_message(word, earlier, group), word.span)
        return trc

    def _sync_reads(self, block: Block, trc: Word) -> None:
        """IS019: the control refuses a synchronous V.E. read (an implicit #FLUSH WAIT) while
        tool radius compensation is on (seed 004: error 20651) -- it cannot empty the buffer
        that compensation computes the path from.  Decided in the order the blocks are
        written: a G41/G42 above without a G40 between."""
        for item in block.items:
            for e in _expressions(item):
                for node in _walk(e):
                    if not isinstance(node, ExternalVar):
                        continue
                    binding = self.context.external.get(node.name)
                    if binding is not None and binding.sync:
                        number = trc.value.value if isinstance(trc.value, Num) else 41
                        self.diag(DiagnosticCode.ISG_SYNC_READ_IN_TRC,
                                  f"V.E.{node.name} is read synchronously while cutter "
                                  f"compensation is on (G{number:g} on line {trc.span.line}): "
                                  "the control stops with error 20651; read it before the "
                                  "G41/G42, after the G40, or make it sync = false", node.span)

    def _given(self, blocks: list[Block]) -> set[str]:
        """The V.P. names a program gives a value somewhere (assignment, #VAR, #WAIT)."""
        names: set[str] = set()
        for block in blocks:
            for item in block.items:
                if isinstance(item, Assign) and isinstance(item.target, SelfVar):
                    names.add(item.target.name)
                elif isinstance(item, Declare):
                    names.add(item.name)
                elif isinstance(item, WaitSignal):
                    names.update(t.name for _, t in item.params if isinstance(t, SelfVar))
        return names

    def _item(self, item: object, given: set[str]) -> None:
        for e in _expressions(item):
            self._reads(e, given)
        if isinstance(item, Assign):
            self._target(item.target, written=True)
        elif isinstance(item, Signal | WaitSignal | Remove):
            self._sync(item)

    def _reads(self, e: Expr, given: set[str]) -> None:
        for node in _walk(e):
            if isinstance(node, SelfVar) and node.name not in given:
                guess = did_you_mean(node.name, given) if given else None
                hint = f"; did you mean V.P.{guess}?" if guess else ""
                self.diag(DiagnosticCode.ISG_UNDECLARED_VARIABLE,
                          f"V.P.{node.name} is read, but the program never declares (#VAR) "
                          f"or assigns it{hint}", node.span)
            elif isinstance(node, ExternalVar | Param):
                self._target(node, written=False)

    def _target(self, target: object, written: bool) -> None:
        if isinstance(target, Param):
            if target.index >= self.context.e_params:
                self.diag(DiagnosticCode.ISG_PARAM_OUT_OF_RANGE,
                          f"P{target.index}: the channel has P0..P{self.context.e_params - 1} "
                          "(nc.e_params)", target.span)
        elif isinstance(target, ExternalVar):
            binding = self.context.external.get(target.name)
            if binding is None:
                names = list(self.context.external)
                guess = did_you_mean(target.name, names) if names else None
                hint = f"; did you mean V.E.{guess}?" if guess else ""
                declared = ", ".join(names) if names else "none"
                self.diag(DiagnosticCode.ISG_UNKNOWN_EXTERNAL,
                          f"V.E.{target.name} is not declared in [nc.ve] (declared: "
                          f"{declared}){hint}", target.span)
            elif written and binding.area in ("SA", "SK"):
                self.diag(DiagnosticCode.ISG_WRITE_PLC_OWNED,
                          f"V.E.{target.name} maps to {binding.text}, which the PLC owns: a "
                          "program may only read it", target.span)

    def _sync(self, item: Signal | WaitSignal | Remove) -> None:
        context = self.context
        for channel in item.channels:
            self._positive(channel, "CH")
            if isinstance(channel, Num) and channel.value == int(channel.value) and not (
                    1 <= channel.value <= context.processes):
                self.diag(DiagnosticCode.ISG_CHANNEL_OUT_OF_RANGE,
                          f"CH{int(channel.value)}: channels are 1..{context.processes} "
                          "(nc.processes)", channel.span)
        if isinstance(item, Remove):
            for bound, name in ((item.low, "ID"), (item.high, "IDMAX")):
                if bound is not None:
                    self._positive(bound, name)
            return
        self._positive(item.id, "ID")
        if isinstance(item, Signal):
            if item.count is not None:
                self._positive(item.count, "COUNT")
            indices = [(i, e.span) for i, e in item.params]
        else:
            indices = [(i, t.span) for i, t in item.params]
            for _, target in item.params:
                self._target(target, written=True)
            if item.syn and item.params:
                self.diag(DiagnosticCode.ISG_WAIT_SYN_PARAMS,
                          "#WAIT SYN cannot take parameters: they exist only for the decoder "
                          "(drop SYN, or the P[i]=…)", item.span)
        for i, span in indices:
            if i >= context.signal_params:
                self.diag(DiagnosticCode.ISG_PARAM_INDEX,
                          f"P[{i}]: a signal carries P[0]..P[{context.signal_params - 1}] "
                          "(nc.isg.signal_params)", span)

    def _positive(self, e: Expr, what: str) -> None:
        if isinstance(e, Num) and (e.value != int(e.value) or e.value < (1 if what in (
                "CH", "COUNT") else 0)):
            self.diag(DiagnosticCode.ISG_BAD_NUMBER,
                      f"{what}{e.value:g}: expected a whole number"
                      f"{' >= 1' if what in ('CH', 'COUNT') else ' >= 0'}", e.span)

    def _buffer(self, item: object, buffered: dict[int, Span]) -> None:
        """IW001: the seed's own-channel deadlock, seen before it runs."""
        me = self.channel
        if isinstance(item, Flush):
            buffered.clear()
        elif isinstance(item, Signal) and item.syn and isinstance(item.id, Num):
            to = {int(c.value) for c in item.channels if isinstance(c, Num)}
            if me is not None and me in to:
                buffered[int(item.id.value)] = item.span
        elif (isinstance(item, WaitSignal) and not item.syn and isinstance(item.id, Num)
              and me is not None):
            channels = {int(c.value) for c in item.channels if isinstance(c, Num)}
            signal = buffered.get(int(item.id.value))
            if signal is not None and me in channels:
                self.diag(DiagnosticCode.ISG_BUFFERED_SELF_SIGNAL,
                          f"this #WAIT waits for the #SIGNAL SYN of line {signal.line}, which "
                          "stays in the buffer while the decoder waits: add #FLUSH before the "
                          "#WAIT", item.span)


def _expressions(item: object) -> Iterator[Expr]:
    if isinstance(item, Assign):
        yield item.expr
    elif isinstance(item, Word):
        yield item.value
    elif isinstance(item, Signal):
        yield item.id
        if item.count is not None:
            yield item.count
        yield from (e for _, e in item.params)
        yield from item.channels
    elif isinstance(item, WaitSignal):
        yield item.id
        yield from item.channels
    elif isinstance(item, Remove):
        yield from (e for e in (item.low, item.high) if e is not None)
        yield from item.channels
    elif isinstance(item, Declare) and item.value is not None:
        yield item.value
    elif isinstance(item, Control) and item.condition is not None:
        yield item.condition


def _walk(e: Expr) -> Iterator[Expr]:
    yield e
    if isinstance(e, Unary):
        yield from _walk(e.operand)
    elif isinstance(e, Binary):
        yield from _walk(e.left)
        yield from _walk(e.right)
    elif isinstance(e, Call):
        yield from _walk(e.argument)
