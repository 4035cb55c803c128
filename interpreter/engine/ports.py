"""What the engine needs from outside, stated as protocols (as LinuxCNC's canonical
interface does; ARCHITECTURE.md), and what a dialect's front end may ask of the engine.

Outward: the gateway wires real implementations in -- ``ncgate.plc.image.IOImage`` is an
:class:`ImagePort`, the gateway's program store a :class:`ProgramLoader`.  Variables are
addressed as in the PLC: area ``"SA" | "SK" | "SYVAR"``, index, view ``"bit" | "BY" | "IN"``.

Inward: a dialect is a :class:`FrontEnd` -- it compiles a block of its own language into
decoder ops, which act only through the :class:`BlockHost` (the engine's public operations).
The engine imports no front end; ``ncgate.interpreter.nc110`` is one, a second dialect is a
sibling folder.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from ncgate.interpreter.codes import AlarmCode
    from ncgate.interpreter.engine.actions import Action, Step
    from ncgate.interpreter.engine.events import Event
    from ncgate.interpreter.engine.process import (
        CompiledBlock,
        LoadedProgram,
        Process,
        QueueItem,
    )
    from ncgate.interpreter.engine.states import Stage, WaitRecord, Where
    from ncgate.interpreter.motion import Modal
    from ncgate.interpreter.settings import RuntimeSettings

    ActionHandler = Callable[[Process, Stage, Any, Where], bool]


class Cancellable(Protocol):
    def cancel(self) -> None: ...


class ImagePort(Protocol):
    def read(self, area: str, index: int, view: str) -> int: ...

    def write(self, changes: Iterable[tuple[str, int, str, int]], writer: str) -> object: ...

    def check(self, area: str, index: int, view: str, value: int) -> None: ...

    def wait(self, area: str, index: int, view: str, test: Callable[[int], bool],
             on_true: Callable[[], None]) -> Cancellable | None:
        """None when ``test(value)`` holds now; else call ``on_true`` once when it does."""

    def last_writer(self, area: str, index: int, view: str) -> str | None: ...


class ProgramText(Protocol):
    """A program as the engine sees it: a name, a file, a number of blocks (lines)."""

    @property
    def name(self) -> str: ...

    @property
    def file(self) -> str: ...

    @property
    def lines(self) -> Sequence[str]:
        """The source of each block (for messages)."""
        ...

    def __len__(self) -> int: ...


class ProgramLoader(Protocol):
    def load(self, name: str, device: str | None, process: int) -> ProgramText:
        """A checked program, ready to run in ``process``.

        Raises ``ProgramNotFoundError`` or ``ProgramSyntaxError`` (with every diagnostic).
        """


class BlockHost(Protocol):
    """What a front end's compiled ops may ask of the engine (all on the process ``p``)."""

    @property
    def settings(self) -> RuntimeSettings: ...

    @property
    def image(self) -> ImagePort: ...

    def queue_motion(self, p: Process, items: list[QueueItem]) -> Step:
        """Queue motion items (the pending ones first): NEXT, or WAIT_RETRY when full."""

    def flush(self, p: Process) -> Step:
        """NEXT when the motion queue is empty, else wait until it is (WAIT_RETRY)."""

    def perform(self, p: Process, stage: Stage, action: Action | object, where: Where) -> bool:
        """Do one action now; False when the process waits."""

    def wait_process(self, p: Process, stage: Stage, n: int, code: str, where: Where) -> bool:
        """``(WAI,n)``: the hot path of an SND/WAI exchange, with no action object."""

    def send(self, p: Process, stage: Stage, n: int, code: str, where: Where) -> bool:
        """``(SND,n)``: likewise."""

    def write_syvar(self, p: Process, index: int, value: int, where: Where,
                    stage: Stage = ...) -> None: ...

    def acts_early(self, p: Process, code: str, where: Where) -> None:
        """A plain code that acts while motion above it is still queued (``p.queue``): the
        hazard event that says so."""

    def end_decoding(self, p: Process, how: str, where: Where) -> None:
        """The program ends (REL, M30, ...) once the motion queued before has run."""

    def program_stop(self, p: Process, optional: bool = ...) -> None:
        """M00 (M01 with ``optional``): stop after this block until a cycle start."""

    @property
    def block_skip(self) -> bool:
        """The block-skip switch: a block marked "/" is skipped while it is on."""

    # -- for a dialect's own actions (registered with Engine.register_action) --

    @property
    def now(self) -> float: ...

    @property
    def processes(self) -> Mapping[int, Process]: ...

    def begin_wait(self, p: Process, stage: Stage, wait: WaitRecord) -> None:
        """The stage waits (state, trace, timeout); ``finish_wait`` ends it."""

    def finish_wait(self, p: Process, wait: WaitRecord, by: int | str) -> None: ...

    def check_wait(self, p: Process, wait: WaitRecord) -> None:
        """After a wait began: an orphan wait or a deadlock through ``p`` is an alarm."""

    def alarm(self, p: Process, code: AlarmCode, message: str, where: Where | None) -> None:
        """An alarm of ``p`` raised outside its own step (e.g. by another channel's signal)."""

    def flush_wait(self, p: Process, where: Where, code: str) -> bool:
        """The decoder waits for its interpolator to run every block before: True when it
        need not."""

    def write_image(self, p: Process, area: str, index: int, view: str, value: int,
                    where: Where) -> None: ...

    def record(self, kind: type[Event], proc: int, where: Where | None,
               *fields: object) -> None: ...

    def count_signal(self, sender: Process, target: int, ident: int, where: Where) -> None:
        """A signal counts like an SND on the fieldbus (spec 5.6): the sender's count, the
        last-SND registers, the SND log (target 0: a broadcast)."""

    def register_action(self, kind: type, handler: ActionHandler) -> None: ...


class FrontEnd(Protocol):
    """A dialect: compiles its programs' blocks for the engine."""

    def compile_block(self, host: BlockHost, loaded: LoadedProgram,
                      index: int) -> CompiledBlock:
        """Block ``index`` as decoder ops; raises RuntimeAlarm if it cannot run."""

    def exe_targets(self, program: ProgramText) -> tuple[frozenset[int], bool]:
        """The processes the program may start, and whether it names others by variables."""

    def exe_calls(self, program: ProgramText) -> frozenset[tuple[int, str]]:
        """The (process, program name) of each EXE that names its process by a constant."""

    def block_search(self, program: ProgramText, at: str, modal: Modal, e_params: list[float],
                     settings: RuntimeSettings, read: Callable[[str, int, str], int],
                     with_calc: bool) -> tuple[int, Modal, list[float]]:
        """A start at ``at`` (a label, an N number): the line index, the modal state and the
        E parameters the blocks before it make; ValueError saying why it cannot start
        there."""
