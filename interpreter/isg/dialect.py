"""TwinCAT CNC / ISG as the runtime's dialect (spec 5): what
:mod:`ncgate.interpreter.dialects` finds for ``nc.dialect = "isg"``.

A file holds a program per channel (its ``%`` sections; a file without them runs in any
channel).  It is parsed and checked once per version, and a section is kept from starting only
by its own errors (and a file-wide one).  The engine runs with the buffer effect, and the
operator may start any channel.  Its own settings are ``[nc.isg]`` (``max_events``,
``signal_params``); ``[nc.ve]`` names its ``V.E.`` variables.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from contextlib import nullcontext
from pathlib import Path

from ncgate.interpreter import heap
from ncgate.interpreter.diagnostics import Diagnostic, ProgramSyntaxError
from ncgate.interpreter.dialect import (
    DialectOptions,
    DialectPlugin,
    ProgramReader,
    Version,
)
from ncgate.interpreter.isg.checker import IsgCheckContext, check_file
from ncgate.interpreter.isg.frontend import IsgFrontEnd, IsgOptions
from ncgate.interpreter.isg.nodes import Flush, Signal, WaitSignal
from ncgate.interpreter.isg.parser import IsgFile, IsgProgram
from ncgate.interpreter.settings import Dialect
from ncgate.interpreter.storage import Storage, file_version


def isg_options(options: DialectOptions) -> IsgOptions:
    return IsgOptions(**options.own, external=options.variables)


def check_context(options: DialectOptions) -> IsgCheckContext:
    return IsgCheckContext(options.processes, options.e_params,
                           isg_options(options).signal_params, options.variables)


class _Reader:
    def __init__(self, options: DialectOptions, storage: Storage) -> None:
        self.context = check_context(options)
        self.storage = storage
        # file -> (version, the parsed file, its diagnostics): its sections share them
        self._files: dict[Path, tuple[Version, IsgFile, list[Diagnostic]]] = {}

    def _entry(self, path: Path, version: Version) -> tuple[Version, IsgFile, list[Diagnostic]]:
        cached = self._files.get(path)
        if cached is None or cached[0] != version:
            # A big file's parse is kept out of the full collections (interpreter/heap.py):
            # each walked it all, holding every thread (2.6 s for 10 MB).
            big = version[1] >= heap.BIG_BYTES  # (mtime_ns, size)
            with heap.building() if big else nullcontext():
                source = IsgFile.from_path(path, display=path.name)
                diagnostics = check_file(source, self.context)
            if big:
                heap.keep(source)
            cached = (version, source, diagnostics)
            self._files[path] = cached
        return cached

    def load(self, path: Path, version: Version, process: int,
             apart: bool = False, checked: bool = False) -> IsgProgram:
        # ``checked`` is not taken: a file is checked once for all its sections (_entry),
        # and a section's errors are picked from that.
        _, source, diagnostics = self._entry(path, version)
        program = source.program(process)
        # A section is a program: only its own errors (and a file-wide one) keep it from
        # starting.
        lo = program.section.header + 1 if program.section else 1
        errors = [d for d in diagnostics if d.is_error and lo <= d.span.line <= program.end]
        if errors:
            raise ProgramSyntaxError(errors)
        return program

    def channels(self, name: str) -> tuple[int, ...]:
        path = self.storage.locate(name, None)
        _, source, _ = self._entry(path, file_version(path))
        return tuple(section.channel for section in source.sections)

    def cancel(self) -> None:
        pass  # read in the caller's thread: nothing runs apart to stop


class IsgDialect:
    name = Dialect.ISG
    buffered = True  # the buffer effect (spec 5.4)

    def front_end(self, options: DialectOptions) -> IsgFrontEnd:
        return IsgFrontEnd(isg_options(options))

    def reader(self, options: DialectOptions, storage: Storage) -> ProgramReader:
        return _Reader(options, storage)

    def check(self, paths: Sequence[Path], options: DialectOptions, storage: Storage,
              process: int | None) -> Mapping[Path, Sequence[Diagnostic]]:
        """Each file with its sections, against the channels, signal parameters and
        ``[nc.ve]`` (a section's channel is its own: ``process`` is not needed)."""
        context = check_context(options)
        out: dict[Path, Sequence[Diagnostic]] = {}
        for path in paths:
            # A file without sections runs where it is started: in ``process`` when given,
            # and the main program in channel 1 (its own-channel rules, IW001, then apply).
            channel = process if process is not None else (
                1 if options.main and path.stem.upper() == options.main.upper() else None)
            try:
                out[path] = check_file(IsgFile.from_path(path, display=str(path)), context,
                                       channel)
            except ProgramSyntaxError as exc:  # not UTF-8
                out[path] = exc.diagnostics
        return out

    def sync_statements(self, path: Path) -> int:
        try:
            blocks = IsgFile.from_path(path).blocks
        except ProgramSyntaxError:
            return 0
        return sum(isinstance(item, Signal | WaitSignal | Flush)
                   for block in blocks if block is not None for item in block.items)


DIALECT: DialectPlugin = IsgDialect()
