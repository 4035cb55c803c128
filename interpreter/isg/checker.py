"""Check-time rules of the ISG dialect (spec 5.2-5.5), per program (section).

Syntax errors come from the parser; this adds what needs the configuration or the whole
program: channels and parameter indices in range, ``V.E.`` names declared in ``[nc.ve]`` and
not PLC-owned when written, ``V.P.`` variables read but never given a value, ``#WAIT SYN`` with
parameters, constant signal numbers and counts, and the buffer-effect warning.  Must not import
``plc`` or ``gateway``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

from ncgate.interpreter.codes import DiagnosticCode
from ncgate.interpreter.diagnostics import Diagnostic, Span, did_you_mean
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


@dataclass(frozen=True, slots=True)
class IsgCheckContext:
    processes: int = 5
    e_params: int = 1000
    signal_params: int = 10
    external: Mapping[str, ExternalBinding] = field(default_factory=dict)


def check_file(source: IsgFile, context: IsgCheckContext) -> list[Diagnostic]:
    """Every diagnostic of the file: syntax first, then each program's rules."""
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
        or [(0, len(source.lines), None)])
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
        for block in blocks:
            for item in block.items:
                self._item(item, given)
                self._buffer(item, buffered)
        return self.out

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
