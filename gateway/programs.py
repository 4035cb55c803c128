"""The program store: finds programs on the storage devices and checks them before they run.

It is the engine's :class:`~ncgate.interpreter.engine.ports.ProgramLoader`.  A program is
parsed and checked (for the process it will run in) once per file version, and only the
latest version of a file is kept (a program edited all shift long does not pile up); a program
with errors never starts -- the loader raises with every diagnostic, and the runtime turns that
into an alarm of the calling process.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from ncgate.config import Config
from ncgate.interpreter.diagnostics import ProgramSyntaxError
from ncgate.interpreter.nc110.checker import CheckContext, Limits, check_program
from ncgate.interpreter.nc110.parser import Program
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


class ProgramStore:
    def __init__(self, config: Config) -> None:
        self.config = config
        self.storage = storage_of(config)
        # (file, process) -> (the version it was read at, the checked program)
        self._cache: dict[tuple[Path, int], tuple[tuple[int, int], Program]] = {}

    def load(self, name: str, device: str | None, process: int) -> Program:
        path = self.storage.locate(name, device)
        stat = path.stat()
        version = (stat.st_mtime_ns, stat.st_size)
        cached = self._cache.get((path, process))
        if cached is not None and cached[0] == version:
            return cached[1]
        program = Program.from_path(path, display=path.name)
        # nc.lazy_parse: start at once; a bad block is an alarm when it is reached.
        if not self.config.nc.lazy_parse:
            diagnostics = check_program(
                program, check_context(self.config, self.storage, {process}))
            errors = [d for d in diagnostics if d.is_error]
            if errors:
                raise ProgramSyntaxError(errors)
        self._cache[(path, process)] = (version, program)
        return program
