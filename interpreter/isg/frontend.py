"""The ISG front end for the engine: a block becomes decoder ops (spec 5.2-5.5).

- Assignments, words and control flow act when the decoder reaches them; motion is queued.
- ``#SIGNAL``/``#WAIT`` act at the decoder; with ``SYN`` they are evaluated by the decoder and
  queued as one motion item that acts when the interpolator reaches it.
- ``#FLUSH`` (and a synchronous ``V.E.`` read, before its block) waits for the interpolator.
- A synchronous ``V.E.`` write is queued with the motion; an asynchronous one acts at once.
- The engine runs with ``buffered``: its interpolator takes a block only from a full buffer
  or once the decoder reaches the end, a flush or a synchronous read (the buffer effect).

The ops act only through :class:`~ncgate.interpreter.engine.ports.BlockHost`; the signals
live in :class:`~ncgate.interpreter.isg.signals.SignalBoard`.  Must not import ``plc`` or
``gateway``.
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Final

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import RuntimeAlarm, fmt_number
from ncgate.interpreter.dialect import ExternalBinding
from ncgate.interpreter.engine.actions import ItemKind, Step
from ncgate.interpreter.engine.aux import aux_items
from ncgate.interpreter.engine.ports import BlockHost, ProgramText
from ncgate.interpreter.engine.process import CompiledBlock, LoadedProgram, Op, Process, QueueItem
from ncgate.interpreter.engine.states import Stage, Where
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
    Target,
    Unary,
    WaitSignal,
    Word,
)
from ncgate.interpreter.isg.parser import IsgProgram, blank_comments
from ncgate.interpreter.isg.signals import AwaitSignal, RemoveSignals, SendSignal, SignalBoard
from ncgate.interpreter.motion import Modal, plan_move
from ncgate.interpreter.settings import AUX_LETTERS, RuntimeSettings

NEXT, WAIT_NEXT, JUMP, END = Step.NEXT, Step.WAIT_NEXT, Step.JUMP, Step.END
DECODER = Stage.DECODER
_AXES: Final = frozenset("XYZ")
_ARC: Final = frozenset("IJK")


@dataclass(frozen=True, slots=True)
class IsgOptions:
    max_events: int = 150
    signal_params: int = 10
    external: Mapping[str, ExternalBinding] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class WriteExternal:
    """A synchronous ``V.E.`` write, done when the interpolator reaches its block."""

    name: str
    binding: ExternalBinding
    value: int


class IsgFrontEnd:
    """The ISG dialect as the engine's :class:`~ncgate.interpreter.engine.ports.FrontEnd`.

    :meth:`attach` it to the engine before the first program starts: it registers the
    dialect's actions (signals, V.E. writes) and clears the stored signals on a reset."""

    def __init__(self, options: IsgOptions) -> None:
        self.options = options
        self.board: SignalBoard | None = None

    def attach(self, host: BlockHost, reset_listeners: list[Callable[[], None]]) -> SignalBoard:
        board = SignalBoard(host, self.options.max_events)
        self.board = board
        reset_listeners.append(board.clear)

        def write_external(p: Process, stage: Stage, action: WriteExternal,
                           where: Where) -> bool:
            b = action.binding
            host.write_image(p, b.area, b.index, b.view, action.value, where)
            return True
        host.register_action(WriteExternal, write_external)
        return board

    def compile_block(self, host: BlockHost, loaded: LoadedProgram,
                      index: int) -> CompiledBlock:
        program = loaded.program
        assert isinstance(program, IsgProgram)
        block = program.block(index) if index >= program.first else None
        if block is None or not block.items:
            return CompiledBlock((), (loaded.file, index + 1, None), False)
        where: Where = (loaded.file, index + 1, block.number)
        if self.board is None:
            raise RuntimeError("attach the ISG front end to its engine before a program starts")
        ops = _BlockCompiler(host, self.board, self.options, program, index, where).compile(
            block)
        return CompiledBlock(tuple(ops), where, True)

    def exe_targets(self, program: ProgramText) -> tuple[frozenset[int], bool]:
        return frozenset(), False  # an ISG program starts no other channel

    def exe_calls(self, program: ProgramText) -> frozenset[tuple[int, str]]:
        return frozenset()

    def block_search(self, program: ProgramText, at: str, modal: Modal, e_params: list[float],
                     settings: RuntimeSettings, read: Callable[[str, int, str], int],
                     with_calc: bool) -> tuple[int, Modal, list[float]]:
        raise ValueError("block search: the ISG dialect does not have it yet (start the "
                         "section from its beginning)")


