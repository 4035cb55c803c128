"""Standard output whose reader may go early (``ncgate sim | head -1``, ``ncgate map | head``,
``ncgate sweep ... | head``, ``ncgate sweep -o - | head``): the one answer of the command
line and the sweep to a closed pipe.  What is left to say goes to /dev/null, as the Python
docs advise (signal module, "Note on SIGPIPE"), so that neither a later write nor the
interpreter's last flush fails again -- that flush, failing, says "Exception ignored ...
BrokenPipeError" and makes the exit status 120, whatever the command found.  The command
goes on to its end (a sweep's table, sim's JUnit file) and exits with its own status.

Imports the standard library only: the CLI and the sweep both use it."""

from __future__ import annotations

import os
import sys
from typing import TextIO, cast


def stdout_gone() -> None:
    """After the reader of standard output went: the rest of the output goes nowhere."""
    _gone("stdout")


def _gone(name: str) -> None:
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, getattr(sys, name).fileno())
    os.close(null)


def closed_streams() -> None:
    """Standard output or error closed before the command started (``ncgate check >&-``):
    Python gives None for it, and what the command says there goes nowhere instead."""
    if sys.stdout is None:
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (the process's, to its end)
    if sys.stderr is None:
        sys.stderr = open(os.devnull, "w")  # noqa: SIM115


def flush_stdout() -> None:
    """Flush standard output, here rather than at the interpreter's exit: a reader that went
    meanwhile is :func:`stdout_gone`, not exit status 120."""
    _Quiet("stdout").flush()


class _Quiet:
    """sys.stdout or sys.stderr (looked up at each write: pytest's capsys swaps them) that a
    closed reader does not stop: what is left goes nowhere (:func:`_gone`)."""

    def __init__(self, name: str) -> None:
        self._name = name

    def write(self, text: str) -> int:
        try:
            written: int = getattr(sys, self._name).write(text)
        except BrokenPipeError:
            _gone(self._name)
            return len(text)
        return written

    def flush(self) -> None:
        try:
            getattr(sys, self._name).flush()
        except BrokenPipeError:
            _gone(self._name)


def stdout() -> TextIO:
    """Standard output for a command whose exit status says what it found (check, sim,
    sweep): a reader that goes early stops none of it (see the module's docstring).  Flush it
    before the command returns, so that a reader gone by then is not the interpreter's to
    meet."""
    return cast(TextIO, _Quiet("stdout"))


def stderr() -> TextIO:
    """Standard error, alike: ``ncgate check ... 2>&1 | head -1`` closes it too, and the
    command's status is still what it found."""
    return cast(TextIO, _Quiet("stderr"))


def write_stdout_bytes(data: bytes) -> None:
    """``data`` to standard output as it is (a table: ``ncgate sweep -o -``, Parquet too),
    after what was written there as text; a reader that goes early stops none of it."""
    flush_stdout()
    try:
        sys.stdout.buffer.write(data)
        sys.stdout.buffer.flush()
    except BrokenPipeError:
        _gone("stdout")
