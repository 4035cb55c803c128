"""The runtime's rules (spec 2.2-2.6), each shown on a minimal program pair."""

from __future__ import annotations

import math
import re

import pytest

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import ProcessState, WaitKind
from ncgate.interpreter.engine.states import Stage
from ncgate.interpreter.settings import SndPolicy

from ...helpers import make_sim, simulate


def test_early_snd_blocks_the_sender_under_rendezvous() -> None:
    # P2 waits for P1 only after a 1 s dwell, in motion order (#): P1's SND comes early.
    programs = {"A": "N1(EXE,2,B)\nN2(SND,2)\nN3M30\n", "B": "N1(DLY,1)\nN2#(WAI,1)\nN3(REL)\n"}
    sim = simulate(programs)
    assert sim.outcome == "idle"
    wait = sim.first("wait", proc=1)
    assert (wait["t"], wait["n"], wait["on"]) == (0.0, 2, {"snd": 2})
    snd = sim.first("snd", proc=1)
    assert (snd["t"], snd["to"], snd["n"]) == (1.0, 2, 2)
    resume = sim.first("resume", proc=1)
    assert (resume["t"], resume["by"]) == (1.0, 2)
    assert sim.events("hazard") == []


def test_early_snd_leaves_a_token_and_a_hazard_under_latched() -> None:
    programs = {"A": "N1(EXE,2,B)\nN2(SND,2)\nN3M30\n", "B": "N1(DLY,1)\nN2#(WAI,1)\nN3(REL)\n"}
    sim = simulate(programs, snd=SndPolicy.LATCHED)
    assert sim.outcome == "idle"
    hazard = sim.first("hazard", proc=1)
    assert (hazard["t"], hazard["n"]) == (0.0, 2)
    assert [e for e in sim.events("wait") if e["proc"] == 1] == []  # never blocked
    assert sim.first("end", proc=1)["t"] == 0.0
    snd = sim.first("snd", proc=1)  # delivered when P2's WAI takes the token
    assert (snd["t"], snd["to"]) == (1.0, 2)
    assert [e for e in sim.events("wait") if e["proc"] == 2] == []


@pytest.mark.parametrize(("code", "t_snd"), [("N3(SND,2)", 0.0), ("N3#(SND,2)", 1.0)])
def test_hash_snd_fires_after_the_motion_above_it(code: str, t_snd: float) -> None:
    programs = {"A": f"N1(EXE,2,B)\nN2G1X10F600\n{code}\nN4M30\n", "B": "N1(WAI,1)\nN2(REL)\n"}
    sim = simulate(programs)
    assert sim.first("snd", proc=1)["t"] == t_snd
    if t_snd:  # P2 waited for it
        assert sim.first("resume", proc=2)["t"] == t_snd


def test_plain_code_after_a_hash_block_can_act_before_it() -> None:
    # The hazard of spec 2.4: N4's plain SND acts at decode time, before N3's # SND.
    programs = {"A": "N1(EXE,2,B)\nN2G1X10F600\nN3#(SND,2)\nN4(SND,3)\nN5M30\n",
                "B": "N1(WAI,1)\nN2(REL)\n", "C": "N1(WAI,1)\nN2(REL)\n"}
    programs["A"] = "N0(EXE,3,C)\n" + programs["A"]
    sim = simulate(programs)
    sends = [(e["to"], e["t"]) for e in sim.events("snd")]
    assert sends == [(3, 0.0), (2, 1.0)]


def test_interpolator_wait_is_the_state_the_machine_feels() -> None:
    programs = {"A": "N1(EXE,2,B)\nN2G1X10F600\nN3#(WAI,2)\nN4G1X0\nN5M30\n",
                "B": "N1(DLY,5)\nN2#(SND,1)\nN3(REL)\n"}
    sim = simulate(programs, until=2.0)
    status = sim.engine.status(1)
    assert status.state is ProcessState.WAIT_PROC
    assert status.wait is not None and status.wait.stage is Stage.INTERPOLATOR
    assert status.wait.where[1:] == (3, 3) and status.wait_kind is WaitKind.PROC
    assert sim.engine.status(2).state is ProcessState.DWELL
    sim.run()
    assert sim.first("resume", proc=1)["t"] == 5.0
    assert sim.first("end", proc=1)["t"] == 6.0


def test_deadlock_on_a_wai_cycle_names_every_member() -> None:
    programs = {"A": "N1(EXE,2,B)\nN2(WAI,2)\nN3M30\n", "B": "N7(WAI,1)\nN8(REL)\n"}
    sim = simulate(programs)
    (event,) = sim.events("deadlock")
    assert event["message"] == "deadlock: P2 B.nc:1 N7 (WAI,1) -> P1 A.nc:2 N2 (WAI,2) -> P2"
    assert [c["proc"] for c in event["cycle"]] == [2, 1]
    alarms = sim.events("alarm")
    assert {(a["proc"], a["code"]) for a in alarms} == {(1, "AL140"), (2, "AL140")}
    assert all(a["message"] == event["message"] for a in alarms)
    assert sim.engine.status(1).state is ProcessState.ALARM


