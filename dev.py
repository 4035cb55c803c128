#!/usr/bin/env python3
"""One entry point for a fresh machine: sets up .venv, then runs what you ask.

    python3 dev.py run     # the gateway on its built-in defaults (Ctrl-C stops it)
    python3 dev.py test    # the whole test suite
    python3 dev.py lint    # ruff + mypy (strict on the packages)
    python3 dev.py bench   # the benchmarks under bench/

Only Python >= 3.11 and pip are needed: the virtual environment and every dependency (pinned
in pyproject.toml) are installed on first use, and again whenever pyproject.toml changes.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / "python"
STAMP = VENV / ".ncgate-installed"


def ensure_venv() -> None:
    if sys.version_info < (3, 11):  # noqa: UP036 - run by whatever python3 the user has
        sys.exit("ncgate needs Python 3.11 or newer")
    if not PY.exists():
        print("dev.py: creating .venv", flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    digest = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if not STAMP.exists() or STAMP.read_text() != digest:
        print("dev.py: installing ncgate and its pinned dependencies into .venv", flush=True)
        pip = [str(PY), "-m", "pip", "install", "--disable-pip-version-check", "-q"]
        subprocess.run([*pip, "-e", f"{ROOT}[test,dev]"], check=True)
        STAMP.write_text(digest)


def run(*cmd: str) -> int:
    """Run a command in the foreground; Ctrl-C is the child's to handle (as in a shell).

    SIGINT is ignored here only after the child has started, so the child keeps Python's
    default handler (pytest stops cleanly, `ncgate run` shuts down and exits 0).
    """
    child = subprocess.Popen(cmd, cwd=ROOT)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        return child.wait()
    finally:
        signal.signal(signal.SIGINT, previous)


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in {"run", "test", "lint", "bench", "setup"}:
        print(__doc__)
        return 2
    ensure_venv()
    what, rest = argv[0], argv[1:]
    if what == "setup":
        return 0
    if what == "run":
        return run(str(BIN / "ncgate"), "run", *rest)
    if what == "test":
        return run(str(PY), "-m", "pytest", *rest)
    if what == "lint":
        return run(str(PY), "-m", "ruff", "check", ".") or run(str(PY), "-m", "mypy")
    status = 0
    for script in sorted((ROOT / "bench").glob("*.py")):
        print(f"== {script.name}", flush=True)
        status = run(str(PY), str(script), *rest) or status
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
