"""The one door into the cell: validates a typed input (:mod:`ncgate.inputs`), records it,
then applies it to the engine and the image.

Every adapter reaches the engine through here -- Modbus, CANopen, the console and a Python
program through :meth:`ncgate.gateway.Gateway.apply` (which adds the wall clock), the PLC
logic's NC outputs, the sim script and a replayed record directly, on the virtual clock.
``tests/test_door.py`` lists the call sites and fails when another way in appears.

The order is the contract:

1. **validate** everything (the variable inside the image, the value in range, the process
   able to take it, the program found and checked): a refusal raises
   :class:`~ncgate.errors.InputRefused` and nothing of the input is applied or recorded;
2. bring the engine to the input's time (``sync``: the wall clock in ``run``);
3. **record** it (``run --record``): the record's input line comes before every trace event
   it causes, so a record cut anywhere never holds an effect without its cause.  Inputs of
   the PLC logic are not recorded: a replay runs the same logic, which gives them again;
4. **apply** it, attributed to ``str(input.source)``.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable
from typing import TYPE_CHECKING, Final, TypeVar, assert_never

from ncgate import commands
from ncgate.errors import InputRefused, Reason
from ncgate.inputs import (
    FEED_OVERRIDE_MAX,
    RAPID_OVERRIDE_MAX,
    Break,
    ClearFault,
    Command,
    CommandKind,
    Fault,
    FieldbusAlarm,
    Force,
    Input,
    Override,
    PlcVar,
    Snd,
    Source,
    SourceKind,
    Start,
    Var,
    Write,
    Writes,
)
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import ProgramError, ProgramNotFoundError
from ncgate.interpreter.engine.breaks import MAX_BREAKPOINTS, parse_breakpoint
from ncgate.plc.image import ImageAddressError, ImageValueError

if TYPE_CHECKING:
    from ncgate.gateway.wiring import Runtime
    from ncgate.plc.scan import PlcRuntime

# The record's writer: (input, machine time, first -- applied before the timers of its
# instant: ``Door.apply_first``).
Recorder = Callable[[Input, float, bool], None]
E = TypeVar("E", bound=enum.IntEnum)


def _member(kind: type[E], value: object) -> E | None:
    """``value`` as a member of the int enum ``kind``: an int or a member, never a bool or a
    float that happens to equal one; None when it is none of them."""
    if type(value) is not int and type(value) is not kind:
        return None
    try:
        return kind(value)
    except ValueError:
        return None


_KINDS_SAID: Final = commands.summary(tuple(k.spec for k in CommandKind))


def command_kind(value: object) -> CommandKind:
    """A command word of a CommandKind (ncgate.commands: 1 cycle start, ...); InputRefused
    otherwise."""
    kind = _member(CommandKind, value)
    if kind is None:
        raise InputRefused(Reason.BAD_VALUE, f"command {value!r}: {_KINDS_SAID}")
    return kind


# Command words past the CommandKinds: they carry an N number written beside them (Modbus
# holding command+3, CANopen 0x2400:4), and become other inputs.
SEARCH_WORDS: Final = {c.word: c.title for c in commands.COMMANDS if c.with_n}
_BLOCK_SEARCH: Final = commands.BY_NAME["block_search"].word
_BREAKPOINT: Final = commands.BY_NAME["breakpoint"].word


def search_inputs(word: int, n: int, runtime: Runtime, source: Source) -> list[Input] | None:
    """The inputs of the command words with an N number (None: another word): a block search
    starts the process's main (the high byte's; 0: process 1's nc.main) at N``n``, a
    breakpoint is set at N``n`` (of that process, or any), the third clears every
    breakpoint."""
    low, process = word & 0xFF, word >> 8
    if low not in SEARCH_WORDS:
        return None
    if process and process not in runtime.engine.processes:
        raise InputRefused(Reason.UNKNOWN_PROCESS, f"no process {process} (1.."
                           f"{len(runtime.engine.processes)})")
    if low == _BLOCK_SEARCH:
        k = process or 1
        main = runtime.engine.main_of(k)
        if not main:
            raise InputRefused(Reason.NOT_CONFIGURED, f"process {k} has no main program "
                               "([[nc.process]] main)")
        return [Start(main, k, source, f"N{n}")]
    if low == _BREAKPOINT:
        return [Break(f"P{process} N{n}" if process else f"N{n}", True, source)]
    return [Break(b.text, False, source) for b in runtime.engine.breakpoints]


def only_releases_hold(runtime: Runtime, item: Command) -> str | None:
    """What to tell whoever gave ``item`` when it is a cycle start that only releases a feed
    hold (an interlock's, which holds an idle cell too) while the process it would start
    is idle: it starts nothing, and a second cycle start starts the program
    (docs/interfacing-a-plc.md).  None: any other command, or a cycle start that starts."""
    if item.kind is not CommandKind.CYCLE_START:
        return None
    engine = runtime.engine
    number = 1 if item.process is None else item.process
    p = engine.processes.get(number)
    targets = engine.processes.values() if item.process is None else (p,) if p else ()
    if p is None or not any(t.held for t in targets) or p.external or p.loaded is not None:
        return None
    main = engine.main_of(number)
    then = f": a second cycle start starts {main}" if main and p.alarm is None else ""
    return f"released the feed hold; P{number} is idle and nothing started{then}"


ImageChange = tuple[str, int, str, int]
# Forced variables, the image's and the PLC logic's together: each forced PLC variable is set
# twice a scan, and 9,600 of them took a scan to 41 ms at scan_ms 10 (docs/decisions.md).
MAX_FORCED: Final = 256
# Commands only the cell takes (a process in them is refused).
_CELL_ONLY: Final = frozenset(k for k in CommandKind if k.spec.cell_only)
# The operator's switches of the cell, as commands: Engine.switch's keywords.  (Single block
# is one process's too: Engine.single_block.)
_SWITCHES: Final[dict[CommandKind, dict[str, bool]]] = {
    k: {k.spec.switch: k.spec.on} for k in _CELL_ONLY if k.spec.switch is not None}


# Inputs a replay gives again by itself: the PLC logic's and the plant's (same config, same
# logic, same clock).
_NOT_RECORDED: Final = frozenset({SourceKind.PLC, SourceKind.PLANT})


class Door:
    """Applies inputs to one runtime (``run``'s, a ``sim``'s or a replay's)."""

    def __init__(self, runtime: Runtime, plc: Callable[[], PlcRuntime | None] = lambda: None,
                 sync: Callable[[], None] | None = None) -> None:
        """``plc``: the PLC logic a reset restarts after a FAULT (asked at each reset);
        ``sync``: brings the engine's clock to now before an input acts (the wall clock)."""
        self.runtime = runtime
        self._plc = plc
        self._sync = sync
        self.recorder: Recorder | None = None  # run --record: told before the effect
        self._first = False  # (apply_first)
        # The online change of the PLC logic (gateway.plc.OnlineChange), given the source.
        self.reload_plc: Callable[[str], object] | None = None
        self._hold_input = next((var for what, var in runtime.interlocks
                                 if what == "feed hold"), None)
        self._hold_level = 0
        if self._hold_input is not None:
            runtime.image.subscribe(self._feed_hold_input)

    # -- the one entry ------------------------------------------------------------------------

    def apply(self, item: Input) -> None:
        """Validate, record and apply ``item``; InputRefused (nothing applied) otherwise."""
        self._dispatch(item)

    def apply_on_time(self, item: Input) -> None:
        """:meth:`apply` from inside an engine timer, at the timer's own time: the engine is
        not brought to the wall clock first (the plant's writes, at their exact times, so
        that ``run`` and a replay of it agree)."""
        sync, self._sync = self._sync, None
        try:
            self._dispatch(item)
        finally:
            self._sync = sync

    def apply_first(self, item: Input) -> None:
        """:meth:`apply_on_time` from a *first* engine timer, after the plant's tick of its
        instant and before its other timers (a PLC scan of it): ``run --script``'s start at a
        scan's instant, as ``sim`` starts before its first scan.  The record says so, and its
        replay applies it there, where it applies other inputs after that instant's timers."""
        self._first = True
        try:
            self.apply_on_time(item)
        finally:
            self._first = False

    def _dispatch(self, item: Input) -> None:
        if type(item) is Writes:  # the fieldbus's every request: before the match, whose
            self._writes(item.changes, item)  # class patterns cost ~50 ns more (isinstance)
            return
        # One case per member of Input, ending in assert_never: mypy fails on a kind of
        # input without its case.
        match item:
            case Writes():
                self._writes(item.changes, item)
            case Write():
                self._writes(((item.var, item.value),), item)
            case Command():
                self._command(item)
            case Snd():
                self._snd(item)
            case Start():
                self._start(item)
            case FieldbusAlarm():
                self._alarm(item)
            case Override():
                self._override(item)
            case Break():
                self._break(item)
            case Force():
                self._force(item)
            case Fault():
                self._fault(item)
            case ClearFault():
                self._clear_fault(item)
            case _:
                # Unreachable for an Input, which mypy proves here (a kind of input without
                # its case fails the type check); a caller that is not type-checked (a
                # user's program) is refused.
                if not TYPE_CHECKING:
                    raise InputRefused(Reason.UNSUPPORTED, f"not an input of ncgate.inputs: "
                                       f"{item!r}")
                assert_never(item)

    def _enter(self, item: Input) -> None:
        """Validated: now, the record, then the effect."""
        if self._sync is not None:
            self._sync()
        if self.recorder is not None and item.source.kind not in _NOT_RECORDED:
            self.recorder(item, self.runtime.engine.now, self._first)

    # -- each kind ------------------------------------------------------------------------------

    def image_changes(self, changes: tuple[tuple[Var, int], ...]) -> list[ImageChange]:
        """The image writes of ``changes``, each checked against the image."""
        check = self.runtime.image.check
        out = []
        if not changes:
            raise InputRefused(Reason.BAD_VALUE, "a write names one variable or more")
        for var, value in changes:
            try:  # (a value that is no whole number, a bool too, is an ImageValueError)
                check(var.area, var.index, var.view, value)
            except ImageAddressError as exc:
                raise InputRefused(Reason.OUTSIDE_IMAGE, str(exc)) from None
            except ImageValueError as exc:
                raise InputRefused(Reason.BAD_VALUE, str(exc)) from None
            out.append((var.area, var.index, var.view, value))
        return out

    def _writes(self, changes: tuple[tuple[Var, int], ...], item: Write | Writes) -> None:
        planned = self.image_changes(changes)
        self._enter(item)
        self.runtime.image.write(planned, str(item.source), checked=True)

    def _process(self, number: int) -> None:
        processes = self.runtime.engine.processes
        if isinstance(number, bool) or not isinstance(number, int) or number not in processes:
            raise InputRefused(Reason.UNKNOWN_PROCESS, f"no process {number!r} (1.."
                               f"{len(processes)})")

    def _command_check(self, item: Command) -> CommandKind:
        """Every refusal of a command, none of which depends on a program: the word, a
        process where only the cell's is taken, the PLC logic a restart or a reload needs,
        the interlocks of a cycle start or a step, the process known and not external."""
        kind = command_kind(item.kind)
        process = item.process
        if kind in _CELL_ONLY and process is not None:
            raise InputRefused(Reason.BAD_VALUE, f"{kind.label} acts on the whole cell: give "
                               "it without a process")
        if kind is CommandKind.RESTART_PLC and not self._logics():
            raise InputRefused(Reason.NOT_CONFIGURED, "no PLC logic to restart ([plc] logic, "
                               "[plant] logic)")
        if kind is CommandKind.RELOAD_PLC and (self._plc() is None or self.reload_plc is None):
            raise InputRefused(Reason.NOT_CONFIGURED, "no PLC logic to reload ([plc] logic)")
        if kind is CommandKind.CYCLE_START or kind is CommandKind.STEP:
            self._interlocks(kind)
        if process is not None:  # (a cell-only command of a process is refused above)
            self._own_process(process, kind.label)
        return kind

    def _command(self, item: Command) -> None:
        kind = self._command_check(item)
        process = item.process
        engine = self.runtime.engine
        if kind is CommandKind.RESTART_PLC:
            self._enter(item)
            for logic in self._logics():  # after a FAULT (the PLC's, the plant's); a
                logic.restart()  # running one is left alone, the NC untouched
            return
        if kind is CommandKind.RELOAD_PLC:
            self._enter(item)  # a load error is no refusal: the old logic runs on, and the
            assert self.reload_plc is not None  # diagnostics are in the log and plc_reload
            self.reload_plc(str(item.source))
            return
        if kind is CommandKind.RUN_TO_SYNC:
            self._enter(item)
            engine.set_break(parse_breakpoint("sync"))
            return
        if kind in _SWITCHES:
            self._enter(item)
            engine.switch(**_SWITCHES[kind])
            return
        self._enter(item)
        if kind is CommandKind.CYCLE_START:
            engine.cycle_start(by=str(item.source), process=process)
        elif kind is CommandKind.FEED_HOLD:
            engine.hold(True, process, by=f"feed hold by {item.source}")
        elif kind is CommandKind.STEP:
            engine.step(process)
        elif kind is CommandKind.SINGLE_BLOCK_ON or kind is CommandKind.SINGLE_BLOCK_OFF:
            engine.single_block(kind is CommandKind.SINGLE_BLOCK_ON, process)
        else:
            engine.reset(process)
            if process is None:  # a reset of the cell also restarts a faulted PLC (or
                for logic in self._logics():  # plant logic)
                    logic.restart()

    def _logics(self) -> list[PlcRuntime]:
        """The ST tasks a restart restarts: the PLC's logic and the plant's."""
        plant = self.runtime.plant
        return [logic for logic in (self._plc(), plant.logic if plant is not None else None)
                if logic is not None]

    def _force(self, item: Force) -> None:
        image, engine = self.runtime.image, self.runtime.engine
        var, value = item.var, item.value
        if var is None:
            if value is not None:
                raise InputRefused(Reason.BAD_VALUE, "a force names its variable")
            self._enter(item)
            image.unforce()
            plc = self._plc()
            if plc is not None:
                plc.unforce()
            engine.note_force(None, None, str(item.source))
            self._forces_released()
            return
        if isinstance(var, PlcVar):
            self._force_plc(item, var)
            return
        if value is not None and not isinstance(value, int):
            raise InputRefused(Reason.BAD_VALUE, f"{var} holds whole numbers, not {value!r}")
        if value is not None:
            self.image_changes(((var, value),))  # the address and the value, or refused
            if var.address not in image.forced:
                self._room_to_force(var)
            over = image.forced_over(var.area, var.index, var.view)
            if over is not None:
                raise InputRefused(Reason.BAD_VALUE, f"{var} has bits of {Var.at(*over)}, "
                                   "which is forced: release it first")
        else:
            try:  # a release names a variable of the image too
                image.read(var.area, var.index, var.view)
            except ImageAddressError as exc:
                raise InputRefused(Reason.OUTSIDE_IMAGE, str(exc)) from None
        self._enter(item)
        if value is None:
            image.unforce(var.area, var.index, var.view)
        else:
            image.force(var.area, var.index, var.view, value, str(item.source))
        engine.note_force(str(var), value, str(item.source))
        if value is None:
            self._forces_released()

    def _forces_released(self) -> None:
        """The plant's models write what they drive that a force kept (after the release's
        own event: cause before effect)."""
        plant = self.runtime.plant
        if plant is not None:
            plant.show_driven()

    def _force_plc(self, item: Force, var: PlcVar) -> None:
        """Force a variable of the PLC logic: kept at the start and the end of every scan
        (docs/decisions.md)."""
        plc = self._plc()
        if plc is None:
            raise InputRefused(Reason.NOT_CONFIGURED, f"{var}: no PLC logic runs ([plc] logic)")
        path = str(var)
        try:
            if item.value is None:
                plc.forceable(path)
            else:
                stored = plc.check_force(path, item.value)
        except KeyError as exc:  # PlcPathError
            raise InputRefused(Reason.UNKNOWN_VARIABLE, str(exc)) from None
        except ValueError as exc:
            raise InputRefused(Reason.BAD_VALUE, str(exc)) from None
        if item.value is not None and not plc.is_forced(path):
            self._room_to_force(var)
        self._enter(item)
        if item.value is None:
            plc.unforce(path)
        else:
            plc.force(path, stored)
        self.runtime.engine.note_force(path, item.value, str(item.source))

    def _room_to_force(self, var: Var | PlcVar) -> None:
        """A new force is refused when MAX_FORCED variables are forced already."""
        plc = self._plc()
        forced = len(self.runtime.image.forced) + (len(plc.forced) if plc is not None else 0)
        if forced >= MAX_FORCED:
            raise InputRefused(Reason.BAD_VALUE, f"{var}: {forced} variables are forced "
                               f"(at most {MAX_FORCED}): release one first")

    def _break(self, item: Break) -> None:
        if not isinstance(item.on, bool):
            raise InputRefused(Reason.BAD_VALUE, f"a breakpoint is set or cleared: on "
                               f"{item.on!r}")
        try:
            bp = parse_breakpoint(item.at)
        except ValueError as exc:
            raise InputRefused(Reason.BAD_VALUE, str(exc)) from None
        if bp.process is not None:
            self._process(bp.process)
        breakpoints = self.runtime.engine.breakpoints
        if item.on and bp not in breakpoints and len(breakpoints) >= MAX_BREAKPOINTS:
            raise InputRefused(Reason.BAD_VALUE, f"{MAX_BREAKPOINTS} breakpoints are set: "
                               "clear one first")
        self._enter(item)
        self.runtime.engine.set_break(bp, item.on)

    def _override(self, item: Override) -> None:
        for name, value, top in (("feed", item.feed, FEED_OVERRIDE_MAX),
                                 ("rapid", item.rapid, RAPID_OVERRIDE_MAX)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, int)
                                      or not 0 <= value <= top):
                raise InputRefused(Reason.BAD_VALUE, f"{name} override {value!r}: a whole "
                                   f"percent 0..{top}")
        if item.feed is None and item.rapid is None:
            raise InputRefused(Reason.BAD_VALUE, "an override names feed, rapid or both")
        if item.process is not None:
            self._own_process(item.process, "an override")
        self._enter(item)
        self.runtime.engine.override(item.feed, item.rapid, item.process)

    def _feed_hold_input(self, changes: object, writer: str) -> None:
        """The feed-hold input (nc.feed_hold_input) rose, by any write of its bit, byte or
        word: the cell holds, as on a feed hold.  It resumes with a cycle start once the input
        is clear -- a machine does not move by itself when its door closes."""
        var = self._hold_input
        assert var is not None
        level = self.runtime.image.read(var.area, var.index, var.view)
        if level and not self._hold_level:
            self.runtime.engine.hold(True, by=f"feed hold input {var}")
        self._hold_level = level

    def _interlocks(self, kind: CommandKind) -> None:
        """A cycle start while a PLC interlock input is set is refused, saying which."""
        plc = self._plc()
        if plc is not None and plc.hold_level:
            raise InputRefused(Reason.INTERLOCK, f"{kind.label}: the PLC's NC.HOLD_LEVEL is "
                               "set")
        image = self.runtime.image
        for key, var in self.runtime.interlocks:
            if image.read(var.area, var.index, var.view):
                raise InputRefused(Reason.INTERLOCK, f"{kind.label}: {key} input {var} is "
                                   "set")

    def _own_process(self, number: int, doing: str) -> None:
        """A command of one process: a configured one that runs part programs."""
        self._process(number)
        if self.runtime.engine.processes[number].external:
            raise InputRefused(Reason.EXTERNAL_PROCESS, f"{doing} of process {number}: it is "
                               "external, it runs no part program")

    def _snd(self, item: Snd) -> None:
        engine = self.runtime.engine
        self._process(item.sender)
        self._process(item.target)
        if not engine.processes[item.sender].external:
            raise InputRefused(Reason.NOT_EXTERNAL, f"SND from {item.sender}: only an "
                               "external process sends from outside (nc.external)")
        target = engine.processes[item.target]
        if not target.external and (target.loaded is None or target.alarm is not None):
            raise InputRefused(Reason.NOT_RUNNING, f"SND to process {item.target}, which "
                               "runs no program")
        self._enter(item)
        engine.external_snd(item.sender, item.target)

    def precheck(self, item: Input) -> None:
        """What of ``item`` can be refused before its program is read, so that a fieldbus
        answers it: a start's program named and process able to take it; every refusal of a
        command (interlocks, the process known and not external: none depends on a
        program).  InputRefused, or nothing."""
        if type(item) is Start:
            self._start_check(item)
        elif type(item) is Command:
            self._command_check(item)

    def _start_check(self, item: Start) -> str:
        runtime = self.runtime
        if item.program is not None and (not isinstance(item.program, str)
                                         or not item.program.strip()):
            raise InputRefused(Reason.BAD_VALUE, f"program {item.program!r}: a name, or None "
                               "for nc.main")
        name = item.program or runtime.config.nc.main
        if not name:
            raise InputRefused(Reason.NOT_CONFIGURED, "no program named and no nc.main "
                               "configured")
        self._process(item.process)
        p = runtime.engine.processes[item.process]
        if p.external:
            raise InputRefused(Reason.EXTERNAL_PROCESS, f"process {item.process} is external:"
                               " it runs no part program")
        if p.loaded is not None or p.alarm is not None:
            raise InputRefused(Reason.BUSY, f"process {item.process} is busy "
                               f"({p.state.name})")
        return name

    def _start(self, item: Start) -> None:
        runtime = self.runtime
        name = self._start_check(item)
        try:  # load (parse and check) before the clock is read: it starts when it is ready
            program = runtime.store.load(name, None, item.process)
        except ProgramNotFoundError as exc:
            raise InputRefused(Reason.PROGRAM_NOT_FOUND, str(exc)) from exc
        except ProgramError as exc:
            raise InputRefused(Reason.PROGRAM_INVALID, str(exc)) from exc
        if item.at is not None:  # a block search: refused before anything acts
            if not isinstance(item.at, str) or not isinstance(item.with_calc, bool):
                raise InputRefused(Reason.BAD_VALUE, f"a block search starts at a label or an "
                                   f"N number, got {item.at!r}")
            try:
                runtime.engine.block_search(program, item.process, item.at, item.with_calc)
            except ValueError as exc:
                raise InputRefused(Reason.BAD_VALUE, f"block search: {exc}") from None
        self._enter(dataclasses.replace(item, program=name))  # recorded by its name
        runtime.engine.start(name, item.process, by=str(item.source), at=item.at,
                             with_calc=item.with_calc)

    def _fault(self, item: Fault) -> None:
        plant = self.runtime.plant
        if plant is None:
            raise InputRefused(Reason.NOT_CONFIGURED, "no plant runs here")
        fault = plant.check(item)
        self._enter(item)
        plant.inject(fault, item.for_s)

    def _clear_fault(self, item: ClearFault) -> None:
        plant = self.runtime.plant
        if plant is None:
            raise InputRefused(Reason.NOT_CONFIGURED, "no plant runs here")
        faults = plant.clear(item)
        self._enter(item)
        plant.remove(faults, str(item.source))

    def _alarm(self, item: FieldbusAlarm) -> None:
        if not isinstance(item.message, str):
            raise InputRefused(Reason.BAD_VALUE, f"an alarm's message is a text, not "
                               f"{item.message!r}")
        code = _member(AlarmCode, item.code)
        if code is None:
            raise InputRefused(Reason.BAD_VALUE, f"AL{item.code!r}: no such alarm "
                               "(docs/diagnostics.md)")
        self._enter(item)
        self.runtime.engine.fieldbus_alarm(code, item.message)
