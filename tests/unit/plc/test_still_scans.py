"""A scan that changed nothing is skipped while what it reads stands still (plc/scan.py:
the programs' state, the image, the NC's status): nothing the logic does may tell."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pytest

from ncgate.plc.scan import STILL_PAUSE_MAX
from ncgate.plc.st.stdlib import RUNNING

from .st_harness import IDLE, Plc, program


def test_a_scan_that_changed_nothing_is_still_until_an_input_changes() -> None:
    plc = Plc(program("SA[1] := SA[0];")).scan(3)
    assert plc.runtime.still  # (the first scan changed nothing either: SA1 was 0)
    plc.image.write([("SA", 0, "bit", 1)], "test")
    plc.scan()
    assert plc.image.read("SA", 1, "bit") == 1
    assert plc.runtime.status.scans == 4  # a skipped scan counts as a scan


def test_a_running_on_delay_is_no_still_scan_and_rises_on_time() -> None:
    plc = Plc(program("t(IN := SA[0], PT := T#50ms); SA[1] := t.Q;", "t : TON;"))
    plc.image.write([("SA", 0, "bit", 1)], "test")
    rose = []
    for _ in range(8):  # every 10 ms from 0: IN rose at 0, Q at 50 ms
        plc.scan()
        rose.append(plc.image.read("SA", 1, "bit"))
    assert rose == [0, 0, 0, 0, 0, 1, 1, 1]
    assert plc["main.t.ET"] == 50 and plc.runtime.still  # elapsed: it stands still now


def test_a_counter_counts_every_scan() -> None:
    plc = Plc(program("n := n + 1;", "n : DINT;")).scan(5)
    assert plc["main.n"] == 5 and not plc.runtime.still


def test_logic_that_moved_for_long_is_seen_still_soon_after_it_stops() -> None:
    """Its state is read less often while it moves (plc/scan.py: STILL_PAUSE_MAX), never so
    seldom that a still stretch goes unseen for long."""
    plc = Plc(program("IF SA[0] THEN n := n + 1; END_IF;", "n : DINT;"))
    plc.image.write([("SA", 0, "bit", 1)], "test")
    plc.scan(200)
    assert not plc.runtime.still
    plc.image.write([("SA", 0, "bit", 0)], "test")
    plc.scan(STILL_PAUSE_MAX + 2)
    assert plc.runtime.still and plc["main.n"] == 200


def test_a_variable_set_between_scans_is_seen_by_the_next_scan() -> None:
    plc = Plc(program("SA[1] := x;", "x : BOOL;")).scan(3)
    assert plc.runtime.still
    plc.runtime.programs["MAIN"].v_X = True  # as a debugger would: the state is read again
    plc.scan()
    assert plc.image.read("SA", 1, "bit") == 1


def test_the_ncs_status_is_an_input_of_a_still_scan() -> None:
    plc = Plc(program("SA[2] := NOT NC.P[1].IDLE;")).scan(3)
    assert plc.runtime.still and plc.image.read("SA", 2, "bit") == 0
    plc.nc.processes[0] = (1, 10, 2, False, False, 0, False, False)  # P1 runs
    plc.scan()
    assert plc.image.read("SA", 2, "bit") == 1
    plc.nc.processes[0] = IDLE
    plc.scan()
    assert plc.image.read("SA", 2, "bit") == 0


def test_a_real_that_turned_to_minus_zero_is_a_change() -> None:
    # 0.0 * -1.0 is -0.0, and -0.0 * -1.0 is 0.0: equal as numbers, yet each scan changes r
    plc = Plc(program("r := r * -1.0;", "r : LREAL;"))
    signs = [math.copysign(1.0, plc.scan()["main.r"]) for _ in range(4)]
    assert signs == [-1.0, 1.0, -1.0, 1.0] and not plc.runtime.still


DEEP = """
TYPE Slot : STRUCT flag : BOOL; name : STRING[8]; END_STRUCT; END_TYPE
VAR_GLOBAL g : INT; END_VAR
FUNCTION_BLOCK Station
VAR_OUTPUT q : BOOL; END_VAR
VAR t : TON; tray : ARRAY[1..2] OF Slot; END_VAR
t(); (* IN stays FALSE: PT is kept as set *)
q := t.PT > T#5ms OR tray[2].flag;
END_FUNCTION_BLOCK
PROGRAM main
VAR slots : ARRAY[1..3] OF Slot; st : Station; r : ARRAY[1..2] OF LREAL;
  timers : ARRAY[1..2] OF TON;
  s : STRING; END_VAR
