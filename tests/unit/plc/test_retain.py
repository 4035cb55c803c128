"""VAR RETAIN: stored, reloaded, and refused when it no longer fits; a store that cannot be
written never stops the PLC."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from ncgate.plc.image import IOImage
from ncgate.plc.retain import RetainStore
from ncgate.plc.scan import PlcRuntime, PlcState
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.parser import parse_source

from .st_harness import RecordingNc

SOURCE = """PROGRAM keep
VAR RETAIN n : INT; r : REAL; v : ARRAY[1..3] OF BOOL; END_VAR
n := n + 1; r := r + 0.5; v[2] := TRUE;
END_PROGRAM
"""


def runtime(store: RetainStore, source: str = SOURCE) -> PlcRuntime:
    logic = compile_logic([parse_source(source, "keep.st")], Context())
    return PlcRuntime(logic, IOImage(), RecordingNc(), ["keep"], retain=store)


def test_values_come_back_at_the_next_start(tmp_path: Path) -> None:
    store = RetainStore(tmp_path / "r.sqlite")
    first = runtime(store)
    for t in range(3):
        first.scan(t * 10)
    store.close()
    again = runtime(RetainStore(tmp_path / "r.sqlite"))
    assert (again.read("keep.n"), again.read("keep.r"), again.read("keep.v")) == (
        3, 1.5, [False, True, False])


@pytest.mark.parametrize("stored", [("INT", 40000), ("DINT", 5), ("INT", 1.5), ("INT", True)])
def test_a_value_that_no_longer_fits_is_left_out(tmp_path: Path, stored: tuple[str, object],
                                                 caplog: pytest.LogCaptureFixture) -> None:
    store = RetainStore(tmp_path / "r.sqlite")
    store.save({"KEEP.N": stored, "KEEP.R": ("REAL", 2.5)})
    with caplog.at_level(logging.WARNING, "ncgate.plc"):
        plc = runtime(store)
    assert plc.read("keep.n") == 0 and plc.read("keep.r") == 2.5
    assert "RETAIN KEEP.N" in caplog.text


def test_a_store_that_fails_leaves_the_plc_scanning(tmp_path: Path,
                                                    caplog: pytest.LogCaptureFixture) -> None:
    store = RetainStore(tmp_path / "r.sqlite")
    plc = runtime(store)
    plc.scan(0)
    store.close()  # every later save fails
    with caplog.at_level(logging.ERROR, "ncgate.plc"):
        for t in range(1, 4):
            plc.scan(t * 10)
    assert plc.status.state is PlcState.RUNNING and plc.read("keep.n") == 4
    assert caplog.text.count("RETAIN values not saved") == 1
