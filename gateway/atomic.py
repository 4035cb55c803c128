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
import tempfile
from pathlib import Path


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