class _BlockCompiler:
    def __init__(self, host: BlockHost, board: SignalBoard, options: IsgOptions,
                 program: IsgProgram, index: int, where: Where) -> None:
        self.host = host
        self.board = board
        self.options = options
        self.program = program
        self.index = index
        self.where = where
        self.sync_read = False  # the block reads a synchronous V.E.: flush first

    def compile(self, block: Block) -> list[Op]:
        ops: list[Op] = []
        body: list[Op] = []
        words: list[Word] = []
        for item in block.items:
            if isinstance(item, Assign):
                body.append(self._assign(item))
            elif isinstance(item, Word):
                words.append(item)
            else:
                body.extend(self._command(item))
        if words:
            body.append(self._motion(words))
            for w in words:
                if w.letter == "M" and isinstance(w.value, Num) and w.value.value in (30, 2):
                    body.append(self._end("M30" if w.value.value == 30 else "M02"))
                    break
                if w.letter == "M" and isinstance(w.value, Num) and w.value.value in (0, 1):
                    body.append(self._stop(optional=w.value.value == 1))
                    break
        if self.sync_read:  # spec 5.5: an implicit #FLUSH WAIT before the read
            flush_wait = self.host.flush_wait
            where = self.where

            def sync_read(p: Process) -> Step:
                return NEXT if flush_wait(p, where, "synchronous V.E. read") else WAIT_NEXT
            ops.append(sync_read)
        ops.extend(body)
        return ops

    def _stop(self, optional: bool) -> Op:
        """M00 / M01, as NC-110's: stop after this block until a cycle start."""
        program_stop = self.host.program_stop

        def stop(p: Process) -> Step:
            program_stop(p, optional)
            return NEXT
        return stop

    # ---- expressions ---------------------------------------------------------------------

    def expr(self, e: Expr) -> Callable[[Process], float]:
        if isinstance(e, Num):
            value = e.value
            return lambda p: value
        if isinstance(e, Param):
            i = e.index

            def param(p: Process) -> float:
                try:
                    return p.E[i]
                except IndexError:
                    raise _no_param(p, i) from None
            return param
        if isinstance(e, SelfVar):
            name = e.name

            def self_var(p: Process) -> float:
                try:
                    return p.vars[name]
                except KeyError:
                    raise RuntimeAlarm(AlarmCode.UNDEFINED_VARIABLE,
                                       f"V.P.{name} is read before it has a value") from None
            return self_var
        if isinstance(e, ExternalVar):
            binding = self.binding(e.name)
            if binding.sync:
                self.sync_read = True
            read = self.host.image.read
            area, index, view = binding.area, binding.index, binding.view
            return lambda p: float(read(area, index, view))
        if isinstance(e, Unary):
            inner = self.expr(e.operand)
            if e.op == "-":
                return lambda p: -inner(p)
            return lambda p: 0.0 if inner(p) else 1.0
        if isinstance(e, Call):
            arg = self.expr(e.argument)
            return _FUNCTIONS[e.function](arg)
        assert isinstance(e, Binary)
        left, right = self.expr(e.left), self.expr(e.right)
        return _binary(e.op, left, right)

    def binding(self, name: str) -> ExternalBinding:
        """A V.E. name's binding (the checker refuses an undeclared one before it runs)."""
        binding = self.options.external.get(name)
        if binding is None:
            raise RuntimeAlarm(AlarmCode.PROGRAM_INVALID, f"V.E.{name} is not in [nc.ve]")
        return binding

    def int_arg(self, e: Expr, what: str) -> Callable[[Process], int]:
        if isinstance(e, Num) and e.value == int(e.value):
            constant = int(e.value)
            return lambda p: constant
        fn = self.expr(e)

        def value(p: Process) -> int:
            v = fn(p)
            if v != int(v) or v < 0:
                raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT,
                                   f"{what} {fmt_number(v)} is not a whole number >= 0")
            return int(v)
        return value

    # ---- assignments -----------------------------------------------------------------------

    def _assign(self, item: Assign) -> Op:
        fn = self.expr(item.expr)
        store = self.store(item.target)
        where = self.where
        target = item.target
        if isinstance(target, ExternalVar):
            binding = self.binding(target.name)
            if binding.sync:  # spec 5.5: in motion order
                queue_motion = self.host.queue_motion
                name = target.name

                def write_sync(p: Process) -> Step:
                    if p.pending is not None:
                        return queue_motion(p, p.pending)
                    action = WriteExternal(name, binding, _whole(fn(p), f"V.E.{name}"))
                    return queue_motion(p, [QueueItem(ItemKind.SYNC, 0.0, where, None,
                                                      [action])])
                return write_sync

        def assign(p: Process) -> Step:
            store(p, fn(p), where)
            return NEXT
        return assign

    def store(self, target: Target) -> Callable[[Process, float, Where], None]:
        """How a value is put into a variable (an assignment, a #WAIT's parameter)."""
        if isinstance(target, Param):
            i = target.index

            def param(p: Process, value: float, where: Where) -> None:
                try:
                    p.E[i] = value
                except IndexError:
                    raise _no_param(p, i) from None
            return param
        if isinstance(target, SelfVar):
            name = target.name

            def self_var(p: Process, value: float, where: Where) -> None:
                p.vars[name] = value
            return self_var
        binding = self.binding(target.name)
        write_image = self.host.write_image
        name = target.name

        def external(p: Process, value: float, where: Where) -> None:
            write_image(p, binding.area, binding.index, binding.view,
                        _whole(value, f"V.E.{name}"), where)
        return external

    # ---- commands --------------------------------------------------------------------------

    def _command(self, item: object) -> list[Op]:
        host = self.host
        where = self.where
        if isinstance(item, Signal):
            return [self._signal(item)]
        if isinstance(item, WaitSignal):
            return [self._wait(item)]
        if isinstance(item, Remove):
            low = self.int_arg(item.low, "IDMIN") if item.low is not None else None
            high = self.int_arg(item.high, "IDMAX") if item.high is not None else None
            channels = [self.int_arg(c, "CH") for c in item.channels]
            perform = host.perform

            def remove(p: Process) -> Step:
                act = RemoveSignals(low(p) if low else None, high(p) if high else None,
                                    tuple(c(p) for c in channels))
                perform(p, DECODER, act, where)
                return NEXT
            return [remove]
        if isinstance(item, Flush):
            flush_wait = host.flush_wait

            def flush(p: Process) -> Step:
                return NEXT if flush_wait(p, where, "#FLUSH") else WAIT_NEXT
            return [flush]
        if isinstance(item, Declare):
            fn = self.expr(item.value) if item.value is not None else (lambda p: 0.0)
            name = item.name

            def declare(p: Process) -> Step:
                p.vars[name] = fn(p)
                return NEXT
            return [declare]
        if isinstance(item, Control):
            return [self._control(item)]
        return []  # %section, #VAR, #ENDVAR: nothing to do

    def _signal(self, item: Signal) -> Op:
        ident = self.int_arg(item.id, "ID")
        count = self.int_arg(item.count, "COUNT") if item.count is not None else None
        params = [(i, self.expr(e)) for i, e in item.params]
        channels = [self.int_arg(c, "CH") for c in item.channels]
        level = "syn" if item.syn else "dec"
        where = self.where
        check_channels = self.board.check_channels

        def make(p: Process | None) -> SendSignal:
            c = count(p) if count is not None else None  # type: ignore[arg-type]
            if c is not None and c < 1:
                raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"COUNT{c}: at least 1")
            to = tuple(dict.fromkeys(ch(p) for ch in channels))  # type: ignore[arg-type]
            check_channels(to, "#SIGNAL to")
            return SendSignal(ident(p), c,  # type: ignore[arg-type]
                              tuple((i, fn(p)) for i, fn in params),  # type: ignore[arg-type]
                              to, level)
        if item.syn:
            queue_motion = self.host.queue_motion

            def signal_syn(p: Process) -> Step:
                if p.pending is not None:
                    return queue_motion(p, p.pending)
                return queue_motion(p, [QueueItem(ItemKind.SYNC, 0.0, where, None, [make(p)])])
            return signal_syn
        send = self.board.send
        if _constant(item.id, item.count, *item.channels, *(e for _, e in item.params)):
            fixed = make(None)  # the same signal every time: built once

            def signal_fixed(p: Process) -> Step:
                send(p, DECODER, fixed, where)
                return NEXT
            return signal_fixed

        def signal(p: Process) -> Step:
            send(p, DECODER, make(p), where)
            return NEXT
        return signal

    def _wait(self, item: WaitSignal) -> Op:
        ident = self.int_arg(item.id, "ID")
        channels = [self.int_arg(c, "CH") for c in item.channels]
        stores = [(i, self.store(t)) for i, t in item.params]
        indices = tuple(i for i, _ in item.params)
        level = "syn" if item.syn else "dec"
        code = _code_text(self.program.lines[self.index])
        where = self.where

        def assign(p: Process, got: dict[int, float], at: Where) -> None:
            for i, put in stores:
                put(p, got[i], at)

        check_channels = self.board.check_channels

        def make(p: Process | None) -> AwaitSignal:
            chosen = tuple(ch(p) for ch in channels)  # type: ignore[arg-type]
            check_channels(chosen, "#WAIT for")
            return AwaitSignal(ident(p), chosen, indices, level, code,  # type: ignore[arg-type]
                               assign if stores else None)
        if item.syn:
            queue_motion = self.host.queue_motion

            def wait_syn(p: Process) -> Step:
                if p.pending is not None:
                    return queue_motion(p, p.pending)
                return queue_motion(p, [QueueItem(ItemKind.SYNC, 0.0, where, None, [make(p)])])
            return wait_syn
        wait_for = self.board.wait
        if _constant(item.id, *item.channels):
            fixed = make(None)

            def wait_fixed(p: Process) -> Step:
                return NEXT if wait_for(p, DECODER, fixed, where) else WAIT_NEXT
            return wait_fixed

        def wait(p: Process) -> Step:
            return NEXT if wait_for(p, DECODER, make(p), where) else WAIT_NEXT
        return wait

    def _control(self, item: Control) -> Op:
        partner = self.program.source.partner
        index = self.index
        if item.word in ("ENDIF",):
            return lambda p: NEXT
        if item.word == "ENDWHILE":
            back = partner[index]

            def loop(p: Process) -> Step:
                p.pc = back
                p.block = None
                return JUMP
            return loop
        after = partner[index] + 1
        if item.word == "ELSE":  # reached from the true branch: on after $ENDIF
            def skip(p: Process) -> Step:
                p.pc = after
                p.block = None
                return JUMP
            return skip
        assert item.condition is not None
        holds = self.expr(item.condition)

        def branch(p: Process) -> Step:  # $IF / $WHILE: on if it holds, else past its end
            if holds(p):
                return NEXT
            p.pc = after
            p.block = None
            return JUMP
        return branch

    # ---- motion and the end ----------------------------------------------------------------

    def _motion(self, words: list[Word]) -> Op:
        values = [(w.letter, self.expr(w.value)) for w in words]
        settings = self.host.settings
        queue_motion = self.host.queue_motion
        where = self.where

        def motion(p: Process) -> Step:
            if p.pending is not None:
                return queue_motion(p, p.pending)
            modal = p.modal
            axes: dict[str, float] = {}
            arc: dict[str, float] = {}
            aux: list[tuple[str, float]] = []  # M, S, T: for [nc.aux]
            for letter, fn in values:
                v = fn(p)
                if letter in AUX_LETTERS:
                    aux.append((letter, v))
                if letter == "G":
                    modal.g_word(int(v), planes=False)  # the subset has no G17..G19
                elif letter == "F":
                    modal.feed(v)
                elif letter in _AXES:
                    axes[letter] = v
                elif letter in _ARC:
                    arc[letter] = v
            move = plan_move(modal, axes, arc, settings)
            if not aux:
                if move is None:
                    return NEXT
                return queue_motion(p, [QueueItem(ItemKind.MOVE, move.duration_s, where,
                                                  move)])
            before, after = aux_items(settings.aux_interface, aux, where)
            items = [*before, QueueItem(ItemKind.MOVE, move.duration_s, where, move),
                     *after] if move is not None else [*before, *after]
            if not items:
                return NEXT
            return queue_motion(p, items)
        return motion

    def _end(self, how: str) -> Op:
        end_decoding = self.host.end_decoding
        where = self.where

        def end(p: Process) -> Step:
            end_decoding(p, how, where)
            return END
        return end


