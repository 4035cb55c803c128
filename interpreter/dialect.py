"""What a dialect brings to the runtime, stated as protocols: one folder, one object.

A dialect is a folder ``interpreter/<name>/`` whose ``dialect.py`` defines ``DIALECT``, a
:class:`DialectPlugin`; it is registered by its member of
:class:`~ncgate.interpreter.settings.Dialect` (``NAME = "<name>"``), and
:mod:`ncgate.interpreter.dialects` finds it by that name.  Nothing outside the dialect's
folder and the registry branches on which dialect runs: the gateway asks the plugin.

The plugin is told of the configuration as plain data (:class:`DialectOptions`, filled by the
gateway): a dialect imports no ``ncgate.config``.  Stdlib and ``ncgate.interpreter`` only;
this module imports no dialect.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from ncgate.interpreter.engine.ports import FrontEnd

if TYPE_CHECKING:
    from ncgate.interpreter.diagnostics import Diagnostic
    from ncgate.interpreter.engine.ports import BlockHost, ProgramText
    from ncgate.interpreter.settings import Dialect
    from ncgate.interpreter.storage import Storage

Version = tuple[int, int]  # a file's (mtime_ns, size): a program is read once per version


@dataclass(frozen=True, slots=True)
class ExternalBinding:
    """A named variable of the image (``[nc.ve]``; ISG's ``V.E.``): where it lives in the
    image, and whether access is synchronous."""

    area: str
    index: int
    view: str
    sync: bool
    text: str  # as configured: "SYVAR5"


@dataclass(frozen=True, slots=True)
class DialectOptions:
    """What a dialect is told of the configuration (the gateway fills it from ``[nc]`` and
    ``[plc]``): the processes, the image's sizes, and the dialect's own table."""

    processes: int = 5
    external: frozenset[int] = frozenset()  # processes a PLC plays (they run no program)
    e_params: int = 1000
    syvars: int = 256
    sa_bits: int = 1024
    k_bytes: int = 512
    main: str = ""  # the main program: process 1 runs it
    lazy_parse: bool = False  # start a program before it is parsed whole
    variables: Mapping[str, ExternalBinding] = field(default_factory=dict)  # [nc.ve]
    own: Mapping[str, Any] = field(default_factory=dict)  # [nc.<dialect>]: its own settings


class DialectFrontEnd(FrontEnd, Protocol):
    """The engine's front end, and what the gateway does with it once the engine is built."""

    def attach(self, host: BlockHost, reset_listeners: list[Callable[[], None]]) -> object:
        """The engine is built: register the dialect's own actions, and the state a reset
        clears (NC-110 has none)."""


class ProgramReader(Protocol):
    """Reads and checks a dialect's program files for the program store, which keeps the
    result per (file, process, version); the reader may keep what a file's processes share."""

    def load(self, path: Path, version: Version, process: int,
             apart: bool = False, checked: bool = False) -> ProgramText:
        """The program file ``path`` holds for ``process``, checked for it.  ``apart``: the
        caller is a thread of its own that may wait (never the event loop's): a reader may
        then check a big file in a child process, which the loop would only wait for.
        ``checked``: this version of the file was checked for ``process`` already, and had no
        error (``run``'s start-up check): a reader need not check it again.

        Raises ``ProgramSyntaxError`` with every error that keeps it from starting, or
        ``ProgramNotFoundError`` when the file has no program for the process."""

    def channels(self, name: str) -> tuple[int, ...]:
        """The processes program ``name`` starts in when it is run on its own (an ISG file:
        each section in its channel, spec 5.1); () when it names none -- it then runs in
        process 1."""

    def cancel(self) -> None:
        """Stop the reads under way (the gateway closes): a :meth:`load` waiting for one
        raises ``ChildCancelled`` (interpreter/child.py); later loads read anew."""


class DialectPlugin(Protocol):
    """Everything a dialect brings: its name, what it needs of the engine, its front end,
    and how its files are read, checked and started."""

    @property
    def name(self) -> Dialect: ...

    @property
    def buffered(self) -> bool:
        """The engine's buffer effect (``RuntimeSettings.buffered``)."""

    def front_end(self, options: DialectOptions) -> DialectFrontEnd: ...

    def reader(self, options: DialectOptions, storage: Storage) -> ProgramReader: ...

    def check(self, paths: Sequence[Path], options: DialectOptions, storage: Storage,
              process: int | None) -> Mapping[Path, Sequence[Diagnostic]]:
        """``ncgate check``: every diagnostic of each file (a file that cannot be read has
        that diagnostic), ``process`` being the one they run in when given."""

    def sync_statements(self, path: Path) -> int:
        """How many synchronisation statements this dialect's reading of the file holds
        (NC-110: EXE, REL, WAI, SND; ISG: #SIGNAL, #WAIT, #FLUSH): a hint that the file is
        in this dialect must not drop the ones the file was written with."""
