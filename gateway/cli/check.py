"""``ncgate check``: parse and check programs against the configuration they will run under.

Which config: ``--config`` when given; otherwise an ``ncgate.toml`` beside the file (the
convention of the examples); otherwise the built-in default with the file's own folder as
storage device MP0, so that the programs it EXEs are looked for beside it.

Which process runs a program, for the checks that need it (a process waiting for itself, …):
``--process`` when given; otherwise what the programs say -- the config's main program runs in
process 1, and ``(EXE,n,NAME)`` with a constant n runs NAME in process n.  The main program is
read for that even when it is not among the files checked.  (That is NC-110's rule; an ISG
section runs in its channel.  The dialect checks its files: ``DialectPlugin.check``.)
"""

from __future__ import annotations

import glob
import logging
import re
import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from ncgate.config import Config, ConfigError, StorageConfig, load_config
from ncgate.config.schema import BUILT_IN
from ncgate.gateway.errors import UsageError
from ncgate.gateway.programs import CheckedFile, dialect_options, storage_of
from ncgate.interpreter.diagnostics import Diagnostic
from ncgate.interpreter.dialects import dialect_of
from ncgate.interpreter.settings import Dialect
from ncgate.interpreter.storage import PROGRAM_SUFFIXES, file_version
from ncgate.plc.st.compiler import compile_logic
from ncgate.plc.st.diagnostics import LogicError, StCode, StDiagnostic
from ncgate.plc.st.logic import Logic
from ncgate.plc.st.nodes import SourceFile, Span
from ncgate.plc.st.plcopen import read_logic_file

LOGIC_SUFFIXES = (".st", ".xml")  # PLC logic (ST, PLCopen XML), checked as the PLC loads it
# TwinCAT 3's own source files (a POU, a global variable list, a data type, ...): XML whose
# root is TcPlcObject, which neither the PLC nor an NC dialect reads.  Known by the suffix,
# or by the root element in the file's first bytes whatever its suffix.
TWINCAT_SUFFIXES = (".tcpou", ".tcgvl", ".tcdut", ".tcio", ".tctto", ".tcplcproj")
TWINCAT_ROOT = b"<TcPlcObject"
SNIFF_BYTES = 4096

CONFIG_BESIDE = "ncgate.toml"

log = logging.getLogger("ncgate")




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


_CHECKED_SUFFIXES = (*PROGRAM_SUFFIXES[1:], *LOGIC_SUFFIXES)


def expand(arguments: Sequence[str]) -> tuple[list[Path], list[Path]]:
    """Files, directories (their programs) and globs, in a stable order, each file once; and
    the files given again (by another argument, another name or a link), which are not
    checked twice.  A file named is checked whatever its name; a directory or a glob gives
    its programs and logic (.nc, .txt, .st, .xml), not a README or a config beside them."""
    out: list[Path] = []
    for arg in arguments:
        if not arg:  # (Path("") is the current folder: `check "$UNSET"` checked that)
            raise UsageError("an empty argument: give a file, a folder or a glob")
        if arg.endswith("/") and not Path(arg).is_dir():  # (Path drops the slash)
            raise UsageError(f"not a folder: {arg}")
        magic = glob.has_magic(arg)
        matches = sorted(glob.glob(arg, recursive=True)) if magic else [arg]
        if not matches:
            raise UsageError(f"no file matches {arg}")
        for match in matches:
            path = Path(match)
            if path.is_dir():
                out.extend(sorted(p for p in path.iterdir() if p.is_file()
                                  and p.suffix.lower() in _CHECKED_SUFFIXES))
            elif path.is_file():
                if not magic or path.suffix.lower() in _CHECKED_SUFFIXES:
                    out.append(path)
            elif path.exists():  # (a FIFO, a device: what would be read is no program)
                raise UsageError(f"not a regular file: {arg}")
            else:
                raise UsageError(f"no such file: {arg}")
    return _once(out)


def _once(paths: Sequence[Path]) -> tuple[list[Path], list[Path]]:
    """``paths`` without a file met before, and those dropped.  A file is one file whatever
    it is called: an ST file checked beside itself would be ST032 at its own line, "defined
    where it is defined", and a program's diagnostics would be said and counted twice."""
    seen: set[tuple[int, int]] = set()
    once: list[Path] = []
    again: list[Path] = []
    for path in paths:
        found = path.stat()  # (the file itself, whatever its name: a link, a hard link)
        key = (found.st_dev, found.st_ino)
        (again if key in seen else once).append(path)
        seen.add(key)
    return once, again


