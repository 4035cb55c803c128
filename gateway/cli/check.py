"""``ncgate check``: parse and check programs against the configuration they will run under.

Which config: ``--config`` when given; otherwise an ``ncgate.toml`` beside the file (the
convention of the examples); otherwise the built-in default with the file's own folder as
storage device MP0, so that the programs it EXEs are looked for beside it.

Which process runs a program, for the checks that need it (a process waiting for itself, …):
``--process`` when given; otherwise what the programs say -- the config's main program runs in
process 1, and ``(EXE,n,NAME)`` with a constant n runs NAME in process n.  The main program is
read for that even when it is not among the files checked.
"""

from __future__ import annotations

import contextlib
import glob
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from ncgate.config import Config, StorageConfig, load_config
from ncgate.gateway.errors import UsageError
from ncgate.gateway.programs import check_context, isg_context, storage_of
from ncgate.interpreter.diagnostics import Diagnostic, ProgramSyntaxError
from ncgate.interpreter.isg.checker import check_file
from ncgate.interpreter.isg.parser import IsgFile
from ncgate.interpreter.nc110.checker import check_program
from ncgate.interpreter.nc110.nodes import Exe, Num
from ncgate.interpreter.nc110.parser import Program, program_name
from ncgate.interpreter.settings import Dialect
from ncgate.interpreter.storage import PROGRAM_SUFFIXES
from ncgate.plc.st.compiler import compile_logic
from ncgate.plc.st.diagnostics import LogicError, StDiagnostic
from ncgate.plc.st.nodes import SourceFile
from ncgate.plc.st.parser import parse_file

LOGIC_SUFFIX = ".st"  # Structured Text: PLC logic, checked as the PLC loads it

CONFIG_BESIDE = "ncgate.toml"




@dataclass(frozen=True, slots=True)
class FileReport:
    path: Path
    diagnostics: tuple[Diagnostic | StDiagnostic, ...]

    @property
    def errors(self) -> int:
        return sum(1 for d in self.diagnostics if d.is_error)

    @property
    def warnings(self) -> int:
        return len(self.diagnostics) - self.errors


def expand(arguments: Sequence[str]) -> list[Path]:
    """Files, directories (their programs) and globs, in a stable order."""
    out: list[Path] = []
    for arg in arguments:
        matches = sorted(glob.glob(arg, recursive=True)) if glob.has_magic(arg) else [arg]
        if not matches:
            raise UsageError(f"no file matches {arg}")
        for match in matches:
            path = Path(match)
            if path.is_dir():
                out.extend(sorted(p for p in path.iterdir() if p.is_file()
                                  and p.suffix.lower() in (*PROGRAM_SUFFIXES[1:],
                                                           LOGIC_SUFFIX)))
            elif path.is_file():
                out.append(path)
            else:
                raise UsageError(f"no such file: {arg}")
    return out


def config_for(path: Path, explicit: Config | None) -> Config:
    if explicit is not None:
        return explicit
    beside = path.parent / CONFIG_BESIDE
    if beside.is_file():
        return load_config(beside)
    default = load_config(None)
    folder = path.parent.resolve()
    return replace(default, nc=replace(default.nc, storage=StorageConfig({"MP0": folder}, "MP0")))


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


def check_files(
    files: Sequence[Path], config: Config | None = None, process: int | None = None,
    dialect: Dialect | None = None,
) -> list[FileReport]:
    """Check files; those sharing a config are checked together (process inference).
    ``dialect`` overrides the config's ``nc.dialect``."""
    groups: dict[Path | None, list[Path]] = defaultdict(list)
    for path in files:
        groups[None if config is not None else path.parent.resolve()].append(path)
    reports: dict[Path, FileReport] = {}
    for group in groups.values():
        cfg = config if config is not None else config_for(group[0], None)
        logic = [p for p in group if p.suffix.lower() == LOGIC_SUFFIX]
        if logic:
            reports.update(check_logic(logic, cfg))
        paths = [p for p in group if p.suffix.lower() != LOGIC_SUFFIX]
        if not paths:
            continue
        if (dialect or cfg.nc.dialect) is Dialect.ISG:
            reports.update(check_isg(paths, cfg))
            continue
        storage = storage_of(cfg)
        programs: dict[Path, Program] = {}
        for path in paths:
            try:
                programs[path] = Program.from_path(path)
            except ProgramSyntaxError as exc:  # not UTF-8: its report is that diagnostic
                reports[path] = FileReport(path, exc.diagnostics)
        known = {program.name.upper() for program in programs.values()}
        context_programs = list(programs.values())
        main_path = storage.find(cfg.nc.main)
        if main_path is not None and program_name(main_path).upper() not in known:
            # A main program that is not UTF-8 starts nothing we could infer from.
            with contextlib.suppress(ProgramSyntaxError):
                context_programs.append(Program.from_path(main_path))
        runs = process_assignments(context_programs, cfg.nc.main)
        for path, program in programs.items():
            runs_in = {process} if process is not None else runs.get(program.name.upper(), set())
            diagnostics = check_program(program, check_context(cfg, storage, runs_in))
            reports[path] = FileReport(path, tuple(diagnostics))
    return [reports[p] for p in files]


def check_isg(files: Sequence[Path], config: Config) -> dict[Path, FileReport]:
    """ISG programs (spec 5): each file with its sections, against the config's channels,
    signal parameters and [nc.ve]."""
    context = isg_context(config)
    out = {}
    for path in files:
        try:
            diagnostics = check_file(IsgFile.from_path(path, display=str(path)), context)
        except ProgramSyntaxError as exc:  # not UTF-8
            diagnostics = list(exc.diagnostics)
        out[path] = FileReport(path, tuple(diagnostics))
    return out


def check_logic(files: Sequence[Path], config: Config) -> dict[Path, FileReport]:
    """Structured Text files, checked together (one may use another's function blocks)
    against the config's image sizes and processes, as ``[plc] logic`` loads them."""
    from ncgate.gateway.plc import logic_context

    found: dict[str, list[StDiagnostic]] = {str(p): [] for p in files}
    parsed: list[SourceFile] = []
    for path in files:
        try:
            parsed.append(parse_file(path))
        except LogicError as exc:
            found[str(path)].extend(exc.diagnostics)
    if parsed:
        try:
            compile_logic(parsed, logic_context(config))
        except LogicError as exc:
            for d in exc.diagnostics:
                found.setdefault(d.span.file, []).append(d)
    return {path: FileReport(path, tuple(found[str(path)])) for path in files}


def storage_files(config: Config) -> list[Path]:
    """Every program on every configured device (what ``ncgate check`` with no file checks)."""
    out: list[Path] = []
    for folder in config.nc.storage.devices.values():
        if folder.is_dir():
            out.extend(sorted(p for p in folder.iterdir() if p.is_file()
                              and p.suffix.lower() in PROGRAM_SUFFIXES[1:]))
    return out
