"""VAR RETAIN values kept across restarts of ``ncgate run``, in SQLite (WAL mode).

Every save is one transaction: a reader -- the next start, after ``kill -9`` at any moment --
finds the values of the last committed save, never a mix and never a torn file.  WAL with
``synchronous=NORMAL``: a commit is in the operating system once it returns, so a killed
process loses nothing it committed; after a power cut the file is still consistent, at the
last checkpoint (docs/plc.md).  Values are JSON (bools, numbers, lists of them), stored
beside their type; a value whose variable no longer exists or changed type is left out at
load (the caller logs it and saves at once, so that the old row is gone).

A file that is not a sound store -- not SQLite, a page SQLite finds corrupt, another
program's table -- is moved aside (``NAME.corrupt-<UTC time>``, kept for inspection) with a
warning, and a new store starts empty: the PLC starts with its initial values instead of not
at all.  A file that cannot be opened or is locked is still an error for the caller: that is
a place problem the user must fix, and moving it aside would lose good values.

Stdlib only.
"""

from __future__ import annotations

import json
import logging
import sqlite3
import time
from pathlib import Path
from typing import Any

SCHEMA = "CREATE TABLE IF NOT EXISTS retain (name TEXT PRIMARY KEY, type TEXT, value TEXT)"
log = logging.getLogger(__name__)
# What SQLite says of a file that is not a sound database (sqlite3 errors carry the name).
_CORRUPT = ("SQLITE_CORRUPT", "SQLITE_NOTADB")


class _NotOurs(Exception):
    """The file opens, but is not a sound retain store."""


def default_path(folder: Path) -> Path:
    """The file when ``plc.retain_file`` is not set, in the config's state folder
    (``ncgate.config.state.state_folder``: beside the user's config, never in a package)."""
    return folder / "ncgate-plc-retain.sqlite"


class RetainStore:
    """One SQLite file of ``name -> (type, value)``."""

    def __init__(self, path: Path) -> None:
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)  # a fresh state folder
        try:
            self._db = self._open()
        except _NotOurs as exc:
            self._move_aside(str(exc))
            self._db = self._open()

    def _open(self) -> sqlite3.Connection:
        db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        try:
            # Checked before anything is written, so that a file moved aside is as it was.
            # A small file: reading it whole at start finds a bad page now, not mid-run.
            check = db.execute("PRAGMA quick_check").fetchone()
            if check is None or check[0] != "ok":
                raise _NotOurs(f"SQLite's check says: {check[0] if check else 'nothing'}")
            if db.execute("SELECT 1 FROM sqlite_master WHERE name = 'retain'").fetchone():
                db.execute("SELECT name, type, value FROM retain LIMIT 1").fetchall()
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA synchronous=NORMAL")
            db.execute(SCHEMA)
        except sqlite3.DatabaseError as exc:
            db.close()
            name = getattr(exc, "sqlite_errorname", "")
            if name in _CORRUPT or (name == "SQLITE_ERROR" and "no such column" in str(exc)):
                raise _NotOurs(str(exc)) from None
            raise
        except _NotOurs:
            db.close()
            raise
        return db

    def _move_aside(self, why: str) -> None:
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        aside = self.path.with_name(f"{self.path.name}.corrupt-{stamp}")
        k = 1
        while aside.exists():
            k += 1
            aside = self.path.with_name(f"{self.path.name}.corrupt-{stamp}-{k}")
        self.path.replace(aside)  # one rename: the store is either there or aside
        wal = self.path.with_name(self.path.name + "-wal")
        if wal.exists():
            wal.replace(aside.with_name(aside.name + "-wal"))
        self.path.with_name(self.path.name + "-shm").unlink(missing_ok=True)
        log.warning("RETAIN store %s is unreadable (%s): moved aside to %s; the PLC starts "
                    "with its initial values", self.path, why, aside.name)

    def load(self) -> dict[str, tuple[str, Any]]:
        try:
            rows = self._db.execute("SELECT name, type, value FROM retain").fetchall()
        except sqlite3.DatabaseError as exc:
            if getattr(exc, "sqlite_errorname", "") not in _CORRUPT:
                raise
            self._db.close()
            self._move_aside(str(exc))
            self._db = self._open()
            return {}
        out: dict[str, tuple[str, Any]] = {}
        for name, type_name, value in rows:
            try:
                out[name] = (type_name, json.loads(value))
            except (TypeError, ValueError):
                continue
        return out

    def save(self, values: dict[str, tuple[str, Any]]) -> None:
        """Replace the stored values with these, in one transaction."""
        db = self._db
        db.execute("BEGIN IMMEDIATE")
        try:
            db.execute("DELETE FROM retain")
            db.executemany("INSERT INTO retain (name, type, value) VALUES (?, ?, ?)",
                           [(k, t, json.dumps(v)) for k, (t, v) in values.items()])
        except BaseException:
            db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")

    def clear(self) -> None:
        self.save({})

    def close(self) -> None:
        self._db.close()
