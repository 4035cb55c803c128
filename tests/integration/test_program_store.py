"""The program store keeps the latest version of each file: a program edited all shift long
does not pile up in memory, and an edit is what runs next."""

from __future__ import annotations

import os
from pathlib import Path

from ncgate.config import load_config
from ncgate.gateway.programs import ProgramStore


def test_each_edit_replaces_the_version_kept(tmp_path: Path) -> None:
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n')
    store = ProgramStore(load_config(tmp_path / "ncgate.toml"))
    program = tmp_path / "A.nc"
    for i in range(20):
        program.write_text(f"N1E1={i}\nN2M30\n")
        os.utime(program, ns=(i * 10**9, i * 10**9))  # a new version, whatever the clock
        loaded = store.load("A", None, 1)
        assert loaded.lines[0] == f"N1E1={i}"
        assert store.load("A", None, 1) is loaded  # an unchanged file is not read again
    store.load("A", None, 2)  # checked for another process: a second entry
    assert len(store._cache) == 2