def test_crossing_snds_deadlock_under_rendezvous_only() -> None:
    programs = {"A": "N1(EXE,2,B)\nN2(SND,2)\nN3(WAI,2)\nN4M30\n",
                "B": "N1(SND,1)\nN2(WAI,1)\nN3(REL)\n"}
    sim = simulate(programs)
    (event,) = sim.events("deadlock")
    assert event["message"] == "deadlock: P2 B.nc:1 N1 (SND,1) -> P1 A.nc:2 N2 (SND,2) -> P2"
    latched = simulate(programs, snd=SndPolicy.LATCHED)
    assert latched.outcome == "idle" and latched.events("deadlock") == []
    assert len(latched.events("hazard")) >= 1


def test_deadlock_found_when_the_motion_of_a_member_ends() -> None:
    # P1 waits in its decoder while still moving: no deadlock until its motion is done.
    programs = {"A": "N1(EXE,2,B)\nN2G1X10F600\nN3(WAI,2)\nN4M30\n", "B": "N1(WAI,1)\nN2(REL)\n"}
    sim = simulate(programs)
    (event,) = sim.events("deadlock")
    assert event["t"] == 1.0


def test_orphan_wait_is_reported() -> None:
    sim = simulate({"A": "N1G1X1F60\nN2(WAI,3)\nN3M30\n"})
    (alarm,) = sim.events("alarm")
    assert alarm["code"] == "AL141" and alarm["proc"] == 1 and alarm["n"] == 2
    assert alarm["message"].startswith("orphan wait: P1 A.nc:2 N2 (WAI,3) waits for P3")


def test_wait_on_an_idle_process_that_another_will_start_is_no_orphan() -> None:
    programs = {"A": "N1(EXE,2,B)\nN2(WAI,3)\nN3M30\n", "B": "N1(DLY,1)\nN2#(EXE,3,C)\nN3(REL)\n",
                "C": "N1(SND,1)\nN2(REL)\n"}
    sim = simulate(programs)
    assert sim.outcome == "idle" and sim.events("alarm") == []
    assert sim.first("resume", proc=1) == {**sim.first("resume", proc=1), "t": 1.0, "by": 3}


def test_an_exe_chain_through_programs_not_yet_loaded_is_no_orphan() -> None:
    """Issue 25's cell: P1 waits for P3, which only L4 -- started by L2's queued # EXE --
    starts.  The check follows the chain L2 -> L4 -> L3 instead of alarming at t = 0."""
    programs = {"L1": "N1(EXE,2,L2)\nN2(WAI,3)\nN3M30\n",
                "L2": "N1G1X10F600\nN2#(EXE,4,L4)\nN3M30\n",
                "L4": "N1(EXE,3,L3)\nN2M30\n",
                "L3": "N1(SND,1)\nN2M30\n"}
    sim = simulate(programs, main="L1")
    assert sim.outcome == "idle" and sim.events("alarm") == []
    assert sim.first("resume", proc=1)["by"] == 3


def test_an_exe_queued_for_a_busy_process_counts_with_its_chain() -> None:
    """P2 is busy; P1's EXE of L2 waits in the queue, and L2 starts L3 in P3: P4's wait for
    P3 is no orphan while that EXE is queued."""
    programs = {"A": "N1(EXE,2,B)\nN2(EXE,4,D)\nN3(EXE,2,L2)\nN4M30\n",
                "B": "N1(DLY,1)\nN2M30\n",
                "D": "N1(WAI,3)\nN2M30\n",
                "L2": "N1(EXE,3,L3)\nN2M30\n",
                "L3": "N1(SND,4)\nN2M30\n"}
    sim = simulate(programs)
    assert sim.outcome == "idle" and sim.events("alarm") == []


def test_an_orphan_is_still_found_when_no_chain_reaches_the_process() -> None:
    """The chain followed to its end (L2 -> L4 -> L5, and L5 names L2 again) starts P4 and
    P5 only: P3 is an orphan, found at once."""
    programs = {"L1": "N1(EXE,2,L2)\nN2(WAI,3)\nN3M30\n",
                "L2": "N1(EXE,4,L4)\nN2M30\n", "L4": "N1G1X1F60\nN2(EXE,5,L5)\nN3M30\n",
                "L5": "N1(DLY,1)\nN2(EXE,2,L2)\nN3M30\n"}
    sim = simulate(programs, main="L1", until=10.0)
    alarm = sim.first("alarm", proc=1)
    assert alarm["code"] == "AL141" and alarm["t"] == 0.0
    assert "which no running or queued program can start" in alarm["message"]


def test_stall_when_nothing_can_change() -> None:
    sim = simulate({"A": "N1(WAI,SA10=1)\nN2M30\n"})
    assert sim.outcome == "blocked"
    assert [b.proc for b in sim.engine.blocked()] == [1]
    assert "(WAI,SA10=1) waits for SA10=1 (now 0)" in sim.engine.blocked()[0].reason


def test_exe_waits_for_a_busy_process_then_starts_it() -> None:
    programs = {"A": "N1(EXE,2,B)\nN2(EXE,2,C)\nN3M30\n", "B": "N1(DLY,2)\nN2(REL)\n",
                "C": "N1(REL)\n"}
    sim = simulate(programs)
    wait = sim.first("wait", proc=1)
    assert (wait["t"], wait["on"]) == (0.0, {"exe": 2})
    starts = [(e["t"], e["proc"], e["prog"], e["by"]) for e in sim.events("start")]
    assert starts == [(0.0, 1, "A", "operator"), (0.0, 2, "B", 1), (2.0, 2, "C", 1)]
    assert sim.first("resume", proc=1)["by"] == 2


