"""What the interpreter needs from the outside world, stated as protocols (STYLE: LinuxCNC's
canonical interface).  The gateway wires real implementations in: ``plc.image.IOImage`` is an
:class:`ImagePort`, the gateway's program store a :class:`ProgramLoader`.

Variables are addressed as in the PLC: area ``"SA" | "SK" | "SYVAR"``, index, view
``"bit" | "BY" | "IN"`` (the values of :class:`interpreter.nodes.VarKind` and ``View``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Protocol

from ncgate.interpreter.parser import Program


class Cancellable(Protocol):
    def cancel(self) -> None: ...


class ImagePort(Protocol):
    def read(self, area: str, index: int, view: str) -> int: ...

    def write(self, changes: Iterable[tuple[str, int, str, int]], writer: str) -> object: ...

    def check(self, area: str, index: int, view: str, value: int) -> None: ...

    def wait(self, area: str, index: int, view: str, op: str, value: int,
             on_true: Callable[[], None]) -> Cancellable | None:
        """None when the condition holds now; else call ``on_true`` once when it does."""

    def last_writer(self, area: str, index: int, view: str) -> str | None: ...


class ProgramLoader(Protocol):
    def load(self, name: str, device: str | None, process: int) -> Program:
        """A checked program, ready to run in ``process``.

        Raises ``ProgramNotFoundError`` or ``ProgramSyntaxError`` (with every diagnostic).
        """