def config_for(path: Path, explicit: Config | None) -> Config:
    if explicit is not None:
        return explicit
    beside = path.parent / CONFIG_BESIDE
    if beside.is_file():
        return load_config(beside, serving=False)
    default = load_config(None, serving=False)
    folder = path.parent.resolve()
    return replace(default, nc=replace(default.nc, storage=StorageConfig({"MP0": folder}, "MP0")))


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
        for path in group:
            said = twincat_file(path)
            if said is not None:
                reports[path] = FileReport(path, (said,))
        group = [p for p in group if p not in reports]
        if not group:
            continue
        cfg = config if config is not None else config_for(group[0], None)
        logic = [p for p in group if p.suffix.lower() in LOGIC_SUFFIXES]
        if logic:
            reports.update(check_logic(logic, cfg))
        paths = [p for p in group if p.suffix.lower() not in LOGIC_SUFFIXES]
        if not paths:
            continue
        which = dialect or cfg.nc.dialect
        found = dialect_of(which).check(paths, dialect_options(cfg, which), storage_of(cfg),
                                        process)
        reports.update((path, FileReport(path, tuple(found[path]))) for path in paths)
    return [reports[p] for p in files]


def twincat_file(path: Path) -> StDiagnostic | None:
    """ST040 at its root element when ``path`` is a TwinCAT 3 source file (``.TcPOU``, ...),
    which would otherwise be read as an NC program and drown in its syntax errors."""
    try:
        with path.open("rb") as f:
            head = f.read(SNIFF_BYTES)
    except OSError:
        return None  # (said where the file is read)
    at = head.find(TWINCAT_ROOT)
    if at < 0 and path.suffix.lower() not in TWINCAT_SUFFIXES:
        return None
    before = head[:max(at, 0)]
    line = before.count(b"\n") + 1
    column = len(before) - (before.rfind(b"\n") + 1) + 1
    lines = head.decode("utf-8", "replace").splitlines()
    return StDiagnostic(
        StCode.XML_PROJECT, "a TwinCAT 3 source file (TcPlcObject XML), not an NC program "
        "and not PLC logic ncgate reads: export the POUs as PLCopen XML (.xml), or save "
        "their Structured Text as .st (docs/plc.md)",
        Span(str(path), line, column), lines[line - 1] if line <= len(lines) else "")


def other_dialect(paths: Sequence[Path], config: Config, which: Dialect) -> Dialect | None:
    """Another dialect that reads every one of ``paths`` without an error, which ``which``
    did not, and keeps their synchronisation: the files are most likely in that language
    (an ISG file given to NC-110).  ISG reads ``(…)`` as a comment, so nearly every NC-110
    program "reads" as ISG -- with every EXE, WAI, SND and REL gone: a dialect is named only
    when its reading holds at least as many sync statements as the text has such codes."""
    for other in Dialect:
        if other is which:
            continue
        plugin = dialect_of(other)
        found = plugin.check(list(paths), dialect_options(config, other), storage_of(config),
                             None)
        if any(d.is_error for path in paths for d in found.get(path, ())):
            continue
        if all(plugin.sync_statements(path) >= _sync_codes(path) for path in paths):
            return other
    return None


# NC-110's synchronisation codes as a file's text has them, whatever reads it: what a reading
# in another dialect must keep (the engine's notation, not a dialect's branch).
_SYNC_CODE = re.compile(r"\(\s*(?:EXE|WAI|SND|REL)\b", re.IGNORECASE)


def _sync_codes(path: Path) -> int:
    try:
        return len(_SYNC_CODE.findall(path.read_text(encoding="utf-8", errors="replace")))
    except OSError:
        return 0


