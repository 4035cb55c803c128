"""The ``ncgate`` command line (spec 4.1)."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import stat
import sys
import traceback
from collections.abc import Callable, Coroutine, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ncgate import __version__
from ncgate.config import Config, default_script_path, load_config
from ncgate.errors import NcgateError
from ncgate.gateway.errors import UsageError
from ncgate.gateway.examples import examples, examples_folder, find_example
from ncgate.gateway.lifecycle import tune_interpreter
from ncgate.gateway.stdout import closed_streams, flush_stdout, stderr, stdout, stdout_gone
from ncgate.interpreter.diagnostics import ProgramError
from ncgate.interpreter.settings import Dialect
from ncgate.plc.st.diagnostics import LogicError

if TYPE_CHECKING:
    from ncgate.gateway.cli.check import FileReport
    from ncgate.gateway.programs import CheckedFile

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_BUG = 70  # EX_SOFTWARE (sysexits.h): an internal error


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ncgate",
        description="Modbus/CAN I/O gateway and PLC-logic co-simulator for multi-process CNC "
        "part programs.",
    )
    parser.add_argument("--version", action="version", version=f"ncgate {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    check = commands.add_parser(
        "check", help="parse and check part programs and PLC logic (.st)",
        description="Parse and check part programs and Structured Text PLC logic (.st files, "
        "checked together); print every diagnostic. With no FILE, check every program on the "
        "config's storage devices and its [plc] logic.",
    )
    check.add_argument("files", nargs="*", metavar="FILE",
                       help="program files, directories or globs")
    check.add_argument("--config", metavar="C", help="config file (default: ncgate.toml "
                       "beside each file, else the built-in default)")
    check.add_argument("--example", metavar="NAME", help="check the programs of an installed "
                       "example (see 'ncgate examples')")
    check.add_argument("--process", type=int, metavar="N",
                       help="the process the files run in (default: inferred from the main "
                       "program and EXE codes)")
    check.add_argument("--dialect", choices=[d.value for d in Dialect],
                       help="the programs' language (default: the config's nc.dialect)")
    check.add_argument("-q", "--quiet", action="store_true", help="no summary line")

    sim = commands.add_parser(
        "sim", help="closed simulation on the virtual clock",
        description="Run MAIN in process 1 on the virtual clock, the script playing the PLC "
        "(several programs: the first in process 1, the second in process 2, ...); "
        "print a summary table. Exit 0 when every program ended normally (or --until was "
        "reached with no alarm), 1 on an alarm, deadlock or stall, 2 on usage, config or "
        "program errors.",
    )
    sim.add_argument("main", nargs="*", metavar="MAIN",
                     help="the main program (default: the config's nc.main); more than one: "
                     "each starts in its own process, in order")
    sim.add_argument("--config", metavar="C", help="config file (default: built-in)")
    sim.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="set any config key, as with run (e.g. --set nc.lookahead=0)")
    sim.add_argument("--dialect", choices=[d.value for d in Dialect],
                     help="the programs' language (default: the config's nc.dialect)")
    sim.add_argument("--example", metavar="NAME", help="run an installed example: its config, "
                     "its script and its main program (see 'ncgate examples')")
    sim.add_argument("--junit", metavar="F.xml", help="write the scenarios' verdicts "
                     "([[expect]]) as JUnit XML, for CI")
    sim.add_argument("--script", metavar="S", action="append", default=[],
                     help="sim script: scripted PLC inputs, faults and expectations (TOML); "
                     "several: independent scenarios, each run on its own; "
                     "default: none, or the built-in one with the built-in config")
    sim.add_argument("--trace", metavar="T.jsonl", help="write the trace as JSON Lines")
    sim.add_argument("--until", type=float, metavar="SECONDS", help="stop at this time")
    sim.add_argument("--single-block", action="store_true", help="every process stops after "
                     "each block (STEP) until the script's next [[command]] step or "
                     "cycle_start")
    sim.add_argument("--break", dest="breaks", action="append", default=[], metavar="AT",
                     help="a breakpoint: PROG92:8 (file stem and line), N40 (any process), "
                     "'P2 N40', 'P2 wait', 'P2 wait EXE', sync (run to sync); a hit stops the "
                     "cell until the script's next cycle_start, or at once with --continue")
    sim.add_argument("--continue", dest="keep_going", action="store_true",
                     help="--break: each hit is traced, then the run goes on")
    sim.add_argument("--at", metavar="LABEL|N", help="block search: start the main program "
                     "at a label or an N number, with the modal state of the blocks before")
    sim.add_argument("--with-calc", action="store_true",
                     help="--at: the E parameters of the blocks before are calculated too")
    sim.add_argument("--gantt", metavar="G.svg", help="draw the timeline picture")
    sim.add_argument("--replay", metavar="R.jsonl", help="re-run a session recorded with "
                     "'ncgate run --record' (its config, programs and inputs) and say whether "
                     "it matches: exit 0 it does, 1 it diverges (the first divergence is "
                     "printed)")
    sim.add_argument("--tolerance-ms", type=float, default=10.0, metavar="MS",
                     help="--replay: how far apart in machine time a replayed event may be "
                     "from the recorded one (default 10)")

    run = commands.add_parser(
        "run", help="run the gateway (Modbus TCP, CANopen, web console) until SIGINT/SIGTERM",
        description="The soft PLC, the processes on the wall clock, the Modbus TCP server, "
        "the CANopen node and the web console (http://127.0.0.1:8080/), until SIGINT or "
        "SIGTERM (clean shutdown, exit 0; one before it serves, while it checks its "
        "programs, stops it there, exit 0 too).",
    )
    run.add_argument("--config", metavar="C", help="config file (default: built-in)")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="set any config key, e.g. --set nc.time_scale=10 --set "
                     "modbus.host=0.0.0.0 --set plant.model.clamp.travel_ms=900 (a TOML "
                     "value; a bare word is a string; an entry of an array of tables by its "
                     "name, number or [index])")
    run.add_argument("--port", type=int, metavar="N", help="the Modbus TCP port "
                     "(modbus.port)")
    run.add_argument("--rtu", metavar="DEVICE", help="also serve Modbus RTU on this serial "
                     "port, e.g. /dev/ttyUSB0 (modbus.rtu.port; 19200 bit/s, even parity "
                     "unless [modbus.rtu] says otherwise)")
    run.add_argument("--rtu-tcp", type=int, metavar="PORT", help="also serve Modbus RTU "
                     "frames on this TCP port, as a serial device server carries them "
                     "(modbus.rtu_tcp.port)")
    web = run.add_mutually_exclusive_group()
    web.add_argument("--web", metavar="HOST:PORT", help="serve the console here "
                     "(web.host, web.port; default 127.0.0.1:8080)")
    web.add_argument("--no-web", action="store_true", help="no web console")
    run.add_argument("--opcua", type=int, metavar="PORT", help="serve OPC UA on this port "
                     "(opcua.enabled, opcua.port; docs/opcua.md)")
    run.add_argument("--record", metavar="R.jsonl", help="record the session (every input "
                     "from outside, with its time, beside the trace) for 'ncgate sim "
                     "--replay'")
    run.add_argument("--script", metavar="S.toml", help="play a scenario on the wall clock "
                     "while real clients are connected: its writes and faults at their times, "
                     "its [[expect]] judged as in sim (PASS/FAIL lines); it starts the main "
                     "program itself (nc.autostart off), and that moment is its t = 0; it stops "
                     "at its last window's end, exit 1 when an expectation failed (docs/script.md)")
    run.add_argument("--junit", metavar="F.xml", help="with --script: write its verdicts as "
                     "JUnit XML for CI, as sim --junit does (written when the scenario ends, "
                     "whole or not at all)")
    run.add_argument("--trace", metavar="T.jsonl", help="write every event as JSON Lines, "
                     "rotated at trace.max_mb (default: none; memory keeps trace.ring events)")
    run.add_argument("--loop", choices=("auto", "asyncio", "uvloop"), default="auto",
                     help="the event loop: uvloop serves Modbus faster (bench/modbus.py); auto "
                     "takes it when installed (pip install 'ncgate[fast]')")
    loud = run.add_mutually_exclusive_group()
    loud.add_argument("-v", "--verbose", action="count", default=0, help="-v: ncgate's "
                      "debug lines too (PLC writes); -vv: the libraries' as well")
    loud.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only")
    run.add_argument("--cold", action="store_true", help="start the PLC logic without its "
                     "stored VAR RETAIN values (they are cleared)")
    run.add_argument("--watch", action="store_true", help="reload the PLC logic when one of "
                     "its files changes (online change: between two scans, values kept)")
    run.add_argument("--allow-missing", action="store_true", help="start even when the main "
                     "program is missing or has errors, or a storage folder does not exist "
                     "(a cell whose programs arrive later); default: refuse, with the "
                     "diagnostics of 'ncgate check'")

    _add_sweep(commands)

    map_ = commands.add_parser("map", help="print the Modbus map in force",
                               description="The Modbus map in force, with 0-based and 1-based "
                               "(0xxxx/1xxxx/3xxxx/4xxxx) addresses, types and access.")
    map_.add_argument("--config", metavar="C", help="config file (default: built-in)")
    map_.add_argument("--format", choices=("md", "csv", "json"), default="md")
    map_.add_argument("--bus", choices=("modbus", "canopen"),
                      help="only this bus (CSV holds one table: default modbus)")

    commands.add_parser("examples", help="list the installed examples",
                        description="The manual's examples installed with ncgate: name, main "
                        "program, what happens, and the folder they are in.")

    eds = commands.add_parser("eds", help="write the CANopen node's EDS file",
                              description="Write the node's EDS (CiA 306) for your CANopen "
                              "configuration tool.")
    eds.add_argument("--config", metavar="C", help="config file (default: built-in)")
    eds.add_argument("-o", "--output", metavar="FILE", required=True,
                     help="the .eds file (-: standard output)")
    return parser


def _subparsers(parser: argparse.ArgumentParser) -> argparse._SubParsersAction[
        argparse.ArgumentParser]:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:  # said by the command's own parser: its usage, not the top level's
            command = _subparsers(parser).choices[args.command]
            command.error(f"unrecognized arguments: {' '.join(extra)}")
    except SystemExit as exc:  # argparse exits 2 on usage errors, 0 on --help
        return int(exc.code or 0)
    try:
        if args.command == "check":
            return _check(args)
        if args.command == "sim":
            return _sim(args)
        if args.command == "run":
            return _run(args)
        if args.command == "map":
            return _map(args)
        if args.command == "sweep":
            return _sweep(args)
        if args.command == "eds":
            return _eds(args)
        if args.command == "examples":
            return _examples()
    except (ProgramError, LogicError) as exc:  # diagnostics, each with its source line
        print(str(exc), file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:
        # `ncgate map | head`: the reader has what it wanted, and map only prints.  A command
        # whose status says what it found (sim, sweep) writes through stdout(), and check
        # catches its own: they never get here.
        stdout_gone()
        return EXIT_OK
    except (NcgateError, OSError) as exc:  # ours, or the system's (a path, a port): said
        print(f"ncgate {args.command}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except Exception:  # anything else is a bug of ncgate: show it whole
        traceback.print_exc()
        print(f"ncgate {args.command}: this is a bug in ncgate {__version__}; please report "
              "it with the traceback above and the command that gave it", file=sys.stderr)
        return EXIT_BUG
    parser.error(f"unknown command {args.command}")
    return EXIT_USAGE  # not reached: parser.error exits


def _check(args: argparse.Namespace) -> int:
    from ncgate.gateway.cli.check import (
        LOGIC_SUFFIXES,
        check_files,
        config_for,
        expand,
        storage_files,
    )

    if args.example:
        if args.config or args.files:
            raise UsageError("--example goes without --config and FILE")
        example = find_example(args.example)
        args.files = [str(example.folder)]
        args.config = str(example.config) if example.config.is_file() else None
    # check opens no server: what only a server needs (the console's bind) is not its concern
    config = load_config(args.config, serving=False) if args.config else None
    err = stderr()
    # The cells whose [plc] and [plant] logic is checked as sim and run load it (its PROGRAMs
    # chosen): --config's (or --example's), and without it the config beside a logic file
    # named that is its own -- the config check takes for that file's folder.
    cells: list[Config] = []
    named: dict[Path, Path] = {}  # a file named on the command line: as named
    if args.files:
        files, again = expand(args.files)
        named = {path.resolve(): path for path in (*again, *files)}
        for path in again if not args.quiet else ():
            print(f"ncgate check: {path} is given twice: checked once", file=err)
        if config is not None:
            # Its own logic is checked as the cell loads it, also when named; another ST
            # file named is checked alone (a library's may hold no PROGRAM).
            cells.append(config)
            files = [path for path in files if path.resolve() not in _own_logic(config)]
        else:
            taken: set[Path] = set()
            files = _beside_cells(files, cells, taken)
            _beside_cells(again, cells, taken)  # (one file, two cells' logic: each cell's)
    else:
        cells.append(config or load_config(None, serving=False))
        _require_default_device(cells[0])
        own = _own_logic(cells[0])  # (its logic may lie among its programs: plc.txt)
        files = [path for path in storage_files(cells[0]) if path.resolve() not in own]
    if not files and not any(cell.plc.logic or cell.plant.logic for cell in cells):
        raise UsageError("no program to check")
    if args.process is not None:
        # The processes of the config each file is checked under (the one beside it, when
        # no --config): a process every one of them has.
        one_each = {path.parent.resolve(): path for path in files}.values()
        used = [config] if config is not None else [
            config_for(path, None) for path in one_each] or cells
        count = min((c.nc.processes for c in used),
                    default=load_config(None, serving=False).nc.processes)
        if not 1 <= args.process <= count:
            raise UsageError(f"--process {args.process}: expected 1..{count}")
    dialect = Dialect(args.dialect) if args.dialect else None
    programs = check_files(files, config, args.process, dialect) if files else []
    reports = _one_per_file(
        programs + [report for cell in cells for report in _check_config_logic(cell, named)])
    errors = sum(r.errors for r in reports)
    warnings = sum(r.warnings for r in reports)
    # `ncgate check | head -1` (or `2>&1 | head -1`): the reader has what it wanted, and the
    # status is still what was found (main's exit 0 is map's: it only prints).
    out = stdout()
    for report in reports:
        for diagnostic in report.diagnostics:
            print(diagnostic.render(), file=out)
    out.flush()  # (a pipe's buffer: its error here, not at the interpreter's exit)
    if not args.quiet:
        print(f"{len(reports)} file(s) checked: {errors} error(s), {warnings} warning(s)",
              file=err)
    if errors and dialect is None:
        _suggest_dialect("check", [(r.path, config_for(r.path, config)) for r in programs
                                   if r.errors and r.path.suffix.lower() not in LOGIC_SUFFIXES])
    err.flush()
    return EXIT_FAILED if errors else EXIT_OK


def _one_per_file(reports: list[FileReport]) -> list[FileReport]:
    """One report per file, in order: a file that is both a cell's PLC and plant logic (or
    two cells' logic) is checked in each role, and what two roles found alike is said and
    counted once -- its one error was "2 error(s)" in "3 file(s) checked" of two files."""
    from ncgate.gateway.cli.check import FileReport

    merged: dict[Path, FileReport] = {}
    for report in reports:
        key = report.path.resolve()
        before = merged.get(key)
        if before is None:
            merged[key] = report
            continue
        said = {d.render() for d in before.diagnostics}
        merged[key] = FileReport(before.path, before.diagnostics + tuple(
            d for d in report.diagnostics if d.render() not in said))
    return list(merged.values())


def _own_logic(config: Config) -> set[Path]:
    return {path.resolve() for path in (*config.plc.logic, *config.plant.logic)}


def _beside_cells(files: list[Path], cells: list[Config], taken: set[Path]) -> list[Path]:
    """``files`` but the logic files that are the own of the config beside them (an
    ``ncgate.toml``: the config check takes for their folder; whatever their names end
    in), whose configs go to ``cells``: ``check plc.st`` of a cell's logic refuses what
    ``sim`` beside it refuses (plc.programs naming no PROGRAM of it).  ``taken``: the
    configs whose cells are in ``cells`` already."""
    from ncgate.gateway.cli.check import CONFIG_BESIDE

    found: dict[Path, tuple[Config, set[Path]]] = {}
    rest = []
    for path in files:
        beside = (path.parent / CONFIG_BESIDE).resolve()
        if beside.is_file():
            if beside not in found:
                cell = load_config(beside, serving=False)
                found[beside] = (cell, _own_logic(cell))
            cell, own = found[beside]
            if path.resolve() in own:
                if beside not in taken:
                    taken.add(beside)
                    cells.append(cell)
                continue
        rest.append(path)
    return rest


def _check_config_logic(config: Config, named: dict[Path, Path] | None = None
                        ) -> list[FileReport]:
    """What `run` and `sim` refuse of the config's PLC and plant before a cell starts, in
    their order: the PLC's logic and the PROGRAMs it runs, the plant's models' variables (one
    driven by two models, a number on a bit), and the plant's own logic, checked alone (a task
    of its own: it shares no name with the PLC's).  A refusal of the config itself is its
    ConfigError (exit 2), as `sim` says it.  ``named``: a logic file's resolved path -> the
    path the command line gave it, which its diagnostics say (the config's is whole)."""
    from dataclasses import replace

    from ncgate.gateway.cli.check import check_logic
    from ncgate.gateway.plant import Plant
    from ncgate.gateway.plc import shared_writes
    from ncgate.gateway.wiring import build_runtime
    from ncgate.plc.st.logic import Logic

    named = named or {}
    reports = []
    logics: dict[str, list[Logic]] = {"plc": [], "plant": []}
    plc = [named.get(path.resolve(), path) for path in config.plc.logic]
    if plc:
        found = check_logic(plc, config, "plc", logics["plc"])
        reports += [found[path] for path in plc]
    if config.plant.model:
        Plant(build_runtime(config, closed=True), lambda item: None, closed=True)
    plant = [named.get(path.resolve(), path) for path in config.plant.logic]
    if plant:
        found = check_logic(plant, config, "plant", logics["plant"])
        reports += [found[path] for path in plant]
    # SW006: a variable a logic writes that another writer writes too, in the file of the
    # logic's write (a file both logics load gets it once).
    shared = shared_writes(config, *(found[0] if found else None for found in logics.values()))
    for i, report in enumerate(reports):
        more = [d for d in shared if d.span.file == str(report.path)
                and d not in report.diagnostics]
        if more:
            reports[i] = replace(report, diagnostics=(*report.diagnostics, *more))
            shared = [d for d in shared if d not in more]
    return reports


def _sim(args: argparse.Namespace) -> int:
    from ncgate.config.script import load_script
    from ncgate.gateway.programs import storage_of
    from ncgate.gateway.sim import report, run_sim, write_trace
    from ncgate.gateway.timeline import write_gantt

    for option, file in (("--junit", args.junit), ("--trace", args.trace),
                         ("--gantt", args.gantt)):
        if file:  # before the run (or the suite, or the replay), not after it
            _check_output_folder(option, file)
    if args.junit:
        _check_replaced_whole("--junit", args.junit)
    if args.replay:
        return _replay(args)
    if args.until is not None and args.until < 0:
        raise UsageError("--until: expected a time >= 0")
    shown: dict[str, str] = {}  # a scenario's name in the report and the JUnit XML
    if args.example:
        if args.config:
            raise UsageError("--example goes without --config")
        example = find_example(args.example)
        if example.main is None:
            raise UsageError(f"the {example.name} example has no program to run: "
                             f"ncgate check --example {example.name}")
        args.config = str(example.config)
        if not args.script:
            args.script = [str(s) for s in example.scripts]
            shown = {str(s): _relative(s, example.folder, example.name) for s in example.scripts}
        args.main = args.main or [example.main]
    overrides = _set_overrides(args.set)
    origins = dict.fromkeys(overrides, "--set")
    if args.dialect:
        overrides["nc.dialect"] = args.dialect
        origins["nc.dialect"] = "--dialect"
    own = None if args.config else _programs_here(args.main, overrides)
    if own is not None:  # sim FILE without --config: the file's folder is MP0, as check finds it
        overrides["nc.storage.MP0"], args.main = own
        origins["nc.storage.MP0"] = "the program's folder"
    config = load_config(args.config, overrides=overrides, origins=origins, serving=False)
    _require_default_device(config)
    # The built-in config comes with its PLC script (for its own PROG91); a user's config, or
    # a user's program run on the built-in one, with none unless given.
    files = args.script or ([None] if args.config or own else [default_script_path()])
    scripts = [load_script(f) for f in files]
    mains = args.main or [config.nc.main]
    if len(scripts) > 1 and (args.trace or args.gantt):
        raise UsageError("--trace and --gantt take one scenario: give one --script")
    if len(scripts) > 1:  # each checked on the cell before the first runs
        from ncgate.gateway.sim import check_scenario

        for script in scripts:
            check_scenario(config, script, until=args.until)
    status = EXIT_OK
    verdicts = []
    # `sim | head -1`: a reader that goes early stops neither the scenarios nor the files
    # written after them, and the status is still what the simulation found.
    output = stdout()
    for i, script in enumerate(scripts):  # each an independent scenario, on a runtime of its own
        name = shown.get(script.file) or _relative(Path(script.file), Path.cwd())
        if len(scripts) > 1:
            print(f"== {name}", file=output)
        try:
            result = run_sim(config, mains, script, args.until, signals=True,
                             single_block=args.single_block, breaks=args.breaks,
                             keep_going=args.keep_going, at=args.at, with_calc=args.with_calc,
                             warn=i == 0)  # (one cell: its logic's warnings once, not per scenario)
        except ProgramError as exc:
            print(str(exc), file=sys.stderr)
            storage = storage_of(config)
            _suggest_dialect("sim", [(path, config) for name in mains
                                     if (path := storage.find(name)) is not None])
            return EXIT_USAGE
        report(result, output)
        verdicts.append((name, result.verdicts))
        status = max(status, result.exit_status)
    if args.junit:
        from ncgate.gateway.scenario import save_junit

        save_junit(Path(args.junit), verdicts)
    if len(scripts) > 1:
        failed = sum(1 for _, items in verdicts for v in items if not v.ok)
        total = sum(len(items) for _, items in verdicts)
        print(f"{len(scripts)} scenarios: {total - failed} of {total} expectations passed",
              file=output)
        output.flush()
        return status
    if args.trace:
        with open(args.trace, "w", encoding="utf-8") as out:
            write_trace(result, out)
    if args.gantt:
        with open(args.gantt, "w", encoding="utf-8") as out:
            write_gantt(result.events, result.runtime.config.nc.processes, out,
                        external=result.runtime.config.nc.external)
    output.flush()
    return result.exit_status


def _check_output_folder(option: str, file: str) -> None:
    """An output file's folder exists and can be written, before the work that fills it."""
    folder = Path(file).parent
    if Path(file).is_dir():
        raise UsageError(f"{option} {file}: is a folder: name a file in it")
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{option} {file}: {str(folder)!r} is a file, not a folder")
    if not folder.is_dir():
        raise UsageError(f"{option} {file}: no folder {str(folder)!r} to write it in")
    if not os.access(folder, os.W_OK):
        raise UsageError(f"{option} {file}: the folder {str(folder)!r} cannot be written")


def _check_replaced_whole(option: str, file: str) -> None:
    """A file written whole (a temporary file renamed over it) is a regular file, or none
    yet: a FIFO or a device would be replaced, not written to."""
    try:
        mode = os.stat(file).st_mode
    except FileNotFoundError:
        return
    except OSError as exc:
        raise UsageError(f"{option} {file}: {exc.strerror}") from None
    if not stat.S_ISREG(mode):
        raise UsageError(f"{option} {file}: not a regular file (it is written whole, a "
                         "temporary file renamed over it)")


def _relative(path: Path, base: Path, prefix: str = "") -> str:
    """``path`` as a name for people and CI: relative to ``base`` when inside it (with
    ``prefix/`` before it), else as given."""
    try:
        inside = path.resolve().relative_to(base.resolve()).as_posix()
    except ValueError:
        return str(path)
    return f"{prefix}/{inside}" if prefix else inside


def _programs_here(mains: list[str], overrides: dict[str, Any]) -> tuple[str, list[str]] | None:
    """``ncgate sim FILE ...`` on the built-in config: when every MAIN is a program file in one
    folder (``A.nc``, ``work/A``), that folder as MP0 and the programs' names; None when the
    names are the built-in storage's (``PROG91``) or MP0 is given."""
    from ncgate.interpreter.storage import PROGRAM_SUFFIXES

    if not mains or "nc.storage.MP0" in overrides:
        return None
    found = []
    for main in mains:
        path = Path(main)
        file = next((path.with_name(path.name + s) for s in PROGRAM_SUFFIXES
                     if path.with_name(path.name + s).is_file()), None)
        if file is None and path.is_file():
            file = path
        if file is None:
            return None
        found.append(file.resolve())
    folders = {f.parent for f in found}
    if len(folders) != 1:
        return None
    return str(folders.pop()), [f.name[:-len(f.suffix)] if f.suffix else f.name for f in found]


def _replay(args: argparse.Namespace) -> int:
    from ncgate.gateway.record import replay
    from ncgate.gateway.timeline import write_gantt
    from ncgate.interpreter.engine.trace import write_jsonl

    if args.main or args.example or args.script or args.until is not None:
        raise UsageError("--replay takes its programs, inputs and end from the record: it goes "
                         "without MAIN, --example, --script and --until")
    result = replay(args.replay, args.config, args.tolerance_ms)
    for warning in result.warnings:
        print(f"ncgate sim: warning: {warning}", file=sys.stderr)
    if args.trace:
        with open(args.trace, "w", encoding="utf-8") as out:
            write_jsonl(result.events, out)
    if args.gantt:
        config = result.runtime.config.nc
        with open(args.gantt, "w", encoding="utf-8") as out:
            write_gantt(result.events, config.processes, out, external=config.external)
    recording = result.recording
    output = stdout()  # (`sim --replay R | head -1`: the status is still the replay's)
    print(f"replayed {args.replay}: {len(recording.inputs)} inputs over "
          f"{recording.end:.3f} s of machine time"
          + ("" if recording.stop is not None else " (the session did not stop cleanly)"),
          file=output)
    if result.divergence is not None:
        print(result.divergence, file=output)
        output.flush()
        return EXIT_FAILED
    if not result.compared:  # (a session whose processes did nothing: no "match" to claim)
        print("nothing to compare: the session recorded no event of the processes (the "
              "image's and the plant's writes are replayed, not compared)", file=output)
    else:
        print(f"the replay matches: {result.compared} events of the processes, in the same "
              f"order, within {args.tolerance_ms:g} ms", file=output)
    output.flush()
    return EXIT_OK


def _require_default_device(config: Config) -> None:
    """The folder of the default storage device exists (else no program can be found)."""
    from ncgate.gateway.cli.check import missing_devices

    missing = missing_devices(config).get(config.nc.storage.default)
    if missing is not None:
        raise UsageError(missing)


def _suggest_dialect(command: str, files: Sequence[tuple[Path, Config]]) -> None:
    """After a program's errors: when another dialect reads a file without one, the file is
    most likely in that language (an ISG file given to NC-110); say which --dialect to give."""
    from ncgate.gateway.cli.check import other_dialect

    readable: dict[str, list[str]] = {}
    for path, config in files:
        other = other_dialect([path], config, config.nc.dialect)
        if other is not None:
            readable.setdefault(other.value, []).append(path.name)
    for name, found in readable.items():
        verb = "reads" if len(found) == 1 else "read"
        print(f"ncgate {command}: {', '.join(found)} {verb} without error as {name}: give "
              f"--dialect {name} (or set nc.dialect = \"{name}\" in the config)",
              file=stderr())


def _set_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``--set KEY=VALUE`` as config overrides: the value is TOML, a bare word a string."""
    import tomllib

    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"--set {item!r}: expected KEY=VALUE, e.g. nc.time_scale=10")
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text  # a bare word: a string (--set nc.main=PROG91)
        out[key.strip()] = value
    return out


def _overrides(args: argparse.Namespace) -> tuple[dict[str, Any], dict[str, str]]:
    """``--set``, ``--port``, ``--rtu``, ``--rtu-tcp``, ``--web``, ``--no-web``, ``--opcua``,
    ``--trace`` as config overrides, and the option each key came from (an error names it)."""
    out = _set_overrides(args.set)
    origins = dict.fromkeys(out, "--set")
    if args.port is not None:
        out["modbus.port"] = args.port
        origins["modbus.port"] = "--port"
    if args.rtu is not None:
        out["modbus.rtu.port"] = args.rtu
        origins["modbus.rtu.port"] = "--rtu"
    if args.rtu_tcp is not None:
        out["modbus.rtu_tcp.port"] = args.rtu_tcp
        origins["modbus.rtu_tcp.port"] = "--rtu-tcp"
    if args.web:
        host, sep, port = args.web.rpartition(":")
        if not sep or not port.isdigit() or not host:
            raise UsageError(f"--web {args.web!r}: expected HOST:PORT, e.g. 127.0.0.1:8080")
        out["web.host"] = host.strip("[]")
        out["web.port"] = int(port)
        origins["web.host"] = origins["web.port"] = "--web"
    if args.no_web:
        out["web.enabled"] = False
        origins["web.enabled"] = "--no-web"
    if args.opcua is not None:
        out["opcua.enabled"], out["opcua.port"] = True, args.opcua
        origins["opcua.enabled"] = origins["opcua.port"] = "--opcua"
    if args.trace:
        out["trace.file"] = str(Path(args.trace).resolve())
        origins["trace.file"] = "--trace"
    return out, origins


class _StoppedBeforeServing(BaseException):
    """A SIGINT or SIGTERM before ``run`` serves, raised in the main thread wherever it is
    (the start-up check of a big program, an import) and caught in :func:`_run`.  A
    BaseException, as KeyboardInterrupt is, so that no ``except Exception`` on the way
    swallows it."""

    def __init__(self, signum: int) -> None:
        self.name = signal.Signals(signum).name
        super().__init__(self.name)


def _stop_before_serving(signum: int, frame: object) -> None:
    raise _StoppedBeforeServing(signum)


def _run(args: argparse.Namespace) -> int:
    # Until serve() hands SIGINT and SIGTERM to the event loop, they are ours: the check of
    # a 3 MB main program takes seconds, and the default action would end the process then
    # with no word (status -15), where a service manager expects a prompt, said, clean stop.
    # Python runs the handler in the main thread between two bytecodes: it stops the check
    # at once, but for a call into C, the longest of which (freeing the parse of every
    # block) held it 70 ms for a 2.7 MB program.  A signal after the handlers are handed
    # back and before the loop takes them (while the loop is made) is the default's.
    previous = {sig: signal.signal(sig, _stop_before_serving)
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            serving = _before_serving(args)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    except _StoppedBeforeServing as exc:
        # The same exit as a stop once serving (serve() returns; exit 0): the stop was asked
        # for, and nothing had started that it cut short.
        print(f"ncgate run: stopped before serving ({exc.name})", file=sys.stderr)
        return EXIT_OK
    if serving is None:
        return EXIT_USAGE
    return EXIT_FAILED if serving() else EXIT_OK


def _before_serving(args: argparse.Namespace) -> Callable[[], int] | None:
    """Everything ``run`` does before it serves: the log, the config, the start-up check
    of its programs, the interpreter's tuning and the event loop.  Returns the call that
    serves until SIGINT or SIGTERM, or None when the programs cannot run (said)."""
    import asyncio
    import importlib.metadata
    import importlib.util
    import logging

    from ncgate.gateway.cli.serve import serve

    # ncgate's loggers ("ncgate", "ncgate.web", ...) and the libraries' apart: -v shows
    # ncgate's debug lines (PLC writes), -vv the libraries' step-by-step logging as well.
    logging.basicConfig(level=logging.DEBUG if args.verbose >= 2 else logging.WARNING,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("ncgate").setLevel(
        logging.WARNING if args.quiet else logging.DEBUG if args.verbose else logging.INFO)
    overrides, origins = _overrides(args)
    if args.script:
        # The scenario starts the main program itself, at its t = 0, as sim does: an
        # autostart before it would make its times the gateway's start-up's (docs/script.md).
        overrides["nc.autostart"] = False
        origins["nc.autostart"] = "--script"
    config = load_config(args.config, overrides=overrides, origins=origins)
    checked: tuple[CheckedFile, ...] = ()  # --allow-missing: nothing
    if not args.allow_missing:
        ready = _programs_ready(config)
        if ready is None:
            return None
        checked = ready
    junit = None
    if args.junit:
        if not args.script:
            raise UsageError("--junit goes with --script: it writes the scenario's verdicts")
        _check_output_folder("--junit", args.junit)
        _check_replaced_whole("--junit", args.junit)
        junit = (Path(args.junit).resolve(), _relative(Path(args.script), Path.cwd()))
    record = str(Path(args.record).resolve()) if args.record else None
    if record is not None and Path(record).is_dir():
        raise UsageError(f"--record {args.record}: is a folder: give the record a file name")
    if record is not None and config.trace.file is not None and (
            Path(config.trace.file).resolve() == Path(record)):
        raise UsageError(f"--record {args.record}: it is the trace file too (trace.file): "
                         "each would overwrite the other; give the record another name")
    # The loop shares the interpreter with python-can's receive thread, the CANopen hub and
    # a program being read: a thread that wants the GIL gets it within GIL_SWITCH_S (0.2 ms),
    # not CPython's default 5 ms, so none of them makes another late (measured with
    # bench/storm.py: the flood, storm and load phases); and the young generation's size
    # (lifecycle.GC_YOUNG_OBJECTS).  Put back when it returns: `main(["run", ...])` in a
    # test left them to every test after it in that process.
    loop = args.loop
    if loop == "auto":
        loop = "uvloop" if importlib.util.find_spec("uvloop") is not None else "asyncio"
    run: Callable[[Coroutine[Any, Any, int]], int] = asyncio.run
    if loop == "uvloop":
        try:
            import uvloop
        except ImportError:
            raise UsageError("--loop uvloop: uvloop is not installed (pip install "
                             "'ncgate[fast]')") from None
        logging.getLogger("ncgate").info("event loop: uvloop %s",
                                         importlib.metadata.version("uvloop"))
        run = uvloop.run
    else:
        logging.getLogger("ncgate").info("event loop: asyncio")
    script = None
    if args.script:
        from ncgate.config.script import load_script
        from ncgate.gateway.sim import check_scenario

        script = load_script(args.script)
        check_scenario(config, script, sim=False)  # on the cell, before anything serves:
        # a PLC that connected at once wrote to a gateway that then refused its script

    def tuned() -> int:
        restore = tune_interpreter()
        try:
            return run(serve(config, cold=args.cold, record=record, overrides=overrides,
                             watch=args.watch, checked=checked, script=script, junit=junit))
        finally:
            restore()
    return tuned


def _programs_ready(config: Config) -> tuple[CheckedFile, ...] | None:
    """Whether ``run`` can run its configured programs: what it checked and found no error
    in (for the program store), or None after saying why not (as ``check`` does) and how to
    start anyway.  Otherwise the first sign would be an alarm at cycle start."""
    from ncgate.gateway.cli.check import start_problems

    found = start_problems(config)
    for report in found.reports:
        for diagnostic in report.diagnostics:
            print(diagnostic.render(), file=sys.stderr)
    for problem in found.problems:
        print(f"ncgate run: {problem}", file=sys.stderr)
    if not found.problems and not found.reports:
        return found.checked
    print("ncgate run: not started: the configured programs cannot run (give --allow-missing "
          "to start anyway, for a cell whose programs arrive later)", file=sys.stderr)
    return None


def _add_sweep(commands: Any) -> None:
    sweep = commands.add_parser(
        "sweep", help="run every variant of a spec as independent sims, into one table",
        description="Run each variant of SPEC.toml (programs x scripts x [grid] x [random]) "
        "as an independent 'ncgate sim', on every core or a Dask cluster; write one row per "
        "variant, sorted by id (docs/sweep.md). Exit 0 when every row is ok, 1 when one is "
        "not, 2 on a bad spec.")
    sweep.add_argument("spec", metavar="SPEC.toml")
    sweep.add_argument("-o", "--output", metavar="FILE", help="the table (default: "
                       "SPEC's name with .csv or .parquet, in the working folder; -: "
                       "standard output, the summary then on stderr)")
    sweep.add_argument("--format", choices=("csv", "parquet"), default="csv")
    sweep.add_argument("--workers", type=int, metavar="N", help="local worker processes "
                       "(default: one per core)")
    sweep.add_argument("--scheduler", metavar="URL", help="run on a Dask cluster "
                       "(tcp://HOST:8786; pip install 'ncgate[dask]')")
    sweep.add_argument("--resume", action="store_true", help="continue a stopped sweep: "
                       "run only the variants its parts lack")
    sweep.add_argument("--timeout", type=float, default=60.0, metavar="S", help="wall-clock "
                       "seconds a variant may run (then: a timeout row; default 60, 0: none)")
    sweep.add_argument("--explore", type=int, metavar="N", help="run N seeded random timing "
                       "variants per program and group the failures by signature")
    sweep.add_argument("-q", "--quiet", action="store_true", help="no progress line")


def _sweep(args: argparse.Namespace) -> int:
    from ncgate.gateway.sweep.main import Options
    from ncgate.gateway.sweep.main import main as sweep

    if args.workers is not None and args.workers < 1:
        raise UsageError("--workers: expected 1 or more")
    if args.timeout < 0:
        raise UsageError("--timeout: expected seconds >= 0")
    if args.explore is not None and args.explore < 1:
        raise UsageError("--explore: expected 1 or more")
    suffix = ".parquet" if args.format == "parquet" else ".csv"
    stem = Path(args.spec).stem + ("-explore" if args.explore else "")
    output: Path | None = Path(args.output) if args.output else Path(stem + suffix)
    if args.output == "-":  # standard output, as eds -o - (a file named "-" is ./-)
        output = None
    options = Options(output, args.format, args.workers, args.scheduler, args.resume,
                      args.timeout or None, False if args.quiet else None)
    return sweep(args.spec, options, explore=args.explore)


def _map(args: argparse.Namespace) -> int:
    import csv
    import json

    from ncgate.gateway.canopen.dictionary import dictionary_rows
    from ncgate.gateway.modbus.map import ModbusMap

    config = load_config(args.config, serving=False)  # map and eds open no server
    buses = [args.bus] if args.bus else (["modbus"] if args.format == "csv" else
                                         ["modbus", "canopen"])
    rows = dictionary_rows(config) if "canopen" in buses else []
    plant = plant_rows(config) if not args.bus else []
    if args.format == "json":
        data = json.loads(ModbusMap(config).render("json")) if "modbus" in buses else {}
        if rows:
            data["canopen"] = {"node_id": config.canopen.node_id, "objects": rows}
        if plant:
            data["plant"] = plant
        sys.stdout.write(json.dumps(data, indent=2) + "\n")
    elif args.format == "csv":
        if buses == ["canopen"]:
            writer = csv.DictWriter(sys.stdout, fieldnames=list(rows[0]), lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
        else:
            sys.stdout.write(ModbusMap(config).render("csv"))
    else:
        if "modbus" in buses:
            sys.stdout.write(ModbusMap(config).render("md"))
        if rows:
            sys.stdout.write(f"\n# CANopen dictionary (node {config.canopen.node_id})\n\n"
                             "| index | sub | name | type | access | default |\n"
                             "|---|---|---|---|---|---|\n")
            for r in rows:
                default = "" if r["default"] is None else r["default"]
                sys.stdout.write(f"| {r['index']} | {r['sub']} | {r['name']} | {r['type']} | "
                                 f"{r['access']} | {default} |\n")
        if config.opcua.enabled and not args.bus:
            _ua_nodes(config)
        if plant:
            sys.stdout.write("\n# Plant models (docs/plant.md)\n\n| model | kind | reads | "
                             "writes |\n|---|---|---|---|\n")
            for m in plant:
                # (a model's variables by its keys; the logic's, a list, by themselves)
                reads, writes = (", ".join(
                    [f"{k} {v}" for k, v in m[key].items()] if isinstance(m[key], dict)
                    else m[key]) or "—" for key in ("reads", "writes"))
                sys.stdout.write(f"| {m['name']} | {m['kind']} | {reads} | {writes} |\n")
    return EXIT_OK


def _ua_nodes(config: Config) -> None:
    """The OPC UA nodes beside the registers (``[opcua]`` enabled; docs/opcua.md)."""
    from ncgate.gateway.opcua.model import machine_name, node_rows

    cell = machine_name(config.source)
    plc = config.plc
    rows = node_rows(cell, list(range(1, config.nc.processes + 1)),
                     {"sa_bits": plc.sa_bits, "k_bytes": plc.k_bytes, "syvars": plc.syvars},
                     config.opcua.writable, dict(config.symbols))
    sys.stdout.write("\n# OPC UA nodes (docs/opcua.md)\n\n| browse path | node id | type | "
                     "access | what |\n|---|---|---|---|---|\n")
    for row in rows:
        sys.stdout.write("| " + " | ".join(row) + " |\n")


def plant_rows(config: Config) -> list[dict[str, Any]]:
    """Each plant model and the variables it reads and writes (an I/O name as its variable
    too: ``clamp_valve (SA20)``)."""
    from ncgate.config.plant import MODEL_KEYS

    symbols = {name.upper(): text for name, text in config.symbols.items()}

    def shown(text: str) -> str:
        found = symbols.get(text.upper())
        return f"{text} ({found})" if found else text

    out = []
    for model in config.plant.model:
        spec = MODEL_KEYS[model.kind]
        out.append({"name": model.name, "kind": model.kind,
                    "reads": {k: shown(v) for k, v in model.keys.items() if spec[k][0] == "in"},
                    "writes": {k: shown(v) for k, v in model.keys.items()
                               if spec[k][0] == "out"}})
        if model.kind == "switch":
            out[-1]["reads"] = {"axis": str(model.keys["axis"])}
    if config.plant.logic:
        out.append(_plant_logic_row(config))
    return out


def _plant_logic_row(config: Config) -> dict[str, Any]:
    """The plant's ST logic as a row of the plant's table: the image variables it reads and
    writes at constant places (a computed place: the area, ``SA[…]``)."""
    from ncgate.config import ConfigError
    from ncgate.gateway.plc import PLACE_VIEW, io_namer, prepare_logic
    from ncgate.plc.st.diagnostics import LogicError

    files = ", ".join(path.name for path in config.plant.logic)
    row: dict[str, Any] = {"name": "(logic)", "kind": f"st: {files}, every "
                           f"{config.plant.scan_ms} ms", "reads": {}, "writes": {}}
    try:
        prepared = prepare_logic(config, "plant")
    except (LogicError, ConfigError, OSError):
        row["kind"] += " (does not load: ncgate check says why)"
        return row
    assert prepared is not None
    logic = prepared.logic

    shown = io_namer(config)

    def named(places: Iterable[tuple[str, int]]) -> list[str]:
        return [shown(area, index, PLACE_VIEW[area]) for area, index in sorted(
            places, key=lambda p: (list(PLACE_VIEW).index(p[0]), p[1]))]

    order = prepared.order  # (what the PROGRAMs run reach: a block with no instance is not)
    computed_reads, computed_writes = logic.computed(order)
    for key, places, computed in (
            ("reads", logic.image_reads(order), computed_reads),
            ("writes", logic.image_writes(order), computed_writes)):
        row[key] = [*named(places), *(f"{area}[…]" for area in sorted(computed))]
    return row


def _eds(args: argparse.Namespace) -> int:
    from ncgate.gateway.canopen.dictionary import write_eds

    config = load_config(args.config, serving=False)
    if args.output == "-":  # (a file named "-" is ./-)
        out = stdout()
        write_eds(config, "ncgate.eds", out)
        out.flush()
        return EXIT_OK
    write_eds(config, args.output)
    print(f"wrote {args.output}", file=sys.stderr)
    return EXIT_OK


def _examples() -> int:
    found = examples()
    width = max((len(e.name) for e in found), default=0)
    mains = max((len(e.main or "-") for e in found), default=0)
    out = stdout()  # (`examples | head -0`: the reader gone, where they are is still said)
    for example in found:
        main = example.main or "-"
        print(f"{example.name:<{width}} {main:<{mains}} {example.summary}", file=out)
    print(f"installed in {examples_folder()}", file=stderr())
    return EXIT_OK


def entry_point() -> None:
    closed_streams()  # (`ncgate check >&-`: its status, not a traceback)
    status = main()
    # The last of standard output, here: a reader gone by the interpreter's own last flush
    # (`ncgate map --format csv | head -0`: its 3 KB sit in a pipe's buffer until then) made
    # it "Exception ignored ... BrokenPipeError" and exit 120, whatever the command's status.
    flush_stdout()
    if sys.argv[1:2] == ["run"]:
        # The gateway has stopped: every connection is closed and every file written.
        # What is left is the interpreter freeing the heap object by object (seconds for a
        # 10 MB program) and waiting for a program still being read: a SIGTERM must end the
        # process within a second, so it ends here.
        logging.shutdown()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)
