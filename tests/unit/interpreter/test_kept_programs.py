"""A small NC-110 program read and checked with no error is kept for the next read of the
same bytes with the same options (interpreter/nc110/dialect.py): a scenario suite or a sweep
reads it for every run.  What its check depends on beyond its bytes is never kept."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.interpreter.diagnostics import ProgramSyntaxError
from ncgate.interpreter.dialect import DialectOptions
from ncgate.interpreter.nc110 import dialect as nc110_dialect
from ncgate.interpreter.storage import Storage, file_version


def load(folder: Path, name: str, process: int = 1,
         options: DialectOptions | None = None) -> object:
    reader = nc110_dialect._Reader(options or DialectOptions(),
                                   Storage({"MP0": folder}, "MP0"))
    path = folder / f"{name}.nc"
    return reader.load(path, file_version(path), process)


def test_the_same_bytes_are_read_once_and_an_edit_is_read_anew(tmp_path: Path) -> None:
    (tmp_path / "A.nc").write_text("N1G1X10F6000\nN2M30\n")
    first = load(tmp_path, "A")
    assert load(tmp_path, "A") is first
    assert load(tmp_path, "A", process=2) is not first  # checked for another process
    assert load(tmp_path, "A", options=DialectOptions(syvars=8)) is not first
    (tmp_path / "A.nc").write_text("N1G1X20F6000\nN2M30\n")
    edited = load(tmp_path, "A")
    assert edited is not first and "X20" in edited.lines[0]  # type: ignore[attr-defined]


def test_a_program_that_starts_another_is_checked_at_every_read(tmp_path: Path) -> None:
    """Its check looks for the program it starts, which may come and go."""
    (tmp_path / "A.nc").write_text("N1(EXE,2,SUB)\nN2M30\n")
    (tmp_path / "SUB.nc").write_text("N1M30\n")
    assert load(tmp_path, "A") is not load(tmp_path, "A")
    (tmp_path / "SUB.nc").unlink()
    with pytest.raises(ProgramSyntaxError):
        load(tmp_path, "A")


def test_a_program_with_an_error_is_refused_at_every_read(tmp_path: Path) -> None:
    (tmp_path / "A.nc").write_text("N1G1X10F0000\nN2M30\n")  # F0: NC034
    for _ in range(2):
        with pytest.raises(ProgramSyntaxError):
            load(tmp_path, "A")