@pytest.mark.parametrize(
    ("programs", "code", "line"),
    [
        ({"A": "N1E1=0\nN2E2=5/E1\n"}, AlarmCode.DIVISION_BY_ZERO, 2),
        ({"A": "N1E1=9\nN2(SND,E1)\n"}, AlarmCode.PROCESS_OUT_OF_RANGE, 2),
        ({"A": "N1(SND,2)\n"}, AlarmCode.SND_TO_IDLE, 1),
        ({"A": "N1(EXE,2,BAD)\n", "BAD": "N1GXY\n"}, AlarmCode.PROGRAM_INVALID, 1),
        ({"A": "N1G1X10\n"}, AlarmCode.NO_FEED, 1),
        ({"A": "N1E1=40000\nN2SYVAR1=E1\n"}, AlarmCode.VALUE_OUT_OF_RANGE, 2),
        ({"A": "N1E1=1\nN2(EXE,E1,A)\n"}, AlarmCode.EXE_ON_SELF, 2),
        ({"A": "N1E1=2.5\nN2(WAI,E1)\n"}, AlarmCode.BAD_ARGUMENT, 2),
    ],
)
def test_runtime_errors_become_alarms_with_positions(programs: dict[str, str], code: AlarmCode,
                                                     line: int) -> None:
    sim = simulate(programs)
    (alarm,) = sim.events("alarm")
    assert (alarm["code"], alarm["proc"], alarm["line"]) == (code.label, 1, line)
    assert sim.engine.status(1).alarm_code == int(code)


def test_program_gone_from_storage_at_exe_time_is_an_alarm_of_the_caller() -> None:
    from ...helpers import make_sim

    sim = make_sim({"A": "N1(DLY,1)\nN2#(EXE,2,GONE)\n", "GONE": "N1(REL)\n"})
    sim.engine.start("A")
    del sim.engine.loader.programs["GONE"]  # type: ignore[attr-defined]
    sim.run()
    (alarm,) = sim.events("alarm")
    assert (alarm["code"], alarm["proc"], alarm["line"], alarm["t"]) == ("AL120", 1, 2, 1.0)
    assert alarm["message"] == "program GONE is not on MP0"


def test_snd_to_an_idle_process_message() -> None:
    sim = simulate({"A": "N1(SND,2)\n"})
    assert sim.events("alarm")[0]["message"] == "SND to process 2, which runs no program"


@pytest.mark.parametrize(
    ("text", "seconds"),
    [
        ("N1G1X100F6000\n", 1.0),
        ("N1G0X1000\n", 6.0),
        ("N1G1X3Y4F300\n", 1.0),  # 5 mm at 300 mm/min
        ("N1G91G1X10F600\nN2X10\n", 2.0),  # incremental
        ("N1G1X10F600\nN2G2X10Y0I-5J0\n", 1.0 + (2 * math.pi * 5) / 600 * 60),  # full circle
        ("N1G1X10F600\nN2G3X0Y10I-10J0\n", 1.0 + (math.pi / 2 * 10) / 10),  # quarter circle
        ("N1G1X10F600\nN2G2X0Y10R-10\n", 1.0 + (1.5 * math.pi * 10) / 10),  # 3/4 circle by R
        ("N1G1X10F600\nN2G3X0Y10I-10J0Z10\n",
         1.0 + math.hypot(math.pi / 2 * 10, 10) / 10),  # helix
        ("N1T1.1M6\n", 2.0),
        ("N1(DLY,0.5)\nN2(DLY,E1+0.25)\n", 0.75),
        ("N1M3S1000\n", 0.0),
    ],
)
def test_motion_timing(text: str, seconds: float) -> None:
    sim = simulate({"A": text})
    assert sim.outcome == "idle"
    assert sim.first("end", proc=1)["t"] == pytest.approx(seconds, abs=1e-6)


def test_lookahead_bounds_the_decoder() -> None:
    program = {"A": "N1(EXE,2,B)\nN2G1X10F600\nN3X20\nN4X30\nN5(SND,2)\nN6M30\n",
               "B": "N1(WAI,1)\nN2(REL)\n"}
    times = {la: simulate(program, lookahead=la).first("snd", proc=1)["t"] for la in (0, 1, 2, 16)}
    # lookahead 0: each item finishes before the next block; 1: N4 waits for N2's end.
    assert times == {0: 3.0, 1: 1.0, 2: 0.0, 16: 0.0}


def test_sync_reads_wait_for_the_motion_queue() -> None:
    programs = {"A": "N1G1X10F600\nN2SYVAR2=SYVAR1\nN3M30\n"}
    for sync, expected in ((False, 0), (True, 7)):
        sim = simulate_with_write(programs, sync_reads=sync)
        assert sim.first("write", var="SYVAR2")["value"] == expected
    # The wait is in the trace, as a wait for the interpolator, from N2 until N1's move ends.
    wait = sim.first("wait", proc=1)
    assert (wait["t"], wait["n"], wait["on"]) == (0.0, 2, {"flush": True})
    assert sim.first("resume", proc=1)["t"] == 1.0


