"""The program store: finds programs on the storage devices and checks them before they run.

It is the engine's :class:`~ncgate.interpreter.engine.ports.ProgramLoader`.  A program is
parsed and checked (for the process it will run in) once per file version, and only the
latest version of a file is kept (a program edited all shift long does not pile up); a program
with errors never starts -- the loader raises with every diagnostic, and the runtime turns that
into an alarm of the calling process.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

from ncgate.config import Config
from ncgate.interpreter.diagnostics import Diagnostic, ProgramSyntaxError
from ncgate.interpreter.isg.checker import IsgCheckContext, check_file
from ncgate.interpreter.isg.parser import IsgFile, IsgProgram
from ncgate.interpreter.nc110.checker import CheckContext, Limits, check_program
from ncgate.interpreter.nc110.parser import Program
from ncgate.interpreter.settings import Dialect
from ncgate.interpreter.storage import Storage


def storage_of(config: Config) -> Storage:
    return Storage(config.nc.storage.devices, config.nc.storage.default)


def check_context(config: Config, storage: Storage, runs_in: Iterable[int]) -> CheckContext:
    return CheckContext(
        processes=config.nc.processes,
        external=config.nc.external,
        runs_in=frozenset(runs_in),
        limits=Limits(config.nc.e_params, config.plc.syvars, config.plc.sa_bits,
                      config.plc.k_bytes),
        find_program=lambda name, device: storage.find(name, device) is not None,
        has_device=storage.has_device,
    )


def isg_context(config: Config) -> IsgCheckContext:
    from ncgate.gateway.wiring import external_bindings

    return IsgCheckContext(config.nc.processes, config.nc.e_params,
                           config.nc.isg.signal_params, external_bindings(config))


class ProgramStore:
    def __init__(self, config: Config) -> None:
        self.config = config
        self.storage = storage_of(config)
        self.dialect = config.nc.dialect
        # (file, process) -> (the version it was read at, the checked program)
        self._cache: dict[tuple[Path, int], tuple[tuple[int, int], Program | IsgProgram]] = {}
        # ISG: file -> (version, the parsed file, its diagnostics)
        self._files: dict[Path, tuple[tuple[int, int], IsgFile, list[Diagnostic]]] = {}
        # Told of every program file read (again, when it changed): the session record
        # hashes the files a session used.
        self.loaded: list[Callable[[Path], None]] = []

    def _located(self, name: str, device: str | None) -> tuple[Path, tuple[int, int]]:
        """The file of program ``name`` and its version (mtime, size)."""
        path = self.storage.locate(name, device)
        stat = path.stat()
        return path, (stat.st_mtime_ns, stat.st_size)

    def isg_file(self, name: str, device: str | None = None) -> IsgFile:
        """An ISG file by program name, parsed and checked once per version."""
        return self._isg_entry(*self._located(name, device))[1]

    def _isg_entry(self, path: Path, version: tuple[int, int]
                   ) -> tuple[tuple[int, int], IsgFile, list[Diagnostic]]:
        cached = self._files.get(path)
        if cached is None or cached[0] != version:
            source = IsgFile.from_path(path, display=path.name)
            cached = (version, source, check_file(source, isg_context(self.config)))
            self._files[path] = cached
        return cached

    def load(self, name: str, device: str | None, process: int) -> Program | IsgProgram:
        path, version = self._located(name, device)
        cached = self._cache.get((path, process))
        if cached is not None and cached[0] == version:
            return cached[1]
        if self.dialect is Dialect.ISG:
            program: Program | IsgProgram = self._check_section(path, version, process)
        else:
            program = Program.from_path(path, display=path.name)
            # nc.lazy_parse: start at once; a bad block is an alarm when it is reached.
            if not self.config.nc.lazy_parse:
                diagnostics = check_program(
                    program, check_context(self.config, self.storage, {process}))
                errors = [d for d in diagnostics if d.is_error]
                if errors:
                    raise ProgramSyntaxError(errors)
        self._cache[(path, process)] = (version, program)
        for listener in self.loaded:
            listener(path)
        return program

    def _check_section(self, path: Path, version: tuple[int, int], process: int
                       ) -> IsgProgram:
        _, source, diagnostics = self._isg_entry(path, version)
        program = source.program(process)
        # A section is a program: only its own errors (and a file-wide one) keep it from
        # starting.
        lo = program.section.header + 1 if program.section else 1
        errors = [d for d in diagnostics if d.is_error and lo <= d.span.line <= program.end]
        if errors:
            raise ProgramSyntaxError(errors)
        return program
