"""The NC-110 front end for the engine: a block becomes decoder ops (spec 1.5, 2.4).

Items of one block run in a fixed order (spec 1.5, LinuxCNC-style): assignments, then WAI,
then motion and auxiliary words, then SND/EXE/REL/jumps/DIS in the order written.  A block
marked ``#`` is evaluated by the decoder (values, targets, positions) into typed actions and
queued as one motion item: its SYVAR writes, WAIs, SNDs and EXEs act when the interpolator
reaches it.  Jumps, repeats and the program's end stay with the decoder.

The ops act only through :class:`~ncgate.interpreter.engine.ports.BlockHost`.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from typing import Final

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import ProgramSyntaxError, RuntimeAlarm, fmt_number
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.actions import (
    Action,
    Execute,
    ItemKind,
    Motion,
    Send,
    ShowText,
    Step,
    WaitCondition,
    WaitProcess,
    WriteSyvar,
)
from ncgate.interpreter.engine.aux import aux_items
from ncgate.interpreter.engine.ports import BlockHost, ProgramText
from ncgate.interpreter.engine.process import CompiledBlock, LoadedProgram, Op, Process, QueueItem
from ncgate.interpreter.engine.states import Stage, Where
from ncgate.interpreter.motion import Modal, Move, check_duration, plan_move
from ncgate.interpreter.nc110.evaluate import (
    compile_expr,
    reads_image,
    round_half_away,
    syvars_read,
)
from ncgate.interpreter.nc110.formatter import format_item
from ncgate.interpreter.nc110.nodes import (
    RELATIONS,
    Assign,
    Block,
    Branch,
    Display,
    Dwell,
    EndRepeat,
    Exe,
    Expr,
    InertCode,
    Item,
    Jump,
    Num,
    Rel,
    Repeat,
    Snd,
    VarKind,
    WaitCond,
    WaitProc,
    Word,
)
from ncgate.interpreter.nc110.parser import Program
from ncgate.interpreter.nc110.search import search
from ncgate.interpreter.settings import AUX_LETTERS, AXES, RuntimeSettings

NEXT, WAIT_NEXT, JUMP, END = Step.NEXT, Step.WAIT_NEXT, Step.JUMP, Step.END
DECODER = Stage.DECODER
_NO_AUX: Final[tuple[list[QueueItem], list[QueueItem]]] = ([], [])  # (never appended to)
_MOTION_WORDS: Final = frozenset(AXES) | {"I", "J", "K", "R"}
_EXE_ARG: Final = re.compile(r"\(\s*EXE\s*,\s*([^,)\s]*)(?:\s*,\s*([^,)\s]*))?",
                             re.IGNORECASE)


def exe_scan(program: Program) -> tuple[frozenset[int], bool]:
    """The processes ``program``'s EXEs start and whether one is not a constant, from the
    text (a program parsed lazily must not be parsed whole for this); kept on the program,
    so that reading it (off the loop) does this once."""
    targets, dynamic, _ = _exe_scan(program)
    return targets, dynamic


def exe_calls(program: Program) -> frozenset[tuple[int, str]]:
    """The (process, program) pairs of ``program``'s EXEs with a constant process (the
    orphan-wait check follows them: a program that starts one that starts another)."""
    return _exe_scan(program)[2]


def _exe_scan(program: Program) -> tuple[frozenset[int], bool, frozenset[tuple[int, str]]]:
    if program.exe_scan is None:
        targets: set[int] = set()
        calls: set[tuple[int, str]] = set()
        dynamic = False
        lines = program.lines
        for first in range(0, len(lines), 2048):  # in pieces: no long call holds the GIL
            for m in _EXE_ARG.finditer("\n".join(lines[first:first + 2048])):
                if m.group(1).isdigit():
                    targets.add(int(m.group(1)))
                    if m.group(2):
                        calls.add((int(m.group(1)), m.group(2)))
                else:
                    dynamic = True
        program.exe_scan = (frozenset(targets), dynamic, frozenset(calls))
    return program.exe_scan


class NC110:
    """The NC-110 dialect as the engine's :class:`~ncgate.interpreter.engine.ports.FrontEnd`."""

    def compile_block(self, host: BlockHost, loaded: LoadedProgram,
                      index: int) -> CompiledBlock:
        program = loaded.program
        assert isinstance(program, Program)
        try:
            block = program.block(index)
        except ProgramSyntaxError as exc:  # only with lazy parsing: checked programs parse
            d = exc.diagnostics[0]
            raise RuntimeAlarm(AlarmCode.PROGRAM_INVALID,
                               f"{d.span}: {d.code.code}: {d.message}") from None
        where: Where = (loaded.file, index + 1, block.number)
        if block.deleted and host.block_skip:
            return CompiledBlock((), where, False)  # "/": skipped, not counted
        ops = _BlockCompiler(host, program, index, where).compile(block)
        return CompiledBlock(tuple(ops), where, bool(block.items) or block.number is not None)

    def exe_targets(self, program: ProgramText) -> tuple[frozenset[int], bool]:
        assert isinstance(program, Program)
        return exe_scan(program)

    def exe_calls(self, program: ProgramText) -> frozenset[tuple[int, str]]:
        assert isinstance(program, Program)
        return exe_calls(program)

    def block_search(self, program: ProgramText, at: str, modal: Modal, e_params: list[float],
                     settings: RuntimeSettings, read: Callable[[str, int, str], int],
                     with_calc: bool) -> tuple[int, Modal, list[float]]:
        assert isinstance(program, Program)
        return search(program, at, modal, e_params, settings, read, with_calc)

    def attach(self, host: BlockHost, reset_listeners: list[Callable[[], None]]) -> None:
        """NC-110 registers no actions of its own and keeps no state beside the engine's."""


