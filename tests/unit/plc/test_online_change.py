"""Online change (issue 29, item 5): new logic swapped in between two scans keeps every
variable whose path and type are unchanged and the state of every FB instance; the rest
starts from its initial value.  Expected values are what the old logic had built and what
IEC 61131-3 gives the new one from there (a TON measures from when IN rose, across the
change)."""

from __future__ import annotations

from pathlib import Path

from ncgate.plc.retain import RetainStore
from ncgate.plc.scan import PlcRuntime, PlcState
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.logic import Logic
from ncgate.plc.st.parser import parse_source

from .st_harness import Plc

CONTEXT = Context(64, 16, 8, 5, frozenset({4, 5}))


def logic(source: str) -> Logic:
    return compile_logic([parse_source(source, "new.st")], CONTEXT)


BEFORE = """
FUNCTION_BLOCK stage
VAR_INPUT go : BOOL; END_VAR
VAR_OUTPUT steps : INT; END_VAR
VAR edge : R_TRIG; note : INT; END_VAR
edge(CLK := go);
IF edge.Q THEN steps := steps + 1; END_IF
note := 5;
END_FUNCTION_BLOCK

PROGRAM main
VAR
  n : INT;
  t : TON;
  s : stage;
  level : INT := 3;
  old_only : BOOL;
  history : ARRAY[0..2] OF INT;
END_VAR
n := n + 1;
t(IN := TRUE, PT := T#100ms);
SA[0] := t.Q;
s(go := SA[1]);
history[n MOD 3] := n;
END_PROGRAM
"""

AFTER = """
FUNCTION_BLOCK stage
VAR_INPUT go : BOOL; END_VAR
VAR_OUTPUT steps : INT; END_VAR
VAR edge : R_TRIG; note : REAL := 0.5; added : INT := 9; END_VAR
edge(CLK := go);
IF edge.Q THEN steps := steps + 10; END_IF
END_FUNCTION_BLOCK

PROGRAM main
VAR
  n : INT;
  t : TON;
  s : stage;
  level : DINT := 30;
  fresh : INT := 7;
  history : ARRAY[0..2] OF INT;
END_VAR
n := n + 100;
t(IN := TRUE, PT := T#100ms);
SA[0] := t.Q;
s(go := SA[1]);
END_PROGRAM
"""


def test_kept_values_go_on_and_the_rest_starts_from_its_initial_value() -> None:
    plc = Plc(BEFORE)
    plc.image.write([("SA", 1, "bit", 1)], "test")
    plc.scan(5)  # n 5, one rising edge of go: steps 1
    assert plc["main.n"] == 5 and plc["main.s.steps"] == 1
    done = plc.runtime.reload(logic(AFTER), ["main"])
    assert sorted(done.initial) == ["main.fresh", "main.level", "main.s.added", "main.s.note"]
    assert sorted(done.dropped) == ["main.old_only"]
    assert plc["main.level"] == 30 and plc["main.fresh"] == 7  # retyped, new: initial
    assert plc["main.s.note"] == 0.5 and plc["main.s.added"] == 9
    assert plc["main.history"] == [3, 4, 5]  # n MOD 3 of 3, 4, 5
    plc.scan()
    assert plc["main.n"] == 105  # the new logic, from the kept value
    # The R_TRIG kept its memory of go (TRUE): no new edge, steps stays.
    assert plc["main.s.steps"] == 1
    plc.image.write([("SA", 1, "bit", 0)], "test")
    plc.scan()
    plc.image.write([("SA", 1, "bit", 1)], "test")
    plc.scan()
    assert plc["main.s.steps"] == 11


def test_a_timer_keeps_running_across_the_change() -> None:
    """TON PT 100 ms, IN TRUE from the scan at 0 ms: Q at the scan of 100 ms, whatever
    logic runs in between."""
    plc = Plc(BEFORE).scan(5)  # 0..40 ms
    assert plc["main.t.ET"] == 40
    plc.runtime.reload(logic(AFTER), ["main"])
    plc.scan(5)  # 50..90 ms
    assert plc["main.t.ET"] == 90 and not plc["main.t.Q"]
    plc.scan(1)  # 100 ms
    assert plc["main.t.Q"] and plc.image.sa[0] & 1


def test_an_nc_output_held_across_the_change_is_no_new_edge() -> None:
    source = "PROGRAM main\nVAR n : INT; END_VAR\nn := n + 1;\nNC.START := TRUE;\nEND_PROGRAM\n"
    plc = Plc(source).scan(2)
    assert plc.nc.commands == [1]
    plc.runtime.reload(logic(source.replace("n + 1", "n + 2")), ["main"])
    plc.scan(3)
    assert plc.nc.commands == [1] and plc["main.n"] == 8


def test_a_reload_runs_a_faulted_plc_again() -> None:
    plc = Plc("PROGRAM main\nVAR n : INT; d : INT; END_VAR\nn := n + 1;\nn := n / d;\n"
              "END_PROGRAM\n").scan()
    assert plc.runtime.status.state is PlcState.FAULT
    plc.runtime.reload(logic("PROGRAM main\nVAR n : INT; d : INT; END_VAR\nn := n + 1;\n"
                             "END_PROGRAM\n"), ["main"])
    plc.scan()
    assert plc.runtime.status.state is PlcState.RUNNING and plc["main.n"] == 2


