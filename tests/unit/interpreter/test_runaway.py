"""Issue 9.1: a loop with no motion never hangs the engine; it is an alarm that names the loop,
and nc.block_time_ms gives every block a processing time."""

from __future__ import annotations

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import run_virtual

from ...helpers import make_sim, simulate

LOOP = '"L"\nN1E1=E1+1\nN2(BNC,L)\n'


def test_a_loop_without_motion_is_a_runaway_alarm_naming_the_jump_and_its_target() -> None:
    sim = simulate({"A": LOOP}, runaway_blocks=5000)
    alarm = sim.first("alarm")
    assert alarm["code"] == f"AL{int(AlarmCode.RUNAWAY)}"
    assert (alarm["line"], alarm["n"]) == (3, 2)  # at the jump
    assert "line 3 'N2(BNC,L)'" in alarm["message"] and "back to line 1 '\"L\"'" in alarm["message"]
    assert alarm["t"] == 0.0
    # The limit is counted in blocks decoded (the label line is no block), exactly.
    assert sim.engine.processes[1].stats.blocks == 5000


def test_the_default_limit_is_100000_blocks_and_a_display_loop_stays_bounded() -> None:
    sim = simulate({"A": '"L"\nN1(DIS,"x",E1)\nN2E1=E1+1\nN3(BNC,L)\n'})
    assert sim.first("alarm")["code"] == "AL144"
    assert sim.engine.processes[1].stats.blocks == 100_000
    assert len(sim.events("display")) == 33_334  # one per loop: no more than the blocks allow


def test_a_repeat_without_motion_is_a_runaway_too() -> None:
    sim = simulate({"A": "N1(RPT,1000000)\nN2E1=E1+1\nN3(ERP)\nN4M30\n"}, runaway_blocks=3000)
    alarm = sim.first("alarm")
    assert alarm["code"] == "AL144" and alarm["line"] == 3
    assert "back to line 2 'N2E1=E1+1'" in alarm["message"]


def test_two_processes_passing_a_token_with_no_time_passing_are_runaways() -> None:
    # Each waits at every turn, yet time never passes: the engine never stands still.
    sim = simulate({
        "A": "N1(EXE,2,B)\n\"L\"\nN2(SND,2)\nN3(WAI,2)\nN4(BNC,L)\n",
        "B": "\"L\"\nN1(WAI,1)\nN2(SND,1)\nN3(BNC,L)\n",
    }, runaway_blocks=2000)
    assert sim.first("alarm")["code"] == "AL144"


def test_a_loop_with_motion_is_no_runaway() -> None:
    program = '"L"\nN1G1X1F6000\nN2G1X0\nN3E1=E1+1\nN4(BLT,E1,400,L)\nN5M30\n'
    sim = simulate({"A": program}, runaway_blocks=50)
    assert not sim.events("alarm")
    assert sim.first("end")["how"] == "M30"
    assert sim.engine.processes[1].stats.blocks == 1601


def test_waiting_for_the_plc_resets_the_count() -> None:
    program = '"L"\nN1(WAI,SA1=1)\nN2(WAI,SA1=0)\nN3E1=E1+1\nN4(BLT,E1,30,L)\nN5M30\n'
    sim = make_sim({"A": program}, runaway_blocks=10)
    sim.engine.start("A")
    sim.run()
    for _ in range(40):  # the PLC answers each wait; the engine stands still in between
        if sim.engine.all_idle:
            break
        sim.image.write([("SA", 1, "bit", 1)], "plc")
        sim.run()
        sim.image.write([("SA", 1, "bit", 0)], "plc")
        sim.run()
    assert not sim.events("alarm")
    assert sim.first("end")["how"] == "M30"


def test_no_limit_when_runaway_blocks_is_0_the_engine_still_runs_in_slices() -> None:
    sim = make_sim({"A": LOOP}, runaway_blocks=0, slice_blocks=1000)
    engine = sim.engine
    engine.start("A")
    for _ in range(5):  # a driver that serves others between runs gets control back each time
        assert engine.advance_to(0.0, blocks=1000) is True
    assert not sim.events("alarm")
    assert engine.processes[1].stats.blocks == 5 * 1000


def test_block_time_makes_every_block_take_its_time() -> None:
    sim = make_sim({"A": LOOP}, block_time_ms=2.0)
    sim.engine.start("A")
    assert run_virtual(sim.engine, until=5.0) == "until"
    assert not sim.events("alarm")
    # N1 and N2 take 2 ms each: one block at t = 0, 0.002, ... and the last at t = 5.0.
    assert sim.engine.processes[1].stats.blocks == 2501


def test_block_time_delays_a_program_without_motion_by_its_blocks() -> None:
    sim = simulate({"A": "N1E1=1\nN2E2=2\nN3(DIS,\"x\")\nN4M30\n"}, block_time_ms=10.0)
    # Each block acts, then takes its 10 ms: N3 at 0.02 s, the M30 at 0.03 s.
    assert abs(sim.first("display")["t"] - 0.020) < 1e-9
    assert abs(sim.first("end")["t"] - 0.030) < 1e-9


def test_reset_cancels_a_block_time() -> None:
    sim = make_sim({"A": LOOP}, block_time_ms=100.0)
    sim.engine.start("A")
    sim.run(until=0.05)
    sim.engine.reset()
    assert sim.engine.next_timer() is None  # nothing left armed
    assert run_virtual(sim.engine) == "idle"


def test_rpt_0_repeats_no_time_and_goes_on_after_the_matching_erp() -> None:
    program = ("N1E1=0\nN2(RPT,E1)\nN3(RPT,2)\nN4E2=E2+1\nN5(ERP)\nN6E3=E3+1\nN7(ERP)\n"
               "N8(DIS,\"done\",E2,E3)\nN9M30\n")
    sim = simulate({"A": program})
    assert sim.first("display")["text"] == "done 0 0"
    sim = simulate({"A": program.replace("N1E1=0", "N1E1=3")})
    assert sim.first("display")["text"] == "done 6 3"
    sim = simulate({"A": program.replace("N1E1=0", "N1E1=-1")})
    assert sim.first("alarm")["code"] == "AL104"
