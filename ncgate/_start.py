"""The ``ncgate`` command's and ``python -m ncgate``'s first frame: light on purpose.

A Ctrl-C while the command is still importing what it needs (a tenth of a second and more)
ends it quietly, as one once ``run`` has its handlers does (``ncgate run: stopped before
serving (SIGINT)``), instead of a KeyboardInterrupt traceback from inside an import.
"""

from __future__ import annotations

import sys


def main() -> None:
    try:
        from ncgate.gateway.cli.main import entry_point
    except KeyboardInterrupt:
        _interrupted()
    try:
        entry_point()
    except KeyboardInterrupt:  # before a command took the signal over (parsing the line)
        _interrupted()


def _interrupted() -> None:
    command = sys.argv[1] if len(sys.argv) > 1 and not sys.argv[1].startswith("-") else ""
    if command == "run":
        print("ncgate run: stopped before serving (SIGINT)", file=sys.stderr)
        sys.exit(0)
    print(f"ncgate{' ' + command if command else ''}: interrupted", file=sys.stderr)
    sys.exit(130)