def simulate_with_write(programs: dict[str, str], **settings: object):  # type: ignore[no-untyped-def]
    from ...helpers import make_sim

    sim = make_sim(programs, **settings)
    sim.engine.call_at(0.5, lambda: sim.image.write([("SYVAR", 1, "IN", 7)], "plc"))
    sim.engine.start("A")
    sim.run()
    return sim


def test_wait_timeout_raises_an_alarm_with_the_why_record() -> None:
    sim = simulate({"A": "N1(WAI,SK3=1)\nN2M30\n"}, wait_timeout_s=2.5)
    (alarm,) = sim.events("alarm")
    assert (alarm["t"], alarm["code"]) == (2.5, "AL143")
    assert "P1 A.nc:1 N1 (WAI,SK3=1) waits for SK3=1 (now 0)" in alarm["message"]


def test_why_record_names_value_and_last_writer() -> None:
    from ...helpers import make_sim

    sim = make_sim({"A": "N1(WAI,SYVAR4>9)\nN2M30\n"})
    sim.image.write([("SYVAR", 4, "IN", 3)], "modbus 127.0.0.1:51512")
    sim.engine.start("A")
    sim.run()
    wait = sim.engine.status(1).wait
    assert wait is not None
    assert (wait.kind, wait.cond, wait.value, wait.writer) == (
        WaitKind.COND, "SYVAR4>9", 3, "modbus 127.0.0.1:51512")
    assert wait.where == ("A.nc", 1, 1)
    sim.image.write([("SYVAR", 4, "IN", 10)], "plc")
    sim.run()
    assert sim.outcome == "idle" and sim.first("resume", proc=1)["by"] == "cond"


def test_external_process_snd_and_mailbox() -> None:
    from ...helpers import make_sim

    sim = make_sim({"A": "N1(SND,4)\nN2(WAI,4)\nN3M30\n"}, external=frozenset({4}))
    sim.engine.start("A")
    sim.run()
    assert sim.first("snd", proc=1)["to"] == 4  # published, never blocks
    assert sim.engine.status(1).state is ProcessState.WAIT_PROC
    sim.engine.external_snd(4, 1)
    sim.run()
    assert sim.first("resume", proc=1)["by"] == 4 and sim.outcome == "idle"
    with pytest.raises(ValueError, match="not external"):
        sim.engine.external_snd(2, 1)


def test_e_parameters_are_per_process_syvars_shared() -> None:
    programs = {"A": "N1E1=5\nN2SYVAR1=E1\nN3(EXE,2,B)\nN4M30\n", "B": "N1SYVAR2=E1+SYVAR1\n"}
    sim = simulate(programs)
    assert sim.first("write", var="SYVAR2")["value"] == 5  # B's E1 is 0, SYVAR1 is 5


def test_assignment_rounds_half_away_from_zero() -> None:
    sim = simulate({"A": "N1E8=10.3+20.7\nN2SYVAR2=E8\nN3SYVAR3=-2.5\nN4SYVAR4=2.5\n"})
    values = [e["value"] for e in sim.events("write")]
    assert values == [31, -3, 3]


def test_a_jump_out_of_an_rpt_body_ends_its_repeat() -> None:
    """Issue 25: a loop that jumps back to its RPT stacked one repeat frame a turn (388 MB
    after 40 simulated s).  Leaving the body pops the frame: the stack stays one deep."""
    sim = make_sim({"A": '"L"(RPT,2)\nG91G1X0.001F6000\n(BNC,L)\n(ERP)\nM30\n'})
    sim.engine.start("A")
    depths = []
    # A move of 0.001 mm at 100 mm/s is 10 us: 0.02 s is 2,000 turns of the loop.
    for until in (0.004, 0.008, 0.012, 0.016, 0.02):
        sim.run(until=until)
        depths.append(len(sim.engine.processes[1].repeats))
    assert sim.engine.status(1).blocks > 1_000  # it looped
    assert depths == [1] * 5


def test_a_jump_out_of_nested_repeats_then_their_erp_counts_right() -> None:
    """Jumping out of an inner body to the outer body's ERP ends the inner repeat only: the
    outer one still repeats its count (3 x E1 += 1)."""
    text = ('(RPT,3)\n(RPT,5)\nE1=E1+1\n(BNC,NEXT)\n(ERP)\n"NEXT"\n(ERP)\n'
            "SYVAR1=E1\nM30\n")
    sim = simulate({"A": text})
    assert sim.outcome == "idle" and sim.image.read("SYVAR", 1, "IN") == 3
    assert sim.engine.processes[1].repeats == []


def test_repeat_and_branches() -> None:
    text = ('N1E1=0\n"TOP"\nN2(RPT,3)\nN3(RPT,2)\nN4E1=E1+1\nN5(ERP)\nN6(ERP)\n'
            "N7(BLT,E1,12,TOP)\nN8SYVAR1=E1\nN9(BNC,END)\nN10SYVAR1=99\n\"END\"\nN11M30\n")
    sim = simulate({"A": text})
    assert [e["value"] for e in sim.events("write")] == [12]


def test_alarm_stops_motion_and_reset_clears_everything() -> None:
    programs = {"A": "N1(EXE,2,B)\nN2G1X100F600\nN3E1=1/0\n", "B": "N1(WAI,1)\nN2(REL)\n"}
    sim = simulate(programs, lookahead=0)
    assert sim.engine.status(1).state is ProcessState.ALARM
    assert sim.outcome == "blocked"  # P2 waits for P1, which is in ALARM
    sim.engine.reset()
    assert all(sim.engine.status(k).state is ProcessState.IDLE for k in range(1, 6))
    assert [e["how"] for e in sim.events("end")] == ["reset", "reset"]
    sim.engine.start("A")  # it can run again
    assert sim.engine.status(1).state is ProcessState.RUNNING