st();
timers[2](IN := FALSE);
SA[1] := slots[2].flag;
SA[2] := st.q;
SA[3] := r[2] > 0.5;
SA[4] := s = 'x';
SA[5] := g = 3;
SA[6] := timers[2].PT > T#5ms;
SA[7] := slots[3].name = 'y';
END_PROGRAM
"""


def _set_slot_flag(main: Any, g: Any) -> None:
    main.v_SLOTS[1].v_FLAG = True


def _set_fb_timer(main: Any, g: Any) -> None:
    main.v_ST.v_T.PT = 10


def _set_fb_array(main: Any, g: Any) -> None:
    main.v_ST.v_TRAY[1].v_FLAG = True


def _set_real(main: Any, g: Any) -> None:
    main.v_R[1] = 1.0


def _set_string(main: Any, g: Any) -> None:
    main.v_S = "x"


def _set_global(main: Any, g: Any) -> None:
    g.v_G = 3


def _set_timer_in_array(main: Any, g: Any) -> None:
    main.v_TIMERS[1].PT = 10


def _set_string_in_struct(main: Any, g: Any) -> None:
    main.v_SLOTS[2].v_NAME = "y"


@pytest.mark.parametrize(("setter", "bit"), [
    (_set_slot_flag, 1), (_set_fb_timer, 2), (_set_fb_array, 2), (_set_real, 3),
    (_set_string, 4), (_set_global, 5), (_set_timer_in_array, 6), (_set_string_in_struct, 7)])
def test_every_member_is_part_of_the_state(setter: Callable[[Any, Any], None],
                                           bit: int) -> None:
    """Each kind of member (a structure in an array, an FB's TON and array, a REAL, a
    STRING, a global, a TON in an array) set between scans is seen: none is left out of
    the state a still scan compares."""
    plc = Plc(DEEP).scan(3)
    assert plc.runtime.still and plc.image.read("SA", bit, "bit") == 0
    setter(plc.runtime.programs["MAIN"], plc.runtime.logic.namespace["_G"])
    plc.scan()
    assert plc.image.read("SA", bit, "bit") == 1


def test_a_timer_called_twice_in_a_scan_is_not_still_while_its_first_call_runs() -> None:
    """The end of each scan is the same once the short PT has passed (the second call leaves
    ET saturated), but the first call's Q waits for the long PT: such scans are not still
    (stdlib.RUNNING), found by a hostile review."""
    plc = Plc(program("t(IN := TRUE, PT := T#50ms); SA[1] := t.Q;"
                      "t(IN := TRUE, PT := T#20ms); SA[2] := t.Q;", "t : TON;"))
    rose = []
    for _ in range(8):  # every 10 ms from 0
        plc.scan()
        rose.append((plc.image.read("SA", 1, "bit"), plc.image.read("SA", 2, "bit")))
    assert rose == [(0, 0), (0, 0), (0, 1), (0, 1), (0, 1), (1, 1), (1, 1), (1, 1)]
    assert plc.runtime.still  # both calls saturated: it stands still now


def test_a_variable_set_between_scans_and_undone_by_the_next_is_no_still_scan() -> None:
    """A write between scans that the next scan undoes leaves the state as the scan before
    ended it: that scan did something all the same (found by a hostile review)."""
    plc = Plc(program("IF n > 0 THEN n := n - 1; IF n = 0 THEN SA[1] := TRUE; END_IF; END_IF;",
                      "n : INT := 10;")).scan(3)
    assert plc["main.n"] == 7
    plc.runtime.programs["MAIN"].v_N = 8  # as a debugger would
    plc.scan(12)
    assert plc["main.n"] == 0 and plc.image.read("SA", 1, "bit") == 1


# -- what the logic reads: a write elsewhere leaves a still scan still --------------------------

def _counting(plc: Plc) -> list[int]:
    """How often the program ran (a skipped scan does not run it)."""
    calls: list[int] = []
    run = plc.runtime._runs[0]

    def counted() -> None:
        calls.append(1)
        run()

    plc.runtime._runs[0] = counted
    return calls


def test_a_write_the_logic_neither_reads_nor_writes_leaves_a_still_scan_skipped() -> None:
    plc = Plc(program("SA[1] := SA[0];")).scan(3)
    calls = _counting(plc)
    plc.image.write([("SA", 20, "bit", 1), ("SYVAR", 3, "IN", 7), ("SK", 4, "BY", 9)], "test")
    plc.scan(2)
    assert calls == [] and plc.runtime.status.scans == 5
    plc.image.write([("SA", 0, "bit", 1)], "test")  # what it reads: it runs
    plc.scan()
    assert calls == [1] and plc.image.read("SA", 1, "bit") == 1


def test_what_the_logic_writes_and_another_overwrote_is_written_again() -> None:
    """A still scan's inputs are what the logic writes too: a value it would write again,
    changed by a fieldbus between scans, is no reason to skip."""
    plc = Plc(program("SA[1] := TRUE; SYVAR[2] := 5;")).scan(3)
    assert plc.runtime.still
    plc.image.write([("SA", 1, "bit", 0), ("SYVAR", 2, "IN", 0)], "test")
    plc.scan()
    assert plc.image.read("SA", 1, "bit") == 1 and plc.image.read("SYVAR", 2, "IN") == 5


def test_an_index_the_logic_computes_makes_the_whole_area_its_input() -> None:
    plc = Plc(program("SA[1] := SA[i];", "i : INT := 20;")).scan(3)
    assert plc.runtime.still
    plc.image.write([("SA", 20, "bit", 1)], "test")
    plc.scan()
    assert plc.image.read("SA", 1, "bit") == 1


def test_an_input_that_changes_at_every_scan_is_judged_seldom_and_still_soon_after() -> None:
    """A value moving at every scan (a plant's ramp) leaves each scan still, but the next one
    reads something new: the state is read less often meanwhile -- and once the value
    stands, the scans are found still within STILL_PAUSE_MAX + 2 scans."""
    plc = Plc(program("SA[1] := SYVAR[0] > 500;"))
    for value in range(0, 1000, 10):
        plc.image.write([("SYVAR", 0, "IN", value)], "test")
        plc.scan()
    assert plc.image.read("SA", 1, "bit") == 1
    plc.scan(STILL_PAUSE_MAX + 2)
    assert plc.runtime.still


# -- sim's timed still scans: a running timer's ET the only change ------------------------------

def test_a_running_timer_alone_is_timed_still_until_its_due() -> None:
    """With ``timed`` (sim's leaps) a scan whose only change is a running TON's ET is still
    until the TON is due: the scans before skip (no call of a running timer), and its ET is
    as they would have left it; the scan at the due sees Q."""
    plc = Plc(program("t(IN := SA[0], PT := T#100ms); SA[1] := t.Q;", "t : TON;"))
    plc.runtime.timed = True
    plc.image.write([("SA", 0, "bit", 1)], "test")
    plc.scan(2)  # 0 ms: the TON starts; 10 ms: only its ET moved
    assert plc.runtime.still_until == 100 and not plc.runtime.still
    calls = next(RUNNING)
    plc.scan(8)  # 20 .. 90 ms
    assert next(RUNNING) == calls + 1  # no running timer was called
    assert plc["main.t.ET"] == 90 and plc.image.read("SA", 1, "bit") == 0
    plc.scan()  # 100 ms
    assert plc.image.read("SA", 1, "bit") == 1 and plc["main.t.ET"] == 100
    assert plc.runtime.status.scans == 11 and plc.runtime.still_until is None


@pytest.mark.parametrize("reads", ["SA[1] := t.ET > T#50ms;",
                                   "t(IN := SA[0], PT := T#100ms, ET => e); SA[1] := e > T#50ms;"])
def test_logic_that_reads_a_timers_et_is_never_timed_still(reads: str) -> None:
    plc = Plc(program(f"t(IN := SA[0], PT := T#100ms); {reads}", "t : TON; e : TIME;"))
    plc.runtime.timed = True
    plc.image.write([("SA", 0, "bit", 1)], "test")
    rose = []
    for _ in range(8):  # every 10 ms from 0: ET > 50 ms at 60 ms
        plc.scan()
        rose.append(plc.image.read("SA", 1, "bit"))
        assert plc.runtime.still_until is None
    assert plc.logic.reads_et and rose == [0, 0, 0, 0, 0, 0, 1, 1]


TIMERS = """
FUNCTION_BLOCK Station
VAR_OUTPUT q : BOOL; END_VAR
VAR t : TON; END_VAR
t(IN := TRUE, PT := T#80ms);
q := t.Q;
END_FUNCTION_BLOCK
PROGRAM main
VAR st : Station; ts : ARRAY[1..2] OF TON; off : TOF; p : TP; END_VAR
st();
ts[2](IN := TRUE, PT := T#50ms);
off(IN := SA[0], PT := T#120ms);
p(IN := SA[0], PT := T#30ms);
SA[1] := st.q;
SA[2] := ts[2].Q;
SA[3] := off.Q;
SA[4] := p.Q;
END_PROGRAM
"""


def test_timed_still_scans_see_every_timer_where_it_would() -> None:
    """A TON in an FB and in an array, a TOF, a TP: scans timed still, each rises and falls
    at the scan it does scan by scan."""
    def run(timed: bool) -> tuple[list[tuple[int, ...]], list[int | None]]:
        plc = Plc(TIMERS)
        plc.runtime.timed = timed
        plc.image.write([("SA", 0, "bit", 1)], "test")
        seen, untils = [], []
        for k in range(25):
            if k == 3:
                plc.image.write([("SA", 0, "bit", 0)], "test")  # at 30 ms: the TOF runs
            plc.scan()
            seen.append(tuple(plc.image.read("SA", i, "bit") for i in range(1, 5)))
            untils.append(plc.runtime.still_until)
        return seen, untils

    timed, untils = run(True)
    assert timed == run(False)[0]
    # (the TP due at 30, the TON in the FB at 80, the TOF at 30 + 120; ts[2]'s 50 comes
    # while the TOF's start moves the state)
    assert {30, 80, 150} <= set(untils)


def test_a_timer_called_twice_is_timed_still_until_its_first_calls_due() -> None:
    plc = Plc(program("t(IN := TRUE, PT := T#50ms); SA[1] := t.Q;"
                      "t(IN := TRUE, PT := T#20ms); SA[2] := t.Q;", "t : TON;"))
    plc.runtime.timed = True
    rose = []
    for _ in range(8):  # every 10 ms from 0
        plc.scan()
        rose.append((plc.image.read("SA", 1, "bit"), plc.image.read("SA", 2, "bit")))
    assert rose == [(0, 0), (0, 0), (0, 1), (0, 1), (0, 1), (1, 1), (1, 1), (1, 1)]
