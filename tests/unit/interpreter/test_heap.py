"""A big ISG parse kept whole stays out of the full collections (interpreter/heap.py), and
nothing frozen with it is kept for ever."""

from __future__ import annotations

import gc
from pathlib import Path

import pytest

from ncgate.interpreter import heap
from ncgate.interpreter.dialect import DialectOptions
from ncgate.interpreter.isg import dialect as isg_dialect
from ncgate.interpreter.isg.dialect import IsgDialect
from ncgate.interpreter.isg.parser import IsgFile
from ncgate.interpreter.storage import Storage, file_version


def isg_text(lines: int) -> str:
    return "%channel1\n" + "".join(f"N{n % 9999}G01X{n % 500}Y{n % 7}F6000\n"
                                   for n in range(lines)) + "M30\n"


def test_an_isg_parse_has_no_reference_cycles() -> None:
    """What heap.keep relies on: a kept parse that is dropped is freed by its reference
    counts, with nothing left for the collector."""
    text = isg_text(2000) + "$IF P1 == 1\nN5 G01 X1\n$ELSE\nN6 G01 X2\n$ENDIF\n"
    gc.collect()
    gc.disable()
    try:
        source = IsgFile.from_text(text, "BIG.nc", "BIG")
        assert len(source.blocks) > 2000
        del source
        assert gc.collect() == 0  # no cycle among the parse's objects
    finally:
        gc.enable()


def test_a_big_isg_file_is_frozen_while_kept_and_given_back_when_dropped(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """While a big file is parsed no full collection comes (each walked the whole heap so
    far, holding every thread: 2.6 s for 10 MB); once it is kept its objects are frozen
    (out of every walk); when the last reference goes the heap is given back."""
    path = tmp_path / "BIG.nc"
    path.write_text(isg_text(30_000))
    assert path.stat().st_size >= heap.BIG_BYTES
    reader = IsgDialect().reader(DialectOptions(processes=3), Storage({"MP0": tmp_path}, "MP0"))
    before = gc.get_freeze_count()
    thresholds: list[tuple[int, int, int]] = []
    check_file = isg_dialect.check_file

    def watched(source: IsgFile, context: object) -> object:
        thresholds.append(gc.get_threshold())  # the parse is built, not yet checked
        return check_file(source, context)  # type: ignore[arg-type]

    monkeypatch.setattr(isg_dialect, "check_file", watched)
    program = reader.load(path, file_version(path), 1)
    assert thresholds and thresholds[0][2] == heap.POSTPONED
    assert gc.get_threshold()[2] != heap.POSTPONED  # the process's thresholds are back
    assert heap.kept() == 1
    assert gc.get_freeze_count() - before > 30_000 * 10  # its objects: out of every walk
    del program, reader  # the file's last references
    assert heap.kept() == 0
    assert gc.get_freeze_count() == 0  # given back: frozen garbage is collected again


def test_a_small_isg_file_is_left_to_the_collector(tmp_path: Path) -> None:
    path = tmp_path / "SMALL.nc"
    path.write_text(isg_text(100))
    reader = IsgDialect().reader(DialectOptions(processes=3), Storage({"MP0": tmp_path}, "MP0"))
    reader.load(path, file_version(path), 1)
    assert heap.kept() == 0
