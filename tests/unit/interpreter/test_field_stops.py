"""What the field found about stops (the issue "What the field found", items 4, 6, 7, 11):
where a stopped process stands, what ends an M00/M01 stop, what a stall under a 0 %
override names, and the trace events of stops, steps and feed holds."""

from __future__ import annotations

from ncgate.interpreter.engine import ProcessState
from ncgate.interpreter.engine.breaks import parse_breakpoint

from ...helpers import make_sim

# --- item 4: the block N while stopped is the block the process stopped after --------------


def test_single_block_shows_the_block_it_stopped_after() -> None:
    sim = make_sim({"A": "N10E1=1\nN20E1=2\nN30M30\n"})
    engine = sim.engine
    engine.single_block(True)
    engine.start("A")
    sim.run()
    status = engine.status(1)
    assert status.state is ProcessState.STEP
    assert (status.line, status.n) == (1, 10)
    engine.cycle_start()
    sim.run()
    assert (engine.status(1).line, engine.status(1).n) == (2, 20)
    engine.hold(True)  # a feed hold keeps it
    assert engine.status(1).state is ProcessState.HOLD
    assert (engine.status(1).line, engine.status(1).n) == (2, 20)


def test_a_block_breakpoint_shows_the_block_before_the_breakpoint() -> None:
    sim = make_sim({"A": "N10E1=1\nN20E1=2\nN30E1=3\nN40M30\n"})
    engine = sim.engine
    engine.set_break(parse_breakpoint("N30"))
    engine.start("A")
    sim.run()
    (hit,) = sim.events("break")
    assert hit["n"] == 30
    status = engine.status(1)
    assert (status.line, status.n) == (2, 20)  # it stands after N20, N30 not run
    assert engine.processes[1].E[1] == 2.0


def test_run_to_sync_shows_the_block_of_the_sync_code() -> None:
    sim = make_sim({"A": "N10E1=1\nN20(EXE,2,B)\nN30E1=3\nN40M30\n",
                    "B": "N5G1X10F600\nN6M30\n"})
    engine = sim.engine
    engine.set_break(parse_breakpoint("sync"))
    engine.start("A")
    sim.run()
    status = engine.status(1)
    assert (status.line, status.n) == (2, 20)  # stopped after the EXE's block


# --- item 6: switching single block off does not leave an M00/M01 stop --------------------


def test_single_block_off_leaves_an_m01_stop_standing() -> None:
    sim = make_sim({"A": "N10M01\nN20SYVAR1=1\nN30M30\n"})
    engine = sim.engine
    engine.switch(optional_stop=True)
    engine.single_block(True)
    engine.start("A")
    sim.run()
    assert engine.status(1).state is ProcessState.STEP
    engine.single_block(False)
    sim.run()
    assert engine.status(1).state is ProcessState.STEP and sim.image.read("SYVAR", 1, "IN") == 0
    engine.cycle_start()  # NC start leaves it
    sim.run()
    assert engine.status(1).state is ProcessState.IDLE and sim.image.read("SYVAR", 1, "IN") == 1


def test_single_block_off_leaves_an_m00_stop_standing() -> None:
    sim = make_sim({"A": "N10M00\nN20SYVAR1=1\nN30M30\n"})
    engine = sim.engine
    engine.start("A")
    sim.run()
    assert engine.status(1).state is ProcessState.STEP
    engine.single_block(False)
    sim.run()
    assert engine.status(1).state is ProcessState.STEP and sim.image.read("SYVAR", 1, "IN") == 0


def test_single_block_off_still_releases_a_single_block_stop() -> None:
    sim = make_sim({"A": "N10E1=1\nN20SYVAR1=1\nN30M30\n"})
    engine = sim.engine
    engine.single_block(True)
    engine.start("A")
    sim.run()
    engine.single_block(False)
    sim.run()
    assert engine.status(1).state is ProcessState.IDLE and sim.image.read("SYVAR", 1, "IN") == 1


# --- item 7: a stall under a 0 % override names the standing move --------------------------


def test_a_stall_under_zero_rapid_override_names_the_move() -> None:
    sim = make_sim({"A": "N10G0X100\nN20G1X0F600\nN30M30\n"})
    engine = sim.engine
    engine.override(rapid=0)
    engine.start("A")
    assert sim.run() == "blocked"
    (blocked,) = engine.blocked()
    assert (blocked.proc, blocked.line, blocked.n) == (1, 1, 10)
    assert blocked.reason.startswith("rapid override 0 %")


def test_a_stall_under_zero_feed_override_names_the_move() -> None:
    sim = make_sim({"A": "N10G1X10F600\nN20E1=1\nN30M30\n"})
    engine = sim.engine
    engine.override(feed=0)
    engine.start("A")
    assert sim.run() == "blocked"
    (blocked,) = engine.blocked()
    assert (blocked.line, blocked.n) == (1, 10)
    assert blocked.reason.startswith("feed override 0 %")


# --- item 11: stops, steps and feed holds are trace events ---------------------------------


def test_stops_steps_and_holds_are_in_the_trace() -> None:
    sim = make_sim({"A": "N10G1X10F600\nN20M00\nN30E1=1\nN40E1=2\nN50M30\n"})
    engine = sim.engine
    engine.start("A")
    engine.call_at(0.5, lambda: engine.hold(True, 1))
    engine.call_at(1.0, lambda: engine.cycle_start(process=1))
    sim.run()
    holds = [(e["t"], e["on"], e["n"]) for e in sim.events("hold")]
    assert holds == [(0.5, True, 20), (1.0, False, 20)]  # the decoder waits in N20
    # the move (1 s) resumed at 1.0 ends at 1.5: the M00 stop, after N20, is felt then
    assert [(e["t"], e["cause"], e["n"]) for e in sim.events("stop")] == [(1.5, "M00", 20)]
    engine.step(1)
    sim.run()
    assert [(e["proc"], e["n"]) for e in sim.events("step")] == [(1, 20)]
    assert [(e["cause"], e["n"]) for e in sim.events("stop")][1:] == [("step", 30)]
    engine.single_block(True)
    engine.cycle_start()
    sim.run()
    assert [(e["cause"], e["n"]) for e in sim.events("stop")][2:] == [("single_block", 40)]


def test_a_stop_after_a_block_is_waiting_time_not_running_time() -> None:
    """An M00 stop waits for the operator's cycle start: the summary's "waiting s" (as a feed
    hold's time is), not "running s"."""
    sim = make_sim({"A": "N10E1=1\nN20M00\nN30E1=2\nN40M30\n"})
    engine = sim.engine
    engine.start("A")
    sim.run()
    assert engine.status(1).state is ProcessState.STEP
    stopped_at = engine.now
    engine.advance_to(stopped_at + 30.0)  # the operator comes back after 30 s
    engine.set_time(stopped_at + 30.0)
    engine.cycle_start()
    assert sim.run() == "idle"
    stats = engine.processes[1].stats
    assert stats.waiting_s == 30.0
    assert stats.running_s == stopped_at  # what ran before the stop, and nothing after it
