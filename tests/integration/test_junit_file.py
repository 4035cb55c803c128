"""The JUnit file (`sim --junit`, `run --script --junit`) is written whole, as a shell's `>`
would leave it for another user's CI to read: through a symbolic link to the file it reaches,
with 0666 less the umask (an existing file keeps its mode); a FIFO or a device is refused
before the run (a file written whole replaces what is there)."""

from __future__ import annotations

import contextlib
import os
import stat
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from ncgate.gateway.cli.main import main

from ..helpers import write_cell


def _cell(folder: Path) -> None:
    write_cell(folder, '[nc]\nmain = "O1"\n[nc.storage]\nMP0 = "."\n',
               {"O1": "N10 (DLY,0.1)\nN20 M30\n"})
    (folder / "s.toml").write_text('[[expect]]\nname = "ends"\ncond = "P1 IDLE"\nby = 1.0\n')


def test_junit_through_a_link_with_a_shells_mode(tmp_path: Path) -> None:
    _cell(tmp_path)
    (tmp_path / "ci").mkdir()
    real = tmp_path / "ci" / "real.xml"
    real.write_text("old")
    os.chmod(real, 0o640)
    (tmp_path / "link.xml").symlink_to(real)
    old = os.umask(0o022)
    try:
        with contextlib.chdir(tmp_path):
            assert main(["sim", "--config", "ncgate.toml", "--script", "s.toml",
                         "--junit", "link.xml"]) == 0
            assert main(["sim", "--config", "ncgate.toml", "--script", "s.toml",
                         "--junit", "new.xml"]) == 0
    finally:
        os.umask(old)
    assert (tmp_path / "link.xml").is_symlink()  # the link is kept, the file it reaches is new
    assert ET.parse(real).getroot().get("tests") == "1"
    assert stat.S_IMODE(real.stat().st_mode) == 0o640  # written over: keeps its mode
    assert stat.S_IMODE((tmp_path / "new.xml").stat().st_mode) == 0o644  # not mkstemp's 0600


def test_junit_to_a_fifo_is_refused_before_the_run(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    _cell(tmp_path)
    os.mkfifo(tmp_path / "f.xml")
    with contextlib.chdir(tmp_path):
        assert main(["sim", "--config", "ncgate.toml", "--script", "s.toml",
                     "--junit", "f.xml"]) == 2
        assert main(["run", "--config", "ncgate.toml", "--script", "s.toml",
                     "--junit", "f.xml"]) == 2
    err = capsys.readouterr().err
    assert err.count("--junit f.xml: not a regular file") == 2, err
    assert stat.S_ISFIFO((tmp_path / "f.xml").stat().st_mode)
