"""The program store: finds programs on the storage devices and checks them before they run.

It is the interpreter's :class:`~interpreter.ports.ProgramLoader`.  A program is parsed and
checked (for the process it will run in) once per file version; a program with errors never
starts -- the loader raises with every diagnostic, and the runtime turns that into an alarm of
the calling process.
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
        self._cache: dict[tuple[Path, int, int, int], Program] = {}

    def load(self, name: str, device: str | None, process: int) -> Program:
        path = self.storage.locate(name, device)
        stat = path.stat()
        key = (path, stat.st_mtime_ns, stat.st_size, process)
        program = self._cache.get(key)
        if program is None:
            program = Program.from_path(path, display=path.name)
            if self.config.nc.lazy_parse:
                # nc.lazy_parse: start at once; a bad block is an alarm when it is reached.
                self._cache[key] = program
                return program
            diagnostics = check_program(
                program, check_context(self.config, self.storage, {process}))
            errors = [d for d in diagnostics if d.is_error]
            if errors:
                raise ProgramSyntaxError(errors)
            self._cache[key] = program
        return program
