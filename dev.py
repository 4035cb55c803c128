#!/usr/bin/env python3
"""One entry point for a fresh machine: sets up .venv, then runs what you ask.

    python3 dev.py run     # the gateway on its built-in defaults (Ctrl-C stops it)
    python3 dev.py test    # the whole test suite
    python3 dev.py lint    # ruff + mypy (strict on the packages)
    python3 dev.py bench   # the benchmarks under bench/

Only Python >= 3.11 and pip are needed: the virtual environment and every dependency (at the
exact versions of constraints.txt) are installed on first use, and again whenever
pyproject.toml or constraints.txt changes.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import signal
import subprocess
import sys
import tomllib
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / "python"
STAMP = VENV / ".ncgate-installed"
INSTALL_INPUTS = ("pyproject.toml", "constraints.txt")


def ensure_venv() -> None:
    if sys.version_info < (3, 11):  # noqa: UP036 - run by whatever python3 the user has
        sys.exit("ncgate needs Python 3.11 or newer")
    if not PY.exists():
        print("dev.py: creating .venv", flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    digest = hashlib.sha256(b"".join((ROOT / name).read_bytes() for name in INSTALL_INPUTS))
    if not STAMP.exists() or STAMP.read_text() != digest.hexdigest():
        print("dev.py: installing ncgate and its locked dependencies into .venv (pymodbus, "
              "python-can, canopen, lark, aiohttp, and for the tests pytest, selenium, blark, "
              "ruff, mypy ...): a minute or more the first time; pip's progress follows",
              flush=True)
        pip = [str(PY), "-m", "pip", "install", "--disable-pip-version-check",
               "--progress-bar", "on", "-c", str(ROOT / "constraints.txt")]
        subprocess.run([*pip, "-e", f"{ROOT}[test,dev]"], check=True)
        STAMP.write_text(digest.hexdigest())


def package_dirs() -> dict[str, Path]:
    """pyproject.toml's package-dir: each package ncgate installs, and the folder it comes from.

    The one list of the source folders: setuptools finds the sub-packages under each of them,
    and the type-check tree below links them.
    """
    with (ROOT / "pyproject.toml").open("rb") as file:
        table = tomllib.load(file)["tool"]["setuptools"]["package-dir"]
    return {package: ROOT / folder for package, folder in table.items()}


def typecheck_tree() -> Path:
    """build/typecheck/ncgate: links that lay the packages out as they install.

    setuptools maps ncgate.gateway to gateway/ (and so on) through package-dir; mypy cannot
    follow that mapping, so it reads the package through these links instead: each file of
    ncgate/ and each folder package-dir maps to ncgate.<name>, so a file or folder added to (or
    dropped from) them is seen at the next lint.
    """
    tree = ROOT / "build" / "typecheck" / "ncgate"
    links: dict[str, Path] = {}
    for package, folder in package_dirs().items():
        if package == "ncgate":
            links.update({p.name: p for p in folder.iterdir() if p.name != "__pycache__"})
        elif package.count(".") == 1 and package.startswith("ncgate."):
            links[package.removeprefix("ncgate.")] = folder
        else:
            sys.exit(f"dev.py: cannot lay out package-dir's {package!r} for mypy: only "
                     "ncgate and ncgate.<name> are mapped to folders")
    # Brought up to date link by link, not laid out afresh: another `dev.py lint` may be
    # reading the tree at the same time.
    tree.mkdir(parents=True, exist_ok=True)
    for old in tree.iterdir():
        if old.is_symlink() and old.readlink() == links.get(old.name):
            continue
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)
    for name, target in links.items():
        with contextlib.suppress(FileExistsError):
            (tree / name).symlink_to(target)
    return tree.parent


def run(*cmd: str) -> int:
    """Run a command in the foreground; Ctrl-C is the child's to handle (as in a shell).

    SIGINT is ignored here only after the child has started, so the child keeps Python's
    default handler (pytest stops cleanly, `ncgate run` shuts down and exits 0); a
    terminal's Ctrl-C reaches both.  SIGTERM, which a service manager or `kill` sends to
    this process alone, is passed on to the child, whose exit ends this one: the child is
    never left behind holding its ports.
    """
    child = subprocess.Popen(cmd, cwd=ROOT)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    previous_term = signal.signal(signal.SIGTERM,
                                  lambda signum, frame: child.send_signal(signum))
    try:
        return child.wait()
    finally:
        signal.signal(signal.SIGINT, previous)
        signal.signal(signal.SIGTERM, previous_term)


def workers(args: list[str]) -> list[str]:
    """Two pytest-xdist workers unless the arguments choose: most of the suite waits (on a
    gateway's process, a socket, a browser), so two workers on two cores halve it -- 540 ->
    310 s quiet, 632 s at load 6 against 591-614 s in one process at load 4
    (docs/decisions.md, "The suite's time")."""
    chosen = "no:xdist" in args or any(
        a in ("-n", "--numprocesses") or a.startswith(("-n", "--numprocesses=")) for a in args)
    return [] if chosen else ["-n", "2"]


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
        if not rest:
            print("dev.py: the whole suite on two workers, about 5 minutes on two quiet cores "
                  "(python3 dev.py test -x tests/unit for a quick look; -n 0: one process)",
                  flush=True)
        return run(str(PY), "-m", "pytest", *workers(rest), *rest)
    if what == "lint":
        os.environ["MYPYPATH"] = str(typecheck_tree())
        return run(str(PY), "-m", "ruff", "check", ".") or run(str(PY), "-m", "mypy", "-p",
                                                               "ncgate")
    status = 0
    for script in sorted((ROOT / "bench").glob("*.py")):
        print(f"== {script.name}", flush=True)
        status = run(str(PY), str(script), *rest) or status
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