def test_feed_hold_pauses_motion() -> None:
    from ...helpers import make_sim

    sim = make_sim({"A": "N1G1X100F6000\nN2M30\n"})  # 1 s
    sim.engine.start("A")
    sim.engine.call_at(0.25, lambda: sim.engine.hold(True))
    sim.engine.call_at(2.25, lambda: sim.engine.hold(False))
    sim.run()
    assert sim.first("end", proc=1)["t"] == pytest.approx(3.0)
    position = sim.engine.status(1).position
    assert position[0] == pytest.approx(100.0)


def test_blocks_counter_and_programs_run() -> None:
    sim = simulate({"A": "; comment\nN1G1X1F60\n\nN2(RPT,3)\nN3E1=E1+1\nN4(ERP)\nN5M30\n"})
    stats = sim.engine.processes[1].stats
    assert stats.blocks == 1 + 1 + 3 * 2 + 1  # N1, N2, 3x(N3, N4), N5
    assert stats.programs == 1


def test_a_plain_exe_after_motion_is_a_hazard_like_a_plain_snd() -> None:
    # N2's EXE starts B at decode time, while N1's move is still queued: on the machine B
    # starts before X10 is reached.  A # EXE acts in motion order, with no hazard.
    programs = {"A": "N1G1X10F600\nN2(EXE,2,B)\nN3M30\n", "B": "N1(REL)\n"}
    sim = simulate(programs)
    (hazard,) = sim.events("hazard")
    assert (hazard["proc"], hazard["t"], hazard["n"]) == (1, 0.0, 2)
    assert hazard["message"].startswith("(EXE,2,B) acted at decode time while motion "
                                        "programmed above it (N1) was still queued")
    assert sim.first("exe", proc=1)["t"] == 0.0
    synced = simulate({"A": "N1G1X10F600\nN2#(EXE,2,B)\nN3M30\n", "B": "N1(REL)\n"})
    assert synced.events("hazard") == [] and synced.first("exe", proc=1)["t"] == 1.0
    assert simulate({"A": "N1(EXE,2,B)\nN2G1X10F600\nN3M30\n", "B": "N1(REL)\n"}).events(
        "hazard") == []


def test_a_decode_time_read_of_the_processs_own_queued_hash_write_is_a_hazard() -> None:
    # N2 writes SYVAR1 in motion order (t = 1); N3 reads it when the decoder reaches it (t = 0)
    # and so reads the value before N2's write.  A read of another SYVAR, or with
    # nc.sync_reads (the decoder first waits for the motion), is no hazard.
    text = "N1G1X10F600\nN2#SYVAR1=5\nN3E1=SYVAR1+SYVAR2\nN4(BEQ,SYVAR1,5,L)\n\"L\"N5M30\n"
    sim = simulate({"A": text})
    hazards = [(e["n"], e["t"]) for e in sim.events("hazard")]
    assert hazards == [(3, 0.0), (4, 0.0)]
    assert sim.events("hazard")[0]["message"].startswith(
        "SYVAR1 read at decode time while this process's # write of it (N2) was still queued")
    assert sim.engine.processes[1].E[1] == 0  # the old value: what the hazard warns about
    assert simulate({"A": text.replace("SYVAR1+", "SYVAR3+").replace(",SYVAR1,", ",SYVAR3,")}
                    ).events("hazard") == []
    flushed = simulate({"A": text}, sync_reads=True)
    assert flushed.events("hazard") == [] and flushed.engine.processes[1].E[1] == 5


def test_a_stall_on_a_process_in_alarm_names_that_alarm() -> None:
    """P1 waits for an SND from P2, which is in ALARM: what ends the stall is that alarm's
    reset, so the report says which alarm, and where."""
    programs = {"A": "N1(EXE,2,B)\nN2(WAI,2)\nN3M30\n", "B": "N1E1=0\nN2E2=5/E1\nN3(SND,1)\n"}
    sim = simulate(programs)
    assert sim.outcome == "blocked"
    (blocked,) = sim.engine.blocked()
    assert blocked.proc == 1 and blocked.reason.endswith(
        "; P2 is in ALARM AL101 at B.nc:2 N2: division by zero")


def test_the_run_logs_stall_line_keeps_the_n_numbers() -> None:
    from ncgate.gateway.cli.serve import describe
    from ncgate.interpreter.engine import events as ev

    sim = simulate({"A": "N1G1X1F60\nN7(WAI,SA10=1)\nN8M30\n"})
    stall = ev.Stall(1, sim.engine.now, 0, None, sim.engine.blocked())
    assert describe(stall) == "stall: P1 A.nc:2 N7 (WAI,SA10=1) waits for SA10=1 (now 0)"


