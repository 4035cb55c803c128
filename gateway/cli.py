"""The ``ncgate`` command line (spec 4.1)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from config import ConfigError, load_config
from gateway.checking import UsageError, check_files, expand, storage_files
from interpreter.diagnostics import InterpreterError

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ncgate",
        description="Modbus/CAN I/O gateway and PLC-logic co-simulator for multi-process CNC "
        "part programs.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    check = commands.add_parser(
        "check", help="parse and check part programs",
        description="Parse and check part programs; print every diagnostic. With no FILE, "
        "check every program on the config's storage devices.",
    )
    check.add_argument("files", nargs="*", metavar="FILE",
                       help="program files, directories or globs")
    check.add_argument("--config", metavar="C", help="config file (default: ncgate.toml "
                       "beside each file, else the built-in default)")
    check.add_argument("--process", type=int, metavar="N",
                       help="the process the files run in (default: inferred from the main "
                       "program and EXE codes)")
    check.add_argument("-q", "--quiet", action="store_true", help="no summary line")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on usage errors, 0 on --help
        return int(exc.code or 0)
    try:
        if args.command == "check":
            return _check(args)
    except (UsageError, ConfigError) as exc:
        print(f"ncgate {args.command}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (InterpreterError, OSError) as exc:
        print(f"ncgate {args.command}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    parser.error(f"unknown command {args.command}")
    return EXIT_USAGE  # not reached: parser.error exits


def _check(args: argparse.Namespace) -> int:
    config = load_config(args.config) if args.config else None
    files = expand(args.files) if args.files else storage_files(config or load_config(None))
    if not files:
        raise UsageError("no program to check")
    if args.process is not None:
        count = (config or load_config(None)).nc.processes
        if not 1 <= args.process <= count:
            raise UsageError(f"--process {args.process}: expected 1..{count}")
    reports = check_files(files, config, args.process)
    errors = warnings = 0
    for report in reports:
        for diagnostic in report.diagnostics:
            print(diagnostic.render())
        errors += report.errors
        warnings += report.warnings
    if not args.quiet:
        print(f"{len(reports)} file(s) checked: {errors} error(s), {warnings} warning(s)",
              file=sys.stderr)
    return EXIT_FAILED if errors else EXIT_OK


def entry_point() -> None:
    sys.exit(main())