class _BlockCompiler:
    """Turns one block into the decoder's ops (closures over the host)."""

    def __init__(self, host: BlockHost, program: Program, index: int, where: Where) -> None:
        self.host = host
        self.program = program
        self.index = index
        self.where = where
        self.read = host.image.read

    def compile(self, block: Block) -> list[Op]:
        items: tuple[Item, ...] = block.items
        # One pass, by exact type (the item classes have no subclasses): a block is compiled
        # each time it runs, and five filtering passes were a tenth of bench/runtime.py's
        # machining.
        assigns: list[Assign] = []
        waits: list[WaitProc | WaitCond] = []
        words: list[Word] = []
        dwells: list[Dwell] = []
        codes: list[Item] = []
        for item in items:
            kind = type(item)
            if kind is Word:
                words.append(item)  # type: ignore[arg-type]
            elif kind is Assign:
                assigns.append(item)  # type: ignore[arg-type]
            elif kind is WaitProc or kind is WaitCond:
                waits.append(item)  # type: ignore[arg-type]
            elif kind is Dwell:
                dwells.append(item)  # type: ignore[arg-type]
            elif kind is not InertCode:
                codes.append(item)
        ops: list[Op] = []
        if self.host.settings.sync_reads and self._reads_image(items):
            ops.append(self._sync_read_op())
        elif len(words) < len(items):  # words alone read no SYVAR at decode time
            ops.extend(self._own_write_reads(items, block.synced))
        if block.synced:
            ops.extend(self._assign_op(a) for a in assigns if a.target.kind is VarKind.E)
            ops.append(self._synced_op(assigns, waits, words, dwells, codes))
            ops.extend(self._code_op(c) for c in codes if isinstance(c, Jump | Branch | Repeat |
                                                                       EndRepeat | Rel))
            ops.extend(self._end_words(words))
            return ops
        ops.extend(self._assign_op(a) for a in assigns)
        ops.extend(self._wait_op(w) for w in waits)
        if words or dwells:
            ops.append(self._motion_op(words, dwells))
        ops.extend(self._code_op(c) for c in codes)
        ops.extend(self._end_words(words))
        return ops

    def _own_write_reads(self, items: tuple[Item, ...], synced: bool) -> list[Op]:
        """A hazard op for a block that reads, at decode time, a SYVAR that a # block above
        writes in motion order and has not written yet: the decoder reads the value from
        before that write (spec 2.4).  Legal, like a plain SND after motion, but rarely what
        was meant.  A # block's WAI condition is tested in motion order and is no such read;
        with nc.sync_reads the decoder waits for the motion first (the flush above)."""
        read: set[int] = set()
        for item in items:
            if type(item) is Word:
                continue  # a word's value is read when the motion is planned
            exprs = _decode_exprs(item)
            if isinstance(item, WaitCond):
                exprs = [item.value] if synced else [item.var, item.value]
            for expr in exprs:
                read.update(syvars_read(expr))
        if not read:
            return []
        indexes = frozenset(read)
        record = self.host.record
        where = self.where

        def own_write(p: Process) -> Step:
            for i, queued in enumerate(p.queue):
                pending = queued.actions
                if queued.kind is not ItemKind.SYNC or not pending:
                    continue
                for action in pending[p.sync_i:] if i == 0 else pending:
                    if type(action) is WriteSyvar and action.index in indexes:
                        _, line, n = queued.where
                        above = f"N{n}" if n is not None else f"line {line}"
                        record(ev.Hazard, p.number, where,
                               f"SYVAR{action.index} read at decode time while this process's "
                               f"# write of it ({above}) was still queued: it reads the value "
                               "from before that write; read it in a # block, or set "
                               "nc.sync_reads = true")
                        return NEXT
            return NEXT
        return [own_write]

    @staticmethod
    def _reads_image(items: tuple[Item, ...]) -> bool:
        return any(reads_image(e) for item in items for e in _decode_exprs(item))

    # ---- evaluation helpers (decode time) ---------------------------------------------

    def _int_arg(self, expr: Expr, what: str) -> Callable[[Process], int]:
        if isinstance(expr, Num) and expr.value == int(expr.value):
            constant = int(expr.value)
            return lambda p: constant
        fn = compile_expr(expr)
        read = self.read

        def value(p: Process) -> int:
            v = fn(p.E, read)
            if v != int(v):
                raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"{what} {v:g} is not a whole number")
            return int(v)

        return value

    # ---- assignments ---------------------------------------------------------------------

    def _assign_op(self, item: Assign) -> Op:
        fn = compile_expr(item.expr)
        read = self.read
        index = item.target.index
        if item.target.kind is VarKind.E:
            def assign_e(p: Process) -> Step:
                p.E[index] = fn(p.E, read)
                return NEXT
            return assign_e
        write_syvar = self.host.write_syvar
        where = self.where

        def assign_syvar(p: Process) -> Step:
            write_syvar(p, index, _int16(fn(p.E, read), f"SYVAR{index}"), where)
            return NEXT
        return assign_syvar

    # ---- waits ---------------------------------------------------------------------------

    def _wait_action(self, item: WaitProc | WaitCond) -> Callable[[Process], Action]:
        code = format_item(item)
        if isinstance(item, WaitProc):
            n = self._int_arg(item.process, "process number")
            return lambda p: WaitProcess(n(p), code)
        var = item.var
        fn = compile_expr(item.value)
        read = self.read
        area, index, view = var.kind.value, var.index, var.view.value
        op = item.op

        def cond(p: Process) -> Action:
            value = fn(p.E, read)
            text = f"{var.name}{op.value}{fmt_number(value)}"
            if value != int(value):
                # An integer variable never equals a fraction: compare as the spec's types do.
                raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT,
                                   f"(WAI,{text}): {var.name} holds whole numbers")
            return WaitCondition(area, index, view, op.against(int(value)), text)
        return cond

    def _exchange_op(self, item: WaitProc | Snd,
                     method: Callable[[Process, Stage, int, str, Where], bool]) -> Op:
        """(WAI,n) and (SND,n): the hot path of a SND/WAI exchange, no action object and no
        dispatch between the op and the engine."""
        n = self._int_arg(item.process, "process number")
        code = format_item(item)
        where = self.where

        def exchange(p: Process) -> Step:
            return NEXT if method(p, DECODER, n(p), code, where) else WAIT_NEXT
        return exchange

    def _action_op(self, make: Callable[[Process], Action]) -> Op:
        perform = self.host.perform
        where = self.where

        def act(p: Process) -> Step:
            return NEXT if perform(p, DECODER, make(p), where) else WAIT_NEXT
        return act

    def _wait_op(self, item: WaitProc | WaitCond) -> Op:
        if isinstance(item, WaitProc):
            return self._exchange_op(item, self.host.wait_process)
        return self._action_op(self._wait_action(item))

    # ---- motion --------------------------------------------------------------------------

    def _plan(self, p: Process, words: list[Word], dwells: list[Dwell]) -> list[QueueItem]:
        settings = self.host.settings
        read = self.read
        modal = p.modal
        axes: dict[str, float] = {}
        arc: dict[str, float] = {}
        items: list[QueueItem] = []
        tool_change = False
        aux: list[tuple[str, float]] = []  # the auxiliary words, for [nc.aux]
        for word in words:
            value = word.value
            v = p.E[value.index] if not isinstance(value, float) else value
            letter = word.letter
            if letter in AUX_LETTERS:
                aux.append((letter, v))
            if letter == "G":
                modal.g_word(int(v))
            elif letter == "F":
                modal.feed(v)
            elif letter == "T":
                modal.tool = word.text
            elif letter == "M" and int(v) == 6:
                tool_change = True
            elif letter in _MOTION_WORDS:
                (arc if letter in "IJKR" else axes)[letter] = v
        where = self.where
        before, after = aux_items(settings.aux_interface, aux, where) if aux else _NO_AUX
        items.extend(before)
        if tool_change:
            items.append(QueueItem(ItemKind.TOOL, settings.tool_change_s, where))
        move = plan_move(modal, axes, arc, settings)
        if move is not None:
            items.append(QueueItem(ItemKind.MOVE, move.duration_s, where, move))
        for dwell in dwells:
            seconds = compile_expr(dwell.seconds)(p.E, read)
            if seconds < 0:
                raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"(DLY,{seconds:g}): negative time")
            check_duration(seconds, settings, f"(DLY,{fmt_number(seconds)})")
            items.append(QueueItem(ItemKind.DWELL, seconds, where))
        items.extend(after)
        return items

    def _motion_op(self, words: list[Word], dwells: list[Dwell]) -> Op:
        queue_motion = self.host.queue_motion

        def motion(p: Process) -> Step:
            if p.pending is None:
                return queue_motion(p, self._plan(p, words, dwells))
            return queue_motion(p, p.pending)
        return motion

    def _end_words(self, words: list[Word]) -> list[Op]:
        for word in words:
            if word.letter == "M" and isinstance(word.value, float) and word.value in (30, 2):
                how = "M30" if word.value == 30 else "M02"
                return [self._end_op(how)]
            if word.letter == "M" and isinstance(word.value, float) and word.value in (0, 1):
                return [self._stop_op(optional=word.value == 1)]
        return []

    def _stop_op(self, optional: bool) -> Op:
        """M00 / M01: the program stops after this block (its motion done) until a cycle
        start; M01 only while the optional-stop switch is on."""
        program_stop = self.host.program_stop

        def stop(p: Process) -> Step:
            program_stop(p, optional)
            return NEXT
        return stop

    def _end_op(self, how: str) -> Op:
        end_decoding = self.host.end_decoding
        where = self.where

        def end(p: Process) -> Step:
            end_decoding(p, how, where)
            return END
        return end

    # ---- a # block: evaluated now, acting in motion order ---------------------------------

    def _synced_op(self, assigns: list[Assign], waits: list[WaitProc | WaitCond],
                   words: list[Word], dwells: list[Dwell], codes: Sequence[Item]) -> Op:
        queue_motion = self.host.queue_motion
        read = self.read
        syvars = [(a.target.index, compile_expr(a.expr)) for a in assigns
                  if a.target.kind is VarKind.SYVAR]
        wait_actions = [self._wait_action(w) for w in waits]
        code_actions = [self._code_action(c) for c in codes
                        if isinstance(c, Snd | Exe | Display)]
        where = self.where

        def synced(p: Process) -> Step:
            if p.pending is not None:
                return queue_motion(p, p.pending)
            actions: list[Action] = [
                WriteSyvar(i, _int16(fn(p.E, read), f"SYVAR{i}")) for i, fn in syvars]
            actions.extend(make(p) for make in wait_actions)
            for item in self._plan(p, words, dwells):
                if item.kind is ItemKind.AUX:  # auxiliary functions: in motion order too
                    actions.extend(item.actions or ())  # type: ignore[arg-type]
                elif item.move is not None:
                    actions.append(Motion(item.move))
                else:  # tool change or dwell inside a # block: a timed move of no length
                    here = tuple(p.modal.position)
                    actions.append(Motion(Move(here, here, 0.0, item.duration)))
            actions.extend(make(p) for make in code_actions)
            return queue_motion(p, [QueueItem(ItemKind.SYNC, 0.0, where, None, actions)])
        return synced

    # ---- codes ---------------------------------------------------------------------------

    def _code_action(self, item: Item) -> Callable[[Process], Action]:
        code = format_item(item)
        if isinstance(item, Snd):
            n = self._int_arg(item.process, "process number")
            return lambda p: Send(n(p), code)
        if isinstance(item, Exe):
            n = self._int_arg(item.process, "process number")
            name, device = item.program, item.device
            return lambda p: Execute(n(p), name, device, code)
        assert isinstance(item, Display)
        fns = [compile_expr(a) for a in item.args]
        read = self.read
        text = item.text

        def display(p: Process) -> Action:
            values = " ".join(fmt_number(fn(p.E, read)) for fn in fns)
            return ShowText(f"{text} {values}" if values else text)
        return display

    def _code_op(self, item: Item) -> Op:
        if isinstance(item, Snd):
            return self._exchange_op(item, self.host.send)
        if isinstance(item, Exe):
            return self._early_exe(item, self._action_op(self._code_action(item)))
        if isinstance(item, Display):
            return self._action_op(self._code_action(item))
        if isinstance(item, Rel):
            return self._end_op("REL")
        if isinstance(item, Jump | Branch):
            return self._jump_op(item)
        if isinstance(item, Repeat):
            return self._repeat_op(item)
        assert isinstance(item, EndRepeat)

        def end_repeat(p: Process) -> Step:
            if not p.repeats:
                raise RuntimeAlarm(AlarmCode.REPEAT_MISMATCH, "(ERP) without a matching (RPT)")
            frame = p.repeats[-1]
            frame[1] -= 1
            if frame[1] > 0:
                p.pc = frame[0] + 1
                p.block = None
                return JUMP
            p.repeats.pop()
            return NEXT
        return end_repeat

    def _sync_read_op(self) -> Op:
        """nc.sync_reads: a block that reads the image first waits for the motion queued
        before it -- a FLUSH wait, traced (wait, resume) and shown like ISG's #FLUSH."""
        flush_wait = self.host.flush_wait
        where = self.where

        def sync_read(p: Process) -> Step:
            return NEXT if flush_wait(p, where, "(sync read)") else WAIT_NEXT
        return sync_read

    def _early_exe(self, item: Exe, act: Op) -> Op:
        """A plain (not #) EXE acts when the decoder reaches it (spec 2.4), as a plain SND,
        WAI or SYVAR write does: with motion above it still queued, the program starts
        before that motion ends -- the engine's hazard for those (``acts_early``)."""
        acts_early = self.host.acts_early
        where = self.where
        code = format_item(item)

        def exe(p: Process) -> Step:
            if p.queue:
                acts_early(p, code, where)
            return act(p)
        return exe

    def _jump_op(self, item: Jump | Branch) -> Op:
        target = self.program.labels.get(item.label.upper())
        label = item.label
        read = self.read

        def jump(p: Process) -> Step:
            if target is None:
                raise RuntimeAlarm(AlarmCode.UNKNOWN_LABEL, f'label "{label}" is not defined')
            # A jump out of an RPT body ends that repeat: its frame goes (a loop that jumps
            # back to its RPT would otherwise stack a frame a turn, without bound).
            repeats = p.repeats
            while repeats and not repeats[-1][0] < target <= repeats[-1][2]:
                repeats.pop()
            p.pc = target
            p.block = None
            return JUMP

        if isinstance(item, Jump):
            return jump
        left, right = compile_expr(item.left), compile_expr(item.right)
        holds = RELATIONS[item.op.name]

        def branch(p: Process) -> Step:
            if holds(left(p.E, read), right(p.E, read)):
                return jump(p)
            return NEXT
        return branch

    def _repeat_op(self, item: Repeat) -> Op:
        count = self._int_arg(item.count, "repeat count")
        index = self.index
        program = self.program

        erp: list[int] = []  # the matching ERP's line index, found once

        def repeat(p: Process) -> Step:
            n = count(p)
            if n < 0:
                raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"(RPT,{n}): a negative count")
            if not erp:
                erp.append(_matching_erp(program, index))
            if n == 0:  # repeated no time: on after the matching (ERP)
                p.pc = erp[0] + 1
                p.block = None
                return JUMP
            p.repeats.append([index, n, erp[0]])
            return NEXT
        return repeat