def test_a_latched_snd_discarded_because_its_target_ended_is_a_hazard_in_the_trace() -> None:
    """Under latched SNDs, P1's SND to P2 waits as a token; P2 ends without taking it: the
    token is dropped, and the trace says so (it said nothing)."""
    programs = {"A": "N1(EXE,2,B)\nN2(SND,2)\nN3M30\n", "B": "N1G1X1F600\nN2M30\n"}
    sim = simulate(programs, snd=SndPolicy.LATCHED)
    assert sim.outcome == "idle"
    dropped = [e for e in sim.events("hazard") if "discarded" in e["message"]]
    assert [(e["proc"], e["n"], e["t"]) for e in dropped] == [(1, 2, 0.1)]
    assert dropped[0]["message"] == ("latched SND from P1 at A.nc:2 N2 to P2 discarded: P2 "
                                     "ended its program before a WAI took it")


def test_a_reset_of_one_process_frees_it_for_the_exe_waiting_on_it() -> None:
    """P1's EXE waits for busy P2; a reset of P2 alone ends B and starts C there, as B's
    end would; P1 was never reset."""
    programs = {"A": "N1(EXE,2,B)\nN2(EXE,2,C)\nN3(WAI,2)\nN4M30\n",
                "B": "N1(WAI,SA1=1)\nN2M30\n", "C": "N1(SND,1)\nN2M30\n"}
    sim = make_sim(programs)
    sim.engine.start("A")
    sim.engine.call_at(1.0, lambda: sim.engine.reset(2))
    sim.run()
    assert sim.outcome == "idle" and sim.events("alarm") == []
    ends = [(e["proc"], e["how"]) for e in sim.events("end")]
    assert ends[0] == (2, "reset") and sorted(ends[1:]) == [(1, "M30"), (2, "M30")]
    assert sim.first("start", prog="C")["t"] == 1.0


def test_single_block_stops_after_each_block_until_a_cycle_start() -> None:
    """Single block: the process stops (STEP) after each block, a move completing first; a
    WAI still waits; each cycle start runs one block more."""
    sim = make_sim({"A": "N1G1X10F600\nN2E1=5\nN3(WAI,SA1=1)\nN4M30\n"})
    engine = sim.engine
    engine.single_block(True)
    engine.start("A")
    sim.run()
    # N1's move ran to its end (1 s), then the process stopped before N2.
    assert engine.status(1).state is ProcessState.STEP and engine.now == 1.0
    assert engine.processes[1].E[1] == 0.0
    engine.cycle_start()
    sim.run()
    assert engine.status(1).state is ProcessState.STEP and engine.processes[1].E[1] == 5.0
    engine.cycle_start()  # N3 waits, single block or not
    sim.run()
    assert engine.status(1).state is ProcessState.WAIT_COND
    sim.image.write([("SA", 1, "bit", 1)], "plc")
    sim.run()
    assert engine.status(1).state is ProcessState.STEP  # after N3: the wait is the block
    engine.single_block(False)  # off: it goes on by itself
    sim.run()
    assert engine.status(1).state is ProcessState.IDLE


def test_a_step_runs_exactly_one_block_of_a_running_program() -> None:
    sim = make_sim({"A": "N1E1=1\nN2E1=2\nN3E1=3\nN4M30\n"})
    engine = sim.engine
    engine.start("A")
    engine.step(1)  # running, not in single block: it stops after the block it is in
    sim.run()
    assert engine.status(1).state is ProcessState.STEP and engine.processes[1].E[1] == 1.0
    engine.step(1)
    sim.run()
    assert engine.status(1).state is ProcessState.STEP and engine.processes[1].E[1] == 2.0
    engine.cycle_start()  # not in single block: it runs to its end
    sim.run()
    assert engine.status(1).state is ProcessState.IDLE and engine.processes[1].E[1] == 3.0


def test_the_feed_override_scales_feed_moves_only() -> None:
    """50 %: a G1 of 1 s takes 2 s; a G0 (rapid override 100 %) and a dwell keep theirs."""
    programs = {"A": "N1G1X10F600\nN2G0X0\nN3(DLY,1)\nN4M30\n"}
    sim = make_sim(programs, rapid_mm_min=600.0)
    sim.engine.override(feed=50)
    sim.engine.start("A")
    sim.run()
    assert sim.first("end", proc=1)["t"] == pytest.approx(2.0 + 1.0 + 1.0)
    events = sim.events("override")  # one per process of the cell
    assert [(e["proc"], e["feed"], e["rapid"], e["t"]) for e in events] == [
        (k, 50, 100, 0.0) for k in range(1, 6)]


def test_an_override_changed_mid_move_acts_from_where_the_move_is() -> None:
    """At 0.5 s a 1 s move is half done; at 200 % its other half takes 0.25 s.  At 0 % it
    stands (RUNNING, not HOLD), and goes on when raised."""
    sim = make_sim({"A": "N1G1X10F600\nN2M30\n"})
    engine = sim.engine
    engine.start("A")
    engine.call_at(0.5, lambda: engine.override(feed=200))
    sim.run()
    assert sim.first("end", proc=1)["t"] == pytest.approx(0.75)

    sim = make_sim({"A": "N1G1X10F600\nN2M30\n"})
    engine = sim.engine
    engine.start("A")
    engine.call_at(0.25, lambda: engine.override(feed=0))
    seen: list[tuple[ProcessState, float]] = []
    engine.call_at(5.0, lambda: seen.append((engine.status(1).state,
                                             engine.status(1).position[0])))
    engine.call_at(6.0, lambda: engine.override(feed=100))
    sim.run()
    assert seen == [(ProcessState.RUNNING, pytest.approx(2.5))]
    assert sim.first("end", proc=1)["t"] == pytest.approx(6.75)


