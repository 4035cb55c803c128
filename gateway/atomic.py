"""A file written whole or not at all: the one way the gateway replaces a file that must not
be half-written after a ``kill -9`` at any byte (the CANopen node's stored parameters, a
sweep's parts and table).

The data goes to a temporary file in the same folder, flushed and fsynced, which is then
renamed over the file (``os.replace`` is atomic), and the folder is fsynced so that the
rename is on the disk too.  A crash leaves the old file or the new one, and at most a
temporary ``.NAME.*.tmp`` beside it, which readers ignore."""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from pathlib import Path


def shell_mode(path: Path) -> int:
    """An existing file's permissions, else a new file's (0o666 less the umask), as a shell's
    ``>`` gives: not mkstemp's 0o600 (a table or a JUnit file another user's CI reads)."""
    try:
        return stat.S_IMODE(path.stat().st_mode)
    except OSError:
        mask = os.umask(0o022)
        os.umask(mask)
        return 0o666 & ~mask


def write_output(path: Path, data: bytes) -> None:
    """An output a user named (a sweep's table, a JUnit file), whole or not at all: through
    its symbolic links (the file they reach is replaced, not the link), with the mode a
    shell's ``>`` gives."""
    target = path.resolve()
    write_atomic(target, data, shell_mode(target))


def write_atomic(path: Path, data: bytes, mode: int | None = None) -> None:
    """Replace ``path`` by ``data``, whole.  ``mode``: the file's permissions (None: the
    temporary file's, 0o600: readable by its owner only)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        if mode is not None:
            os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as out:
            out.write(data)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    with contextlib.suppress(OSError):  # the rename itself, on the disk (not on every system)
        folder = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(folder)
        finally:
            os.close(folder)
