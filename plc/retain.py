"""VAR RETAIN values kept across restarts of ``ncgate run``, in SQLite (WAL mode).

Every save is one transaction: a reader -- the next start, after ``kill -9`` at any moment --
finds the values of the last committed save, never a mix and never a torn file.  WAL with
``synchronous=NORMAL``: a commit is in the operating system once it returns, so a killed
process loses nothing it committed; after a power cut the file is still consistent, at the
last checkpoint (docs/plc.md).  Values are JSON (bools, numbers, lists of them), stored
beside their type; a value whose variable no longer exists or changed type is left out at
load (and logged by the caller).

Stdlib only.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

SCHEMA = "CREATE TABLE IF NOT EXISTS retain (name TEXT PRIMARY KEY, type TEXT, value TEXT)"


def default_path(folder: Path) -> Path:
    """The file when ``plc.retain_file`` is not set, in the config's state folder
    (``ncgate.config.state.state_folder``: beside the user's config, never in a package)."""
    return folder / "ncgate-plc-retain.sqlite"


class RetainStore:
    """One SQLite file of ``name -> (type, value)``."""

    def __init__(self, path: Path) -> None:
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)  # a fresh state folder
        self._db = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.execute(SCHEMA)

    def load(self) -> dict[str, tuple[str, Any]]:
        rows = self._db.execute("SELECT name, type, value FROM retain").fetchall()
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