def test_moving_time_is_the_time_the_moves_took() -> None:
    """The process's moving seconds (sim's summary, "moving s") are the machine time its moves
    ran: 2 s for a 1 s move at 50 %, nothing for a 0 % stand or a hold, the part of a move
    an NC reset cut short -- not each move's nominal time, counted when it ended.  A stand at
    0 % is waiting time, as a feed hold is."""
    sim = make_sim({"A": "N1G1X10F600\nN2M30\n"})
    sim.engine.override(feed=50)
    sim.engine.start("A")
    sim.run()
    assert sim.engine.processes[1].stats.moving_s == pytest.approx(2.0)

    sim = make_sim({"A": "N1G1X10F600\nN2G1X0\nN3M30\n"})
    engine = sim.engine
    engine.start("A")
    engine.call_at(0.25, lambda: engine.override(feed=0))  # stands 1 s
    engine.call_at(1.25, lambda: engine.override(feed=100))
    engine.call_at(1.5, lambda: engine.hold(True))  # held 2 s
    engine.call_at(3.5, lambda: engine.hold(False))
    engine.call_at(4.25, lambda: engine.reset())  # N1 ended at 4.0; N2 cut short
    sim.run()
    assert sim.first("end", proc=1)["t"] == pytest.approx(4.25)
    # N1: 0.25 s before the stand, 0.25 s before the hold, its last 0.5 s; N2: 0.25 s
    stats = engine.processes[1].stats
    assert stats.moving_s == pytest.approx(0.25 + 0.25 + 0.5 + 0.25)
    # The 1 s standing at 0 % is waiting time, as the 2 s hold is (it was running time).
    assert (stats.running_s, stats.waiting_s) == (pytest.approx(1.25), pytest.approx(3.0))


def test_a_move_under_way_when_the_run_stops_counts_its_moving_time_so_far() -> None:
    """--until (or a SIGTERM) in the middle of a move: its 2.5 s so far are moving time
    (they were counted only if an override had happened to stop its timer), once however
    often the summary is made; the move goes on from where it was."""
    sim = make_sim({"A": "N1G1X100F1000\nN2M30\n"})  # 6 s
    sim.engine.start("A")
    sim.run(until=2.5)
    for _ in range(2):
        sim.engine.finish_stats()
        assert sim.engine.processes[1].stats.moving_s == pytest.approx(2.5)
    sim.run()
    assert sim.first("end", proc=1)["t"] == pytest.approx(6.0)
    sim.engine.finish_stats()
    assert sim.engine.processes[1].stats.moving_s == pytest.approx(6.0)


def test_a_feed_hold_during_a_hash_blocks_move_keeps_its_time() -> None:
    """A move inside a # block held at 0.5 s and resumed at 2.5 s ends at 3.0 s; it ended
    at once on resume before (the hold measured the # block, not its move)."""
    sim = make_sim({"A": "N1#G1X10F600\nN2M30\n"})
    engine = sim.engine
    engine.start("A")
    engine.call_at(0.5, lambda: engine.hold(True))
    engine.call_at(2.5, lambda: engine.hold(False))
    sim.run()
    assert sim.first("end", proc=1)["t"] == pytest.approx(3.0)


def test_m00_stops_after_its_block_and_m01_only_with_optional_stop() -> None:
    """M00: the process stops once the block (and its move) is done, until a cycle start;
    M01 the same while the optional-stop switch is on, else it goes on."""
    text = "N1G1X10F600M00\nN2SYVAR1=1\nN3M01\nN4SYVAR1=2\nN5M30\n"
    sim = make_sim({"A": text})
    engine = sim.engine
    engine.start("A")
    sim.run()
    assert engine.status(1).state is ProcessState.STEP and engine.now == 1.0
    engine.cycle_start()
    sim.run()  # M01 with the switch off: through to the end
    assert engine.status(1).state is ProcessState.IDLE
    assert [e["value"] for e in sim.events("write")] == [1, 2]

    sim = make_sim({"A": text})
    engine = sim.engine
    engine.switch(optional_stop=True)
    engine.start("A")
    sim.run()
    engine.cycle_start()
    sim.run()
    assert engine.status(1).state is ProcessState.STEP  # at M01
    assert [e["value"] for e in sim.events("write")] == [1]


def test_the_block_skip_switch_acts_on_blocks_decoded_after_it() -> None:
    sim = make_sim({"A": "N1SYVAR1=1\n/N2SYVAR1=2\nN3(WAI,SA1=1)\n/N4SYVAR1=4\nN5M30\n"})
    engine = sim.engine
    engine.start("A")
    sim.run()  # the switch is off: N2 runs
    engine.switch(block_skip=True)  # before N4 is decoded
    sim.image.write([("SA", 1, "bit", 1)], "plc")
    sim.run()
    assert [e["value"] for e in sim.events("write") if e["var"] == "SYVAR1"] == [1, 2]


