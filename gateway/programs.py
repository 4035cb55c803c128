"""The program store: finds programs on the storage devices and checks them before they run.

It is the engine's :class:`~ncgate.interpreter.engine.ports.ProgramLoader`.  A program is
parsed and checked (for the process it will run in) once per file version, and only the
latest version of a file is kept (a program edited all shift long does not pile up); a program
with errors never starts -- the loader raises with every diagnostic, and the runtime turns that
into an alarm of the calling process.  How a file is read and checked is the dialect's
(:class:`~ncgate.interpreter.dialect.ProgramReader`).
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable, Iterable
from pathlib import Path

from ncgate.config import Config
from ncgate.interpreter.child import ChildCancelled
from ncgate.interpreter.diagnostics import ProgramError, ProgramNotFoundError
from ncgate.interpreter.dialect import DialectOptions, ExternalBinding, Version
from ncgate.interpreter.dialects import dialect_of, parse_condition
from ncgate.interpreter.engine.ports import ProgramText
from ncgate.interpreter.settings import Dialect
from ncgate.interpreter.storage import Storage, file_version


def storage_of(config: Config) -> Storage:
    return Storage(config.nc.storage.devices, config.nc.storage.default)


def external_bindings(config: Config) -> dict[str, ExternalBinding]:
    """``[nc.ve]`` as a dialect reads it: NAME -> image variable and sync."""
    out = {}
    for name, ve in config.nc.ve.items():
        text = ve.map.upper()
        if text.startswith("K"):  # K12: the K packet's byte 12, as SK12
            text = "S" + text
        (area, index, view), _, _ = parse_condition(f"{text}=0")
        out[name] = ExternalBinding(area, index, view, ve.sync, ve.map)
    return out


def dialect_options(config: Config, dialect: Dialect | None = None) -> DialectOptions:
    """What the dialect (the config's, unless named) is told of the config: ``[nc]``, the
    image's sizes, ``[nc.ve]`` and its own table ``[nc.<dialect>]``."""
    nc = config.nc
    own = getattr(nc, (dialect or nc.dialect).value, None)
    return DialectOptions(
        processes=nc.processes, external=nc.external, e_params=nc.e_params,
        syvars=config.plc.syvars, sa_bits=config.plc.sa_bits, k_bytes=config.plc.k_bytes,
        main=nc.main, lazy_parse=nc.lazy_parse, variables=external_bindings(config),
        own=dataclasses.asdict(own) if own is not None else {})


READ_AHEAD = 64  # programs read ahead of the EXEs of one started program, at most


@dataclasses.dataclass(frozen=True, slots=True)
class CheckedFile:
    """A version of a program file checked for a process with no error found, before the
    store was made (``run``'s start-up check): the store reads it without checking it again
    (:meth:`ProgramStore.add_checked`)."""

    path: Path
    version: Version
    process: int


class ProgramStore:
    def __init__(self, config: Config) -> None:
        self.config = config
        self.storage = storage_of(config)
        self.dialect = dialect_of(config.nc.dialect)
        self._reader = self.dialect.reader(dialect_options(config), self.storage)
        # (file, process) -> (the version it was read at, the checked program, or what was
        # wrong with it: a failure is kept too, so a start after a failed preload does not
        # read the file again on the loop)
        self._cache: dict[tuple[Path, int], tuple[Version, ProgramText | Exception]] = {}
        self._lock = threading.Lock()  # preload() reads in a thread of its own
        # Told (on the loop, by load()) of every program file read, again when it changed:
        # the session record hashes the files a session used.
        self.loaded: list[Callable[[Path], None]] = []
        self._announced: dict[Path, Version] = {}
        # The (process, program) of a program's EXEs (the front end's exe_calls, set by the
        # wiring): what read_ahead follows.
        self.calls: Callable[[ProgramText], frozenset[tuple[int, str]]] = (
            lambda program: frozenset())
        self._checked: set[CheckedFile] = set()  # (add_checked)

    def add_checked(self, files: Iterable[CheckedFile]) -> None:
        """Versions of files checked already with no error (``run``'s start-up check): the
        first read of one of them reads it without checking it again (the check of a 3 MB
        NC-110 program takes seconds).  A file changed since is checked as any other."""
        self._checked.update(files)

    def channels(self, name: str) -> tuple[int, ...]:
        """The processes program ``name`` starts in when run on its own (an ISG file's
        sections); () when it names none."""
        return self._reader.channels(name)

    def load(self, name: str, device: str | None, process: int) -> ProgramText:
        path = self.storage.locate(name, device)
        version = file_version(path)
        result = self._read(path, version, process)
        if self._announced.get(path) != version:
            self._announced[path] = version
            for listener in self.loaded:
                listener(path)
        if isinstance(result, Exception):
            raise result.with_traceback(None)  # kept: no traceback piles up on it
        return result

    def _read(self, path: Path, version: Version, process: int,
              apart: bool = False) -> ProgramText | Exception:
        """``apart``: called from a thread of its own (preload, read_ahead), not the loop."""
        with self._lock:
            cached = self._cache.get((path, process))
        if cached is not None and cached[0] == version:
            return cached[1]
        result: ProgramText | Exception
        try:
            result = self._reader.load(path, version, process, apart,
                                       CheckedFile(path, version, process) in self._checked)
        except (ProgramError, ProgramNotFoundError) as exc:
            result = exc
        except ChildCancelled as exc:
            return exc  # the gateway closes: kept for nobody, the file read anew next time
        with self._lock:
            self._cache[(path, process)] = (version, result)
        return result

    def cancel(self) -> None:
        """Stop the reads under way (the gateway closes; see ProgramReader.cancel)."""
        self._reader.cancel()

    def ready(self, name: str, process: int) -> bool:
        """Read already, as the file is now (then :meth:`load` costs a stat): a start of it
        can act at once."""
        try:
            path = self.storage.locate(name, None)
            version = file_version(path)
        except (ProgramNotFoundError, OSError):
            return True  # nothing to read: the start says so at once
        with self._lock:
            cached = self._cache.get((path, process))
        return cached is not None and cached[0] == version

    def preload(self, name: str, process: int) -> None:
        """Read and check ``name`` for ``process`` now (any thread), keeping the program or
        what is wrong with it for the :meth:`load` that follows on the loop."""
        try:
            path = self.storage.locate(name, None)
            self._read(path, file_version(path), process, apart=True)
        except (ProgramNotFoundError, OSError):
            pass  # the load on the loop says so

    def read_ahead(self, name: str, process: int, limit: int = READ_AHEAD) -> int:
        """Read (any thread) the programs ``name``'s EXEs start, and those theirs start, up to
        ``limit`` programs: an EXE on the loop then finds its program read (a real control
        has its programs in memory).  Returns how many were read now."""
        todo = [(name, process)]
        seen = {(name.upper(), process)}
        read = 0
        while todo and len(seen) <= limit:
            current, k = todo.pop()
            try:
                path = self.storage.locate(current, None)
                version = file_version(path)
                with self._lock:
                    cached = self._cache.get((path, k))
                if cached is None or cached[0] != version:
                    read += 1
                program = self._read(path, version, k, apart=True)
            except (ProgramNotFoundError, OSError):
                continue  # the EXE says so, when it runs
            if isinstance(program, Exception):
                continue
            for callee_process, callee in self.calls(program):
                key = (callee.upper(), callee_process)
                if key not in seen:
                    seen.add(key)
                    todo.append((callee, callee_process))
        return read