def check_logic(files: Sequence[Path], config: Config, section: str | None = None,
                compiled: list[Logic] | None = None) -> dict[Path, FileReport]:
    """Structured Text files, checked together (one may use another's function blocks)
    against the config's image sizes and processes, as ``[plc] logic`` loads them.

    ``section`` ("plc" or "plant"): the files are that section's ``logic``, and with no error
    in them the PROGRAMs it runs are chosen as ``sim`` and ``run`` choose them
    (:func:`ncgate.gateway.plc.program_order`): files with no PROGRAM, or a
    ``section.programs`` entry that names none, is the ConfigError they refuse with.
    ``compiled``: given, the logic is appended to it when it compiled."""
    from ncgate.gateway.plc import logic_context, logic_key, program_order, retain_in_plant

    found: dict[str, list[StDiagnostic]] = {str(p): [] for p in files}
    parsed: list[SourceFile] = []
    for i, path in enumerate(files):
        try:
            parsed.append(read_logic_file(path))
        except LogicError as exc:
            found[str(path)].extend(exc.diagnostics)
        except OSError as exc:  # (found, but its reading fails: a FIFO, an I/O error)
            said = f"cannot read {path}: {exc.strerror or exc}"
            if section is None:
                raise UsageError(said) from None
            raise ConfigError(f"{config.source or BUILT_IN}: "
                              f"{logic_key(section, i, len(files))}: {said}") from None
    if parsed:
        try:
            logic = compile_logic(parsed, logic_context(config))
            for d in (*logic.warnings, *(retain_in_plant(parsed) if section == "plant" else ())):
                found.setdefault(d.span.file, []).append(d)
        except LogicError as exc:
            for d in exc.diagnostics:
                found.setdefault(d.span.file, []).append(d)
        else:
            if section is not None and not any(d.is_error for said in found.values()
                                               for d in said):
                program_order(logic, config, section)
            if compiled is not None:
                compiled.append(logic)
    return {path: FileReport(path, tuple(found[str(path)])) for path in files}


def missing_devices(config: Config) -> dict[str, str]:
    """The storage devices whose folder does not exist: device -> what to say of it."""
    where = config.source or BUILT_IN
    return {name: f"{where}: nc.storage.{name}: no such folder: {folder}"
            for name, folder in config.nc.storage.devices.items() if not folder.is_dir()}


@dataclass(frozen=True, slots=True)
class StartCheck:
    """What ``run`` found of its configured programs before it serves (start_problems)."""

    problems: tuple[str, ...]  # what keeps it from running them, said in words
    reports: tuple[FileReport, ...]  # the main program's report, when it has errors
    checked: tuple[CheckedFile, ...]  # found without error: the store need not check again


def start_problems(config: Config) -> StartCheck:
    """What keeps ``run`` from running its configured programs: a storage folder that does
    not exist, a main program that is not on its device, and the main program's ``check``
    diagnostics (with ``nc.lazy_parse`` a program is read only as it runs, so only found)."""
    problems = tuple(missing_devices(config).values())
    storage = storage_of(config)
    main = config.nc.main
    path = storage.find(main)
    if path is None:
        device = config.nc.storage.default
        folder = config.nc.storage.devices.get(device)
        return StartCheck((*problems, f"{config.source or BUILT_IN}: nc.main: program {main} "
                           f"is not on {device} ({folder})"), (), ())
    if config.nc.lazy_parse:
        return StartCheck(problems, (), ())
    version = file_version(path)
    log.info("checking %s (%s bytes) before serving (--allow-missing skips this)", path.name,
             f"{version[1]:,}")
    began = time.perf_counter()
    reports = tuple(r for r in check_files([path], config) if r.errors)
    errors = sum(r.errors for r in reports)
    log.info("checked %s in %.1f s: %s", path.name, time.perf_counter() - began,
             f"{errors} error(s)" if errors else "no error")
    # The main program runs in process 1, and `check` checked it for process 1 (and for any
    # process it EXEs itself in, which can only add errors): the program store, which would
    # check it for process 1 again, takes this version as checked (seconds for 3 MB).
    same = not errors and file_version(path) == version
    return StartCheck(problems, reports, (CheckedFile(path, version, 1),) if same else ())


def storage_files(config: Config) -> list[Path]:
    """Every program on every configured device (what ``ncgate check`` with no file checks),
    each once: two devices may be one folder."""
    out: list[Path] = []
    for folder in config.nc.storage.devices.values():
        if folder.is_dir():
            out.extend(sorted(p for p in folder.iterdir() if p.is_file()
                              and p.suffix.lower() in PROGRAM_SUFFIXES[1:]))
    return _once(out)[0]