def test_programs_come_and_go_with_the_order(tmp_path: Path) -> None:
    plc = Plc("PROGRAM a\nVAR n : INT; END_VAR\nn := n + 1;\nEND_PROGRAM\n").scan(2)
    done = plc.runtime.reload(logic("PROGRAM b\nVAR m : INT := 4; END_VAR\nm := m + 1;\n"
                                    "END_PROGRAM\nPROGRAM a\nVAR n : INT; END_VAR\n"
                                    "n := n + 10;\nEND_PROGRAM\n"), ["b", "a"])
    assert done.initial == ("b",) and done.kept == 1
    plc.scan()
    assert plc["a.n"] == 12 and plc["b.m"] == 5


def test_retain_values_are_kept_and_the_store_follows_the_new_logic(
        tmp_path: Path) -> None:
    store = RetainStore(tmp_path / "retain.sqlite")
    first = logic("PROGRAM main\nVAR RETAIN count : INT; gone : INT; END_VAR\n"
                  "count := count + 1;\nEND_PROGRAM\n")
    plc = Plc("PROGRAM main\nEND_PROGRAM\n")
    runtime = PlcRuntime(first, plc.image, plc.nc, ["main"], retain=store)
    for now in range(3):
        runtime.scan(now * 10)
    runtime.reload(logic("PROGRAM main\nVAR RETAIN count : INT; later : INT := 5; END_VAR\n"
                         "count := count + 1;\nEND_PROGRAM\n"), ["main"])
    assert runtime.read("main.count") == 3 and runtime.read("main.later") == 5
    runtime.scan(30)
    assert store.load() == {"MAIN.COUNT": ("INT", 4), "MAIN.LATER": ("INT", 5)}


def test_structures_and_globals_are_kept_member_by_member() -> None:
    before = """
TYPE Axis : STRUCT pos : INT; speed : INT := 5; END_STRUCT; END_TYPE
TYPE Mode : (IDLE, RUN, STOPPED); END_TYPE
VAR_GLOBAL total : DINT; mode : Mode; END_VAR
PROGRAM main
VAR x : Axis; n : INT; END_VAR
n := n + 1;
x.pos := x.pos + 2;
total := total + 1;
IF n = 3 THEN mode := Mode#RUN; END_IF
END_PROGRAM
"""
    after = before.replace("speed : INT := 5;", "speed : REAL := 0.5;").replace(
        "(IDLE, RUN, STOPPED)", "(IDLE, RUN, STOPPED, FAILED)")
    plc = Plc(before).scan(3)
    done = plc.runtime.reload(logic(after), ["main"])
    assert sorted(done.initial) == ["main.x.speed"]  # retyped member (mode: RUN is kept)
    assert plc.runtime.logic.namespace["_G"].v_MODE == 1  # RUN
    assert plc["main.x.pos"] == 6 and plc["main.x.speed"] == 0.5
    plc.scan()
    assert plc["main.x.pos"] == 8
    assert plc.runtime.logic.namespace["_G"].v_TOTAL == 4  # the global ran on


def test_a_constant_takes_its_new_value_where_it_is_read_too() -> None:
    """The code uses a CONSTANT's declared value (IEC 61131-3: it cannot be written), so a
    changed constant, or a variable made CONSTANT, reads as declared after the change --
    the console showed the old value while the code used the new one."""
    source = ("VAR_GLOBAL CONSTANT top : INT := {v}; END_VAR\n"
              "FUNCTION_BLOCK f\nVAR CONSTANT k : INT := {v}; END_VAR\nEND_FUNCTION_BLOCK\n"
              "PROGRAM main\nVAR CONSTANT lim : INT := {v}; END_VAR\n"
              "VAR {d} n : INT; g : f; END_VAR\nn := lim + top;\nEND_PROGRAM\n")
    plc = Plc(source.format(v=100, d="later : INT := 3;")).scan()
    plc.runtime.reload(logic(source.format(v=200, d="").replace(
        "VAR CONSTANT lim", "VAR CONSTANT later : INT := 4; lim")), ["main"])
    plc.scan()
    assert plc["main.n"] == 400
    assert (plc["main.lim"], plc["main.g.k"], plc["main.later"]) == (200, 200, 4)
    assert plc.runtime.logic.namespace["_G"].v_TOP == 200


def test_a_state_machine_keeps_its_state_when_its_enumeration_changes() -> None:
    """A state added to the enumeration -- before the current one, which renumbers it -- or
    one removed that is not the current one: the state is carried by its name, so the
    machine goes on where it was (it restarted from IDLE, and counted a second cycle).  A
    variable whose state is gone starts from its initial value."""
    source = """
TYPE Step : (IDLE, CLAMP, DRILL, EJECT); END_TYPE
PROGRAM main
VAR st : Step; other : Step := Step#EJECT; cycles : CTU; n : INT;
    trail : ARRAY[0..1] OF Step; END_VAR
n := n + 1;
IF n = 2 THEN st := Step#DRILL; trail[1] := Step#CLAMP; END_IF
cycles(CU := st = Step#DRILL, PV := 10);
SYVAR[0] := cycles.CV;
END_PROGRAM
"""
    plc = Plc(source).scan(3)
    assert (plc["main.st"], plc["main.cycles.CV"]) == (2, 1)
    done = plc.runtime.reload(logic(source.replace(
        "(IDLE, CLAMP, DRILL, EJECT)", "(IDLE, SAFE, CLAMP, DRILL)").replace(
        " := Step#EJECT", "")), ["main"])
    assert done.initial == ("main.other",)  # EJECT is gone: DRILL's initial, IDLE
    assert plc["main.st"] == 3 and plc["main.other"] == 0  # DRILL, now 3
    assert plc["main.trail"] == [0, 2]  # IDLE, CLAMP (now 2)
    plc.scan(3)
    assert plc["main.cycles.CV"] == 1 and plc.image.syvar[0] == 1  # no second cycle
