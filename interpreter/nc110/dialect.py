"""NC-110 / NC-200 as the runtime's dialect (spec 1): what :mod:`ncgate.interpreter.dialects`
finds for ``nc.dialect = "nc110"``.

A file is one program; it is checked for the process it runs in, and ``ncgate check`` infers
that process from the programs themselves: the main program runs in process 1, and
``(EXE,n,NAME)`` with a constant ``n`` runs NAME in process n.
"""

from __future__ import annotations

import contextlib
import threading
from collections import OrderedDict, defaultdict
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path

from ncgate.interpreter.child import ChildFailed, ChildJobs
from ncgate.interpreter.diagnostics import Diagnostic, ProgramSyntaxError
from ncgate.interpreter.dialect import (
    DialectOptions,
    DialectPlugin,
    ProgramReader,
    Version,
)
from ncgate.interpreter.nc110.checker import CheckContext, Limits, check_program
from ncgate.interpreter.nc110.compiler import NC110, exe_scan
from ncgate.interpreter.nc110.nodes import Exe, Num, Rel, Snd, WaitCond, WaitProc
from ncgate.interpreter.nc110.parser import Program
from ncgate.interpreter.settings import Dialect
from ncgate.interpreter.storage import Storage, file_version, program_name


def check_context(options: DialectOptions, storage: Storage,
                  runs_in: Iterable[int]) -> CheckContext:
    return CheckContext(
        processes=options.processes,
        external=options.external,
        runs_in=frozenset(runs_in),
        limits=Limits(options.e_params, options.syvars, options.sa_bits, options.k_bytes),
        find_program=lambda name, device: storage.find(name, device) is not None,
        has_device=storage.has_device,
    )


def process_assignments(programs: Iterable[Program], main: str) -> dict[str, set[int]]:
    """Program name (upper case) -> the processes the programs start it in."""
    runs: dict[str, set[int]] = defaultdict(set)
    runs[main.upper()].add(1)
    for program in programs:
        blocks, _ = program.parse_all()
        for block in blocks:
            if block is None:
                continue
            for item in block.items:
                if isinstance(item, Exe) and isinstance(item.process, Num):
                    runs[item.program.upper()].add(int(item.process.value))
    return runs


# A file this big is checked in a child process (interpreter/child.py): parsing it in a
# thread would share the interpreter lock, and its blocks the garbage collector, with the loop.
# Below it the child's start (~0.2 s) costs more than the thread's check does.
CHILD_BYTES = 512 * 1024
_ERRORS_PER_FRAME = 500


def _errors(program: Program, options: DialectOptions, storage: Storage,
            process: int) -> list[Diagnostic]:
    diagnostics = check_program(program, check_context(options, storage, {process}))
    return [d for d in diagnostics if d.is_error]


def check_in_child(data: bytes, name: str, display: str, options: DialectOptions,
                   storage: Storage, process: int) -> Iterator[object]:
    """The child's side of :meth:`_Reader.load`: the program's EXE scan, then its errors a
    few hundred a frame (an answer the parent unpickles in short calls)."""
    try:
        program = Program.from_data(data, name, display)
        errors = _errors(program, options, storage, process)
    except ProgramSyntaxError as exc:  # not UTF-8
        program, errors = None, list(exc.diagnostics)
    if program is not None:
        exe_scan(program)
    yield None if program is None else program.exe_scan
    for first in range(0, len(errors), _ERRORS_PER_FRAME):
        yield errors[first:first + _ERRORS_PER_FRAME]


# A program whose blocks are parsed when they run: this many are parsed by the reading thread
# first, so that the loop finds the block parser built (its grammar: 45 ms, once a process)
# and the program's first block shapes learnt.
WARM_BLOCKS = 256


def _warm(program: Program) -> None:
    for i in range(min(WARM_BLOCKS, len(program))):
        with contextlib.suppress(ProgramSyntaxError):  # said when the block runs
            program.block(i)


# Programs read and checked with no error, kept for the next read of the same bytes with the
# same options: a scenario suite or a sweep reads one program for every run (a third of a
# machine scenario's start).  Only small ones (their parse stays out of the collector's way)
# that start no program (whose check asks nothing of other files).  A Program is immutable
# but for its cache of parsed blocks, which only fills in.
KEPT_PROGRAMS = 8
KEPT_BYTES = 16 * 1024
_kept: OrderedDict[tuple[bytes, str, str, int, str], Program] = OrderedDict()
_kept_lock = threading.Lock()  # (read ahead in threads of their own, and on the loop)


def _starts_nothing(program: Program) -> bool:
    blocks, _ = program.parse_all()
    return not any(isinstance(item, Exe) for block in blocks if block is not None
                   for item in block.items)