def _constant(*exprs: Expr | None) -> bool:
    return all(e is None or isinstance(e, Num) for e in exprs)


def _code_text(line: str) -> str:
    """A block as the why-record shows it: without its N number and comments."""
    text = re.sub(r"^\s*N\d+\s*", "", blank_comments(line)).strip()
    text = " ".join(text.split())
    return text[:60] if text else "#WAIT"


def _no_param(p: Process, i: int) -> RuntimeAlarm:
    return RuntimeAlarm(AlarmCode.INDEX_OUT_OF_RANGE, f"P{i}: the channel has P0..P{len(p.E) - 1}")


def _whole(value: float, name: str) -> int:
    if value != int(value):
        raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"{name} holds whole numbers, not {value:g}")
    return int(value)


def _binary(op: str, left: Callable[[Process], float],
            right: Callable[[Process], float]) -> Callable[[Process], float]:
    if op == "+":
        return lambda p: left(p) + right(p)
    if op == "-":
        return lambda p: left(p) - right(p)
    if op == "*":
        return lambda p: left(p) * right(p)
    if op == "/":
        def divide(p: Process) -> float:
            divisor = right(p)
            if divisor == 0:
                raise RuntimeAlarm(AlarmCode.DIVISION_BY_ZERO, "division by zero")
            return left(p) / divisor
        return divide
    if op == "AND":
        return lambda p: 1.0 if left(p) and right(p) else 0.0
    if op == "OR":
        return lambda p: 1.0 if left(p) or right(p) else 0.0
    compare = {"==": operator.eq, "!=": operator.ne, "<": operator.lt, "<=": operator.le,
               ">": operator.gt, ">=": operator.ge}[op]
    return lambda p: 1.0 if compare(left(p), right(p)) else 0.0


def _sqrt(arg: Callable[[Process], float]) -> Callable[[Process], float]:
    def root(p: Process) -> float:
        v = arg(p)
        if v < 0:
            raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, f"SQRT of {fmt_number(v)}")
        return math.sqrt(v)
    return root


_FUNCTIONS: Final[dict[str, Callable[[Callable[[Process], float]], Callable[[Process], float]]]] = {
    "ABS": lambda a: lambda p: abs(a(p)),
    "SQRT": _sqrt,
    "SIN": lambda a: lambda p: math.sin(math.radians(a(p))),
    "COS": lambda a: lambda p: math.cos(math.radians(a(p))),
}