def test_a_block_breakpoint_stops_before_its_block_and_a_cycle_start_goes_on() -> None:
    from ncgate.interpreter.engine.breaks import parse_breakpoint

    programs = {"A": "N1(EXE,2,B)\nN2SYVAR1=1\nN3G1X10F600\nN4SYVAR1=2\nN5M30\n",
                "B": "N10G1X100F600\nN20M30\n"}
    sim = make_sim(programs)
    engine = sim.engine
    engine.set_break(parse_breakpoint("a.nc:4"))  # the file's stem, any case
    engine.start("A")
    sim.run()
    (hit,) = sim.events("break")
    # The decoder reached N4 at t = 0 (plain codes act at decode time, lookahead 16).
    assert (hit["proc"], hit["line"], hit["n"], hit["breakpoint"], hit["t"]) == (
        1, 4, 4, "A:4", 0.0)
    # P1 stopped before N4 (its SYVAR1 is still 1); P2's move is held, not ended.
    assert sim.image.read("SYVAR", 1, "IN") == 1
    assert engine.status(2).state is ProcessState.HOLD
    engine.cycle_start()
    sim.run()
    assert sim.image.read("SYVAR", 1, "IN") == 2 and engine.all_idle
    assert sim.first("end", proc=2)["t"] == pytest.approx(10.0)  # it moved again after


def test_a_wait_breakpoint_and_run_to_sync_stop_the_cell() -> None:
    from ncgate.interpreter.engine.breaks import parse_breakpoint

    programs = {"A": "N1G1X10F600\nN2(WAI,2)\nN3M30\n", "B": "N1G1X20F600\nN2(SND,1)\nN3M30\n"}
    sim = make_sim(programs)
    engine = sim.engine
    engine.set_break(parse_breakpoint("P1 wait WAI"))
    engine.start("A")
    engine.start("B", 2)
    sim.run()
    (hit,) = sim.events("break")
    assert (hit["proc"], hit["n"], hit["t"], hit["breakpoint"]) == (1, 2, 0.0, "P1 wait WAI")
    assert engine.status(2).state is ProcessState.HOLD  # P2's move held
    engine.set_break(parse_breakpoint("P1 wait WAI"), on=False)
    engine.set_break(parse_breakpoint("sync"))  # the next sync event of anyone
    engine.cycle_start()
    sim.run()
    hits = sim.events("break")
    assert [(h["proc"], h["n"], h["breakpoint"]) for h in hits[1:]] == [(2, 2, "sync")]
    assert engine.breakpoints == []  # run to sync is one-shot
    engine.cycle_start()
    sim.run()
    assert engine.all_idle and sim.events("alarm") == []


def test_breakpoints_are_parsed_as_engineers_write_them() -> None:
    from ncgate.interpreter.engine.breaks import parse_breakpoint

    assert parse_breakpoint("PROG92:8").text == "PROG92:8"
    assert parse_breakpoint("prog92.nc:8").program == "PROG92"
    assert parse_breakpoint("n40").n == 40 and parse_breakpoint("N40").process is None
    assert parse_breakpoint("P2  wait").process == 2
    assert parse_breakpoint("P2 wait exe").text == "P2 wait EXE"
    for bad in ("", "P0 N4", "P2 sync", "wait forever", "PROG92:0", "X40"):
        with pytest.raises(ValueError):
            parse_breakpoint(bad)


def test_a_block_search_starts_at_a_label_or_n_with_the_modal_state_before_it() -> None:
    """Start at N40: G1, F600, G91 and X10 of the blocks before it are in force, nothing of
    them acted (no SYVAR write ran, no time passed); with calculation E1 is 5."""
    text = "N10G1F600\nN20E1=5\nN30G91X10\nN40XE1\nN50SYVAR1=E1\nN60M30\n"
    sim = make_sim({"A": text})
    engine = sim.engine
    engine.start("A", at="N40", with_calc=True)
    sim.run()
    # N40 moves X by E1 = 5 mm (incremental) from X10 at F600: 0.5 s.
    assert sim.first("end", proc=1)["t"] == pytest.approx(0.5)
    assert engine.processes[1].actual[0] == pytest.approx(15.0)
    assert [e["value"] for e in sim.events("write")] == [5]
    assert sim.first("start", proc=1)["t"] == 0.0

    sim = make_sim({"A": text})
    sim.engine.start("A", at="N40")  # without calculation: E1 stays 0, no move
    sim.run()
    assert sim.engine.processes[1].actual[0] == pytest.approx(10.0)


def test_a_block_search_is_refused_where_the_skipped_blocks_sync() -> None:
    from ncgate.interpreter.settings import BlockSearchSync

    programs = {"A": '"L"N1G1X1F600\nN2(SND,2)\nN3X2\nN4(BNC,L)\nN5M30\n', "B": "N1M30\n"}
    # The rule by skipped blocks (the default refuses any search in A: test_block_search_sync)
    sim = make_sim(programs, block_search_sync=BlockSearchSync.SKIPPED)
    for at, reason in (("N3", "(SND,2) is a synchronisation code"),
                       ("N5", "(SND,2) is a synchronisation code"),
                       ("N9", "no block N9"), ("NOWHERE", "no label")):
        with pytest.raises(ValueError, match=re.escape(reason)):
            sim.engine.start("A", at=at)
    assert sim.engine.status(1).state is ProcessState.IDLE and sim.events("start") == []


def test_nc_feed_override_is_every_processs_override_at_start() -> None:
    sim = simulate({"A": "N1G1X10F600\nN2M30\n"}, feed_override=50)
    assert sim.first("end", proc=1)["t"] == pytest.approx(2.0)