def _decode_exprs(item: Item) -> list[Expr]:
    """The expressions a block's item has the decoder evaluate (a WAI's condition apart)."""
    if isinstance(item, Assign):
        return [item.expr]
    if isinstance(item, Branch):
        return [item.left, item.right]
    if isinstance(item, Repeat):
        return [item.count]
    if isinstance(item, Dwell):
        return [item.seconds]
    if isinstance(item, Display):
        return list(item.args)
    return []


def _matching_erp(program: Program, index: int) -> int:
    """The line of the (ERP) that closes the (RPT) on line ``index`` (nesting counted)."""
    depth = 0
    for i in range(index + 1, len(program)):
        for item in program.block(i).items:
            if isinstance(item, Repeat):
                depth += 1
            elif isinstance(item, EndRepeat):
                if depth == 0:
                    return i
                depth -= 1
    raise RuntimeAlarm(AlarmCode.REPEAT_MISMATCH, "(RPT) without a matching (ERP)")


def _int16(value: float, name: str) -> int:
    stored = round_half_away(value)
    if not -32768 <= stored <= 32767:
        # The rounded value is what is out of range (32767.5 rounds to 32768): say so, with
        # what the program gave when it was not already whole.
        given = "" if stored == value else f" ({value:g} rounded)"
        raise RuntimeAlarm(AlarmCode.VALUE_OUT_OF_RANGE,
                           f"{name} holds -32768..32767, not {stored}{given}")
    return stored
