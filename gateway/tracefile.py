"""The trace of ``ncgate run`` on disk: every event as a JSON line, size-capped with rotation.

``ncgate run --trace FILE`` (or ``[trace] file``) writes every event of spec 4.4 here while the
in-memory trace keeps only a window (``[trace] ring``).  When the file would pass
``trace.max_mb`` it is rotated as logrotate does: FILE -> FILE.1 -> FILE.2 ..., at most
``trace.backups`` old files, so the disk use is bounded too.

Nothing is ever half-written, even on ``kill -9``: events are collected in memory and written
with one ``os.write`` of whole lines (a write(2) to a regular file is not cut by a signal), at
the latest ``flush_s`` after the first of them, and before a rotation or on close.  A kill
loses at most the events of that last interval, never a line's tail; a write that fails
half-way (a full disk) is cut back to the last whole line.
"""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

from ncgate.interpreter.engine.events import Event, as_line


class TraceFile:
    """A listener of the trace (``trace.subscribe(file.write)``) that owns one file."""

    def __init__(self, path: Path, max_bytes: int, backups: int, flush_s: float = 0.25,
                 loop: asyncio.AbstractEventLoop | None = None, fresh: bool = False) -> None:
        """``fresh``: start the file empty (a session record), instead of appending."""
        self.path = path
        self.max_bytes = max_bytes
        self.backups = backups
        self.flush_s = flush_s
        self._loop = loop
        self._pending: list[str] = []
        self._pending_bytes = 0
        self._timer: asyncio.TimerHandle | None = None
        self._fd = self._open(os.O_TRUNC if fresh else 0)
        self._size = os.fstat(self._fd).st_size

    def _open(self, flags: int = 0) -> int:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        return os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND | flags, 0o644)

    def write(self, event: Event) -> None:
        self.append(as_line(event) + "\n")

    def append(self, line: str) -> None:
        """One whole line (ending in a newline), written with the next flush."""
        self._pending.append(line)
        self._pending_bytes += len(line)  # ASCII-mostly: bytes are counted exactly on flush
        if self._pending_bytes >= 1 << 16:
            self.flush()
        elif self._timer is None and self._loop is not None:
            self._timer = self._loop.call_later(self.flush_s, self.flush)

    def flush(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if not self._pending:
            return
        data = "".join(self._pending).encode("utf-8")
        self._pending.clear()
        self._pending_bytes = 0
        if self._size and self._size + len(data) > self.max_bytes:
            self._rotate()
        view = memoryview(data)
        try:
            while view:  # a short write happens only on a full disk; the rest follows
                written = os.write(self._fd, view)
                view = view[written:]
        except OSError:
            # The disk is full (or failing): cut the file back to its last whole line, so
            # that it never ends in half a line, and say so to the caller.
            os.ftruncate(self._fd, self._size)
            raise
        self._size += len(data)

    def _rotate(self) -> None:
        os.close(self._fd)
        if self.backups:
            for i in range(self.backups - 1, 0, -1):
                older = self.path.with_name(f"{self.path.name}.{i}")
                if older.exists():
                    os.replace(older, self.path.with_name(f"{self.path.name}.{i + 1}"))
            os.replace(self.path, self.path.with_name(f"{self.path.name}.1"))
        else:
            os.unlink(self.path)
        self._fd = self._open()
        self._size = 0

    def close(self) -> None:
        self.flush()
        os.close(self._fd)
