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


# ---- store drift and corruption (issue 29 item 6) ---------------------------------------------
# The expected values are IEC 61131-3's (2.4.2.1 / 6.5.6): a RETAIN variable with no valid
# retained value starts with its initial value, as at a cold restart.

def version(n_type: str) -> str:
    return (f"PROGRAM keep\nVAR RETAIN n : {n_type} := 7; END_VAR\nn := n + 1;\n"
            "END_PROGRAM\n")


def test_a_retyped_variable_drops_its_old_row_so_going_back_gets_no_stale_value(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "r.sqlite"
    store = RetainStore(path)
    runtime(store, version("INT")).scan(0)  # n = 8, stored as INT
    store.close()
    store = RetainStore(path)
    with caplog.at_level(logging.WARNING, "ncgate.plc"):
        v2 = runtime(store, version("DINT"))  # retyped: initial value, the INT row dropped
    assert v2.read("keep.n") == 7 and "RETAIN KEEP.N" in caplog.text
    assert store.load() == {"KEEP.N": ("DINT", 7)}
    store.close()
    back = runtime(RetainStore(path), version("INT"))  # back to INT: not the 8 of version 1
    assert back.read("keep.n") == 7


def test_a_variable_that_is_gone_drops_its_row_with_a_warning(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    store = RetainStore(tmp_path / "r.sqlite")
    store.save({"KEEP.N": ("INT", 3), "KEEP.OLD": ("INT", 9)})
    with caplog.at_level(logging.WARNING, "ncgate.plc"):
        plc = runtime(store, version("INT"))
    assert plc.read("keep.n") == 3 and "RETAIN KEEP.OLD" in caplog.text
    assert store.load() == {"KEEP.N": ("INT", 3)}


def sound_store(path: Path) -> None:
    store = RetainStore(path)
    store.save({f"KEEP.X{k}": ("INT", k) for k in range(400)})  # a few pages
    store.close()


def garble_a_page(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[4096 + 8:4096 + 4000] = b"\xa5" * (4000 - 8)  # inside page 2
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["not sqlite", "a garbled page", "another table"])
def test_a_corrupt_store_is_moved_aside_and_the_plc_starts_cold(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, damage: str) -> None:
    path = tmp_path / "r.sqlite"
    if damage == "not sqlite":
        path.write_bytes(b"this is no database\n" * 300)
    elif damage == "a garbled page":
        sound_store(path)
        garble_a_page(path)
    else:
        import sqlite3
        with sqlite3.connect(path) as db:
            db.execute("CREATE TABLE retain (id INTEGER, blob BLOB)")
    before = path.read_bytes()
    with caplog.at_level(logging.WARNING, "ncgate.plc"):
        store = RetainStore(path)
        plc = runtime(store, version("INT"))
    assert plc.read("keep.n") == 7  # the initial value
    aside = [p for p in tmp_path.iterdir() if ".corrupt-" in p.name and
             not p.name.endswith("-wal")]
    assert len(aside) == 1 and aside[0].read_bytes() == before  # kept, as it was
    assert "moved aside" in caplog.text
    plc.scan(0)
    store.close()
    assert runtime(RetainStore(path), version("INT")).read("keep.n") == 8  # a sound store


def test_a_locked_or_unopenable_store_is_still_an_error_not_moved_aside(tmp_path: Path) -> None:
    import sqlite3
    folder = tmp_path / "a-folder"
    folder.mkdir()
    with pytest.raises(sqlite3.Error):
        RetainStore(folder)  # a folder is no file: a place problem for the user
    assert folder.is_dir() and not list(tmp_path.glob("*.corrupt-*"))


def test_a_real_stored_as_a_double_comes_back_as_the_single_it_is(tmp_path: Path) -> None:
    store = RetainStore(tmp_path / "r.sqlite")
    store.save({"KEEP.R": ("REAL", 0.1)})
    plc = runtime(store)
    assert plc.read("keep.r") == 13421773 / 2**27  # binary32 nearest to 0.1


FB_SOURCE = """TYPE Stats : STRUCT count : DINT; last : STRING[8]; END_STRUCT END_TYPE
FUNCTION_BLOCK Tally
VAR_INPUT pulse : BOOL; END_VAR
VAR edge : R_TRIG; n : INT; END_VAR
edge(CLK := pulse);
IF edge.Q THEN n := n + 1; END_IF
END_FUNCTION_BLOCK
PROGRAM keep
VAR RETAIN parts : CTU; tally : Tally; stats : Stats; END_VAR
VAR pulse : BOOL; END_VAR
pulse := NOT pulse;
parts(CU := pulse, PV := 100);
tally(pulse := pulse);
stats.count := stats.count + 1; stats.last := 'scan';
END_PROGRAM
"""


def test_a_retained_counter_fb_and_structure_keep_their_state_over_a_restart(
        tmp_path: Path) -> None:
    # IEC 61131-3, 6.5.6: a RETAIN instance keeps its state over a warm restart -- a CTU's
    # CV, a user FB's variables (and its R_TRIG's memory), a structure's members.
    store = RetainStore(tmp_path / "r.sqlite")
    first = runtime(store, FB_SOURCE)
    for t in range(5):  # pulse TRUE, FALSE, TRUE, FALSE, TRUE: three rising edges
        first.scan(t * 10)
    assert first.read("keep.parts.CV") == 3
    store.close()
    again = runtime(RetainStore(tmp_path / "r.sqlite"), FB_SOURCE)
    assert again.read("keep.parts.CV") == 3 and again.read("keep.tally.n") == 3
    assert (again.read("keep.stats.count"), again.read("keep.stats.last")) == (5, "scan")
    # pulse (not retained) starts FALSE: TRUE now is no edge, the R_TRIGs remember TRUE;
    # FALSE, then TRUE again is the fourth edge, counted on from 3.
    for t in (100, 110, 120):
        again.scan(t)
    assert again.read("keep.parts.CV") == 4 and again.read("keep.tally.n") == 4


def test_a_retained_fb_whose_type_changed_starts_from_its_initial_state(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    store = RetainStore(tmp_path / "r.sqlite")
    first = runtime(store, FB_SOURCE)
    first.scan(0)
    store.close()
    changed = FB_SOURCE.replace("VAR edge : R_TRIG; n : INT; END_VAR",
                                "VAR edge : R_TRIG; n : INT; extra : BOOL; END_VAR")
    with caplog.at_level(logging.WARNING):
        again = runtime(RetainStore(tmp_path / "r.sqlite"), changed)
    assert again.read("keep.tally.n") == 0 and again.read("keep.parts.CV") == 1
    assert "KEEP.TALLY" in caplog.text.upper()


def test_a_var_global_retain_keeps_its_value_over_a_restart(tmp_path: Path) -> None:
    # 6.5.6: RETAIN globals too; the others start from their initial values.
    source = ("VAR_GLOBAL RETAIN total : DINT; END_VAR\nVAR_GLOBAL plain : DINT := 7; END_VAR\n"
              "PROGRAM keep\ntotal := total + 1; plain := plain + 1;\nEND_PROGRAM\n")
    store = RetainStore(tmp_path / "r.sqlite")
    first = runtime(store, source)
    for t in range(3):
        first.scan(t * 10)
    store.close()
    again = runtime(RetainStore(tmp_path / "r.sqlite"), source)
    g = again.logic.namespace["_G"]
    assert (g.v_TOTAL, g.v_PLAIN) == (3, 7)
