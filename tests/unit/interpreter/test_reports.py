"""Issue 9.4: reports say what happened -- the live why-record, a # block's write at its own
block, and every member of an SND cycle alarmed as the deadlock."""

from __future__ import annotations

from ...helpers import make_sim, simulate


def test_the_why_record_shows_the_current_value_and_its_last_writer() -> None:
    sim = make_sim({"A": "N10(WAI,SYVAR1=5)\nN20M30\n"})
    sim.engine.start("A")
    sim.run()
    (blocked,) = sim.engine.blocked()
    assert blocked.reason == "(WAI,SYVAR1=5) waits for SYVAR1=5 (now 0)"
    sim.image.write([("SYVAR", 1, "IN", 3)], "script")
    sim.run()
    (blocked,) = sim.engine.blocked()
    assert blocked.reason == "(WAI,SYVAR1=5) waits for SYVAR1=5 (now 3, last written by script)"
    assert sim.engine.status(1).wait is not None
    assert "now 3" in sim.engine.status(1).wait.reason()  # the status registers' record too
    # The wait event keeps what held when the wait began: it is history.
    assert sim.first("wait")["on"] == {"cond": "SYVAR1=5", "value": 0}


def test_a_write_in_a_hash_block_is_reported_at_its_own_block() -> None:
    program = ("N10G1X100F6000\nN20#SYVAR1=7\nN30G1X0\nN40G1X100\nN50G1X0\nN60M30\n")
    sim = simulate({"A": program})
    write = sim.first("write", var="SYVAR1")
    assert (write["line"], write["n"], write["who"]) == (2, 20, "P1 N20")
    # It acted when the interpolator got there (after the first move), not at decode time.
    assert write["t"] == 1.0


def test_every_member_of_an_snd_cycle_is_alarmed_as_the_deadlock() -> None:
    sim = simulate({"A": "N1(EXE,2,B)\nN2(SND,2)\nN3M30\n", "B": "N1(SND,1)\nN2M30\n"})
    alarms = {e["proc"]: e["code"] for e in sim.events("alarm")}
    assert alarms == {1: "AL140", 2: "AL140"}
    assert len(sim.events("deadlock")) == 1