class _Reader:
    def __init__(self, options: DialectOptions, storage: Storage) -> None:
        self.options = options
        self.storage = storage
        self.jobs = ChildJobs()
        self._options_key = repr(options)

    def load(self, path: Path, version: Version, process: int,
             apart: bool = False, checked: bool = False) -> Program:
        data = path.read_bytes()
        name = program_name(path)
        key = None
        if len(data) <= KEPT_BYTES and not self.options.lazy_parse:
            key = (data, name, path.name, process, self._options_key)
            with _kept_lock:
                kept = _kept.get(key)
                if kept is not None:
                    _kept.move_to_end(key)
                    return kept
        program, checked_here = self._load(path, data, name, version, process, apart, checked)
        # (A version checked by run's start-up check is not kept: a later read of the same
        # bytes, whose version may not tell an edit, checks them.)
        if key is not None and checked_here and _starts_nothing(program):
            with _kept_lock:
                _kept[key] = program
                while len(_kept) > KEPT_PROGRAMS:
                    _kept.popitem(last=False)
        return program

    def _load(self, path: Path, data: bytes, name: str, version: Version, process: int,
              apart: bool, checked: bool) -> tuple[Program, bool]:
        """The program, and whether it was checked here (not by the child, not before)."""
        # Checked already (run's start-up check, of this version): so only if the bytes just
        # read are still of that version.
        checked = checked and file_version(path) == version
        # nc.lazy_parse: start at once; a bad block is an alarm when it is reached.
        check = not self.options.lazy_parse and not checked
        scan = None  # the EXE scan, when a child checked it
        # On the loop (an EXE whose program was not read ahead) the child would only be
        # waited for, and it checks slower than this process does: checked here then.
        if apart and check and len(data) >= CHILD_BYTES:
            try:
                scan, *frames = self.jobs.run(
                    f"{__name__}:check_in_child",
                    (name, path.name, self.options, self.storage, process), data)
            except ChildFailed:
                pass  # checked here instead, below
            else:
                errors = [d for frame in frames for d in frame]
                if errors:
                    raise ProgramSyntaxError(errors)
                check = False  # by the child: its blocks are parsed when they run
        program = Program.from_data(data, name, path.name)
        if apart and not check:
            _warm(program)
        if check:
            errors = _errors(program, self.options, self.storage, process)
            if errors:
                raise ProgramSyntaxError(errors)
        if scan is not None:
            program.exe_scan = scan
        else:
            exe_scan(program)  # here, not when it starts (a 10 MB text takes a while)
        return program, check

    def cancel(self) -> None:
        self.jobs.cancel()

    def channels(self, name: str) -> tuple[int, ...]:
        return ()  # a file is one program: it runs where it is started


class Nc110Dialect:
    name = Dialect.NC110
    buffered = False

    def front_end(self, options: DialectOptions) -> NC110:
        return NC110()

    def reader(self, options: DialectOptions, storage: Storage) -> ProgramReader:
        return _Reader(options, storage)

    def check(self, paths: Sequence[Path], options: DialectOptions, storage: Storage,
              process: int | None) -> Mapping[Path, Sequence[Diagnostic]]:
        """The files are checked together: which process runs each is inferred from them
        all and the main program (read for that even when it is not among them)."""
        out: dict[Path, Sequence[Diagnostic]] = {}
        programs: dict[Path, Program] = {}
        for path in paths:
            try:
                programs[path] = Program.from_path(path)
            except ProgramSyntaxError as exc:  # not UTF-8: its report is that diagnostic
                out[path] = exc.diagnostics
        known = {program.name.upper() for program in programs.values()}
        context_programs = list(programs.values())
        main_path = storage.find(options.main)
        if main_path is not None and program_name(main_path).upper() not in known:
            # A main program that is not UTF-8 starts nothing we could infer from.
            with contextlib.suppress(ProgramSyntaxError):
                context_programs.append(Program.from_path(main_path))
        runs = process_assignments(context_programs, options.main)
        for path, program in programs.items():
            runs_in = {process} if process is not None else runs.get(program.name.upper(), set())
            out[path] = check_program(program, check_context(options, storage, runs_in))
        return out

    def sync_statements(self, path: Path) -> int:
        try:
            blocks, _ = Program.from_path(path).parse_all()
        except ProgramSyntaxError:
            return 0
        return sum(isinstance(item, Exe | Rel | WaitProc | WaitCond | Snd)
                   for block in blocks if block is not None for item in block.items)


DIALECT: DialectPlugin = Nc110Dialect()
