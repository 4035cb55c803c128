"""Check-time errors and warnings of a program (spec 1.3, 1.5, 1.6).

Everything here is decided from the text and the configuration alone: process numbers out of
range, a process waiting for (or starting, or sending to) itself where it is known which
process runs the program, ``>``/``<`` on a bit, unknown labels, unbalanced RPT/ERP, constant
indexes out of range, EXE of a program missing from its device, writes to SA/SK.  What only the
running program can know (E-parameter values) becomes a runtime alarm instead.

Must not import ``plc`` or ``gateway``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import ClassVar, Final

from ncgate.interpreter.batch import gc_paused
from ncgate.interpreter.codes import DiagnosticCode
from ncgate.interpreter.diagnostics import (
    Diagnostic,
    WordUse,
    clash_message,
    did_you_mean,
    word_clashes,
)
from ncgate.interpreter.nc110.nodes import (
    Assign,
    Binary,
    Block,
    Branch,
    Call,
    CompareOp,
    Display,
    Dwell,
    EndRepeat,
    Exe,
    Expr,
    InertCode,
    Jump,
    Num,
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
    value_object,
)
from ncgate.interpreter.nc110.parser import Program

# The G and M codes of the language (docs/language.md), by modal group as rs274ngc groups
# them: two of one group in a block is NC036.  G4, cutter compensation and the canned cycles
# are known but kept without effect (docs/decisions.md); a G code outside this table is NW005.
_MOTION = "motion"
G_GROUPS: Final[Mapping[float, str]] = {
    **dict.fromkeys((0, 1, 2, 3, *range(80, 90)), _MOTION),
    **dict.fromkeys((17, 18, 19), "plane"),
    **dict.fromkeys((90, 91), "distance (G90/G91)"),
    **dict.fromkeys((40, 41, 42), "cutter compensation"),
    4: "dwell",
}
# M codes are the machine's own functions, handed to the PLC on a real control (M100 is a
# machine builder's): any whole number is accepted.  These groups are the ones a control
# refuses to see twice in a block.
M_GROUPS: Final[Mapping[float, str]] = {
    **dict.fromkeys((0, 1, 2, 30), "program stop and end"),
    **dict.fromkeys((3, 4, 5), "spindle"),
    6: "tool change",
}
WORD_GROUPS: Final[Mapping[str, Mapping[float, str]]] = {"G": G_GROUPS, "M": M_GROUPS}


@value_object
class Limits:
    """Sizes of the variables (spec 1.3 defaults)."""

    e_params: int = 1000
    syvars: int = 256
    sa_bits: int = 1024
    k_bytes: int = 512

    @property
    def sa_bytes(self) -> int:
        return self.sa_bits // 8


def index_range(var: VarRef, limits: Limits) -> tuple[int, int]:
    """The valid first..last index of a variable of this kind and view."""
    if var.kind is VarKind.E:
        return 0, limits.e_params - 1
    if var.kind is VarKind.SYVAR:
        return 0, limits.syvars - 1
    size = limits.k_bytes if var.kind is VarKind.SK else limits.sa_bytes
    if var.view is View.BIT:
        return 0, limits.sa_bits - 1
    if var.view is View.INT16:
        return 0, size - 2  # the word takes bytes n and n+1
    return 0, size - 1


def value_range(view: View) -> tuple[float, float] | None:
    if view is View.BIT:
        return 0, 1
    if view is View.BYTE:
        return 0, 255
    if view is View.INT16:
        return -32768, 32767
    return None


@dataclass(frozen=True, slots=True)
class CheckContext:
    """What the checker knows about where the program will run."""

    processes: int = 5
    external: frozenset[int] = frozenset()
    runs_in: frozenset[int] = frozenset()  # processes that run this program; empty: unknown
    limits: Limits = field(default_factory=Limits)
    # name, device -> True/False when storage is known, None when it is not.
    find_program: Callable[[str, str | None], bool] | None = None
    has_device: Callable[[str | None], bool] | None = None


def check_program(program: Program, ctx: CheckContext) -> list[Diagnostic]:
    """Every syntax and check-time diagnostic of a program, in source order."""
    with gc_paused():
        blocks, diagnostics = program.parse_all()
        checker = _Checker(program, ctx, diagnostics)
        checker.check_blocks(blocks)
    diagnostics.sort(key=lambda d: (d.span.line, d.span.column))
    return diagnostics


class _Checker:
    def __init__(self, program: Program, ctx: CheckContext, out: list[Diagnostic]) -> None:
        self.program = program
        self.ctx = ctx
        self.out = out
        self.repeats: list[Repeat] = []
        self.label_names = [name for name, _ in program.label_lines]

    def report(self, code: DiagnosticCode, message: str, span: Span) -> None:
        self.out.append(Diagnostic(code, message, span, self.program.lines[span.line - 1]))

    def check_blocks(self, blocks: Iterable[Block | None]) -> None:
        seen: dict[str, int] = {}
        for name, index in self.program.label_lines:
            key = name.upper()
            if key in seen:
                line = self.program.lines[index]
                col = line.index('"') + 1
                self.report(DiagnosticCode.DUPLICATE_LABEL,
                            f'label "{name}" is already defined on line {seen[key] + 1}',
                            Span(self.program.file, index + 1, col))
            else:
                seen[key] = index
        dispatch = self._dispatch
        for block in blocks:
            if block is None:
                continue
            words = 0
            for item in block.items:
                kind = type(item)
                if kind is Word:  # most items: only an E parameter, F, G or M needs a look
                    words += 1
                    if type(item.value) is VarRef or item.letter in "FGM":  # type: ignore[union-attr]
                        self.word(item)  # type: ignore[arg-type]
                    continue
                handler = dispatch.get(kind)
                if handler is not None:
                    handler(self, item)
            if words > 1:
                # Only a letter that stands twice can clash (two G codes are two G's): the
                # common block, one word a letter, skips building the clash check's records.
                letters = [i.letter for i in block.items if type(i) is Word]
                if len(set(letters)) < len(letters):
                    self.block_words(block)
        for unclosed in self.repeats:
            self.report(DiagnosticCode.UNBALANCED_REPEAT, "(RPT) without a matching (ERP)",
                        unclosed.span)

    # -- variables and expressions ----------------------------------------------------------

    def var(self, var: VarRef) -> None:
        low, high = index_range(var, self.ctx.limits)
        if not low <= var.index <= high:
            kind = var.kind.value
            self.report(DiagnosticCode.INDEX_OUT_OF_RANGE,
                        f"{var.name} is out of range ({kind}{low}..{kind}{high})", var.span)
        if var.implicit_index:
            self.report(DiagnosticCode.SYVAR_WITHOUT_INDEX,
                        "SYVAR without an index reads SYVAR0", var.span)

    def expr(self, expr: Expr) -> None:
        if isinstance(expr, VarRef):
            self.var(expr)
        elif isinstance(expr, Binary):
            self.expr(expr.left)
            self.expr(expr.right)
        elif isinstance(expr, Unary):
            self.expr(expr.operand)
        elif isinstance(expr, Call):
            self.expr(expr.arg)

    def process_number(self, expr: Expr) -> int | None:
        """The constant process number, after checking its range; None for an E parameter."""
        if not isinstance(expr, Num):
            self.expr(expr)
            return None
        value = expr.value
        count = self.ctx.processes
        if value != int(value) or not 1 <= value <= count:
            shown = int(value) if value == int(value) else value
            self.report(DiagnosticCode.PROCESS_OUT_OF_RANGE,
                        f"process {shown} is not configured (1..{count})", expr.span)
            return None
        return int(value)

    # -- items --------------------------------------------------------------------------------

    def word(self, item: Word) -> None:
        value = item.value
        if isinstance(value, VarRef):
            self.var(value)
        elif item.letter == "F":
            if value <= 0:
                self.report(DiagnosticCode.FEED_NOT_POSITIVE,
                            f"F{item.text}: a feed must be positive (mm/min)", item.span)
        elif item.letter == "G" and value not in G_GROUPS:
            self.report(DiagnosticCode.UNKNOWN_G_OR_M,
                        f"G{item.text} is not a G code of the language: it has no effect "
                        "(known: G0 G1 G2 G3 G17 G18 G19 G90 G91; kept: G4 G40-G42 G80-G89)",
                        item.span)
        elif item.letter == "M" and value != int(value):
            self.report(DiagnosticCode.UNKNOWN_G_OR_M,
                        f"M{item.text} is not an M code: M takes a whole number",
                        item.span)

    def block_words(self, block: Block) -> None:
        """NC035/NC036: a repeated address, or two codes of one modal group (diagnostics.
        word_clashes); the second word's column."""
        uses = [WordUse(w.letter, w.value if type(w.value) is float else None,
                        f"{w.letter}{w.text}", w.span)
                for w in block.items if type(w) is Word]
        for word, earlier, group in word_clashes(uses, WORD_GROUPS):
            code = (DiagnosticCode.REPEATED_WORD if group is None
                    else DiagnosticCode.MODAL_CONFLICT)
            self.report(code, clash_message(word, earlier, group), word.span)

    def assign(self, item: Assign) -> None:
        target = item.target
        self.var(target)
        if target.kind in (VarKind.SA, VarKind.SK):
            self.report(DiagnosticCode.WRITE_TO_PLC_PACKET,
                        f"{target.name} belongs to the PLC: a program may read it, not write it",
                        target.span)
        self.expr(item.expr)

    def exe(self, item: Exe) -> None:
        n = self.process_number(item.process)
        if n is not None:
            if n in self.ctx.runs_in:
                self.report(DiagnosticCode.EXE_ON_SELF,
                            f"a process cannot start a program in itself (EXE,{n})",
                            item.process.span)
            elif n in self.ctx.external:
                self.report(DiagnosticCode.EXE_ON_EXTERNAL,
                            f"process {n} is external: it runs no part program",
                            item.process.span)
        if self.ctx.has_device is not None and not self.ctx.has_device(item.device):
            self.report(DiagnosticCode.UNKNOWN_DEVICE,
                        f"storage device {item.device} is not configured", item.span)
        elif self.ctx.find_program is not None and not self.ctx.find_program(
            item.program, item.device
        ):
            where = f" on {item.device}" if item.device else ""
            self.report(DiagnosticCode.PROGRAM_NOT_FOUND,
                        f"program {item.program} not found{where}", item.span)

    def wait_proc(self, item: WaitProc) -> None:
        n = self.process_number(item.process)
        if n is not None and n in self.ctx.runs_in:
            self.report(DiagnosticCode.WAIT_FOR_SELF, "a process cannot wait for itself",
                        item.process.span)

    def snd(self, item: Snd) -> None:
        n = self.process_number(item.process)
        if n is not None and n in self.ctx.runs_in:
            self.report(DiagnosticCode.SND_TO_SELF, "a process cannot send to itself",
                        item.process.span)

    def wait_cond(self, item: WaitCond) -> None:
        var = item.var
        self.var(var)
        self.expr(item.value)
        if var.view is View.BIT:
            if item.op in (CompareOp.GT, CompareOp.LT):
                self.report(DiagnosticCode.COMPARE_BIT_ORDER,
                            f"{var.name} is a bit, only = and # compare it", var.span)
            elif isinstance(item.value, Num) and item.value.value not in (0.0, 1.0):
                self.report(DiagnosticCode.BIT_VALUE,
                            f"{var.name} is a bit: compare it with 0 or 1", item.value.span)
            return
        bounds = value_range(var.view)
        if bounds and item.op is CompareOp.EQ and isinstance(item.value, Num):
            low, high = bounds
            if not low <= item.value.value <= high:
                self.report(DiagnosticCode.CONDITION_NEVER_HOLDS,
                            f"{var.name} holds {low:g}..{high:g}: {item.text} can never hold",
                            item.value.span)

    def jump_to(self, label: str, span: Span) -> None:
        if label.upper() not in self.program.labels:
            hint = did_you_mean(label, self.label_names)
            suffix = f' (did you mean "{hint}"?)' if hint else ""
            self.report(DiagnosticCode.UNKNOWN_LABEL,
                        f'label "{label}" is not defined{suffix}', span)

    def jump(self, item: Jump) -> None:
        self.jump_to(item.label, item.span)

    def branch(self, item: Branch) -> None:
        self.expr(item.left)
        self.expr(item.right)
        self.jump_to(item.label, item.span)

    def repeat(self, item: Repeat) -> None:
        self.expr(item.count)
        self.repeats.append(item)

    def end_repeat(self, item: EndRepeat) -> None:
        if self.repeats:
            self.repeats.pop()
        else:
            self.report(DiagnosticCode.UNBALANCED_REPEAT, "(ERP) without a matching (RPT)",
                        item.span)

    def dwell(self, item: Dwell) -> None:
        self.expr(item.seconds)

    def display(self, item: Display) -> None:
        for arg in item.args:
            self.expr(arg)

    def inert(self, item: InertCode) -> None:
        self.report(DiagnosticCode.UNMODELLED_CODE,
                    f"({item.code}) is not modelled by the simulator: kept, not executed",
                    item.span)

    _dispatch: ClassVar[dict[type, Callable[[_Checker, object], None]]] = {
        Word: word, Assign: assign, Exe: exe, WaitProc: wait_proc, Snd: snd,  # type: ignore[dict-item]
        WaitCond: wait_cond, Jump: jump, Branch: branch, Repeat: repeat,  # type: ignore[dict-item]
        EndRepeat: end_repeat, Dwell: dwell, Display: display, InertCode: inert,  # type: ignore[dict-item]
    }
