"""The orphan check asks whether something outside the programs may still start the awaited
process (``Sync.outside_starts``): the contract gateway/sim.py keeps for a script's pending
cycle start (the issue "What the field found", item 5)."""

from __future__ import annotations

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import ProcessState

from ...helpers import make_sim

# O1 starts O2 in P2 and ends; O2 waits for an SND from P1.  A cycle start later starts main
# (O3) in P1, which sends.
PROGRAMS = {"O1": "N1(EXE,2,O2)\nN2SYVAR1=1\nN3M30\n", "O2": "N1(WAI,1)\nN2M30\n",
            "O3": "N1(SND,2)\nN2M30\n"}


def test_a_wait_on_a_process_an_operator_start_will_restart_is_no_orphan() -> None:
    sim = make_sim(PROGRAMS, main="O3")
    engine = sim.engine
    engine.sync.outside_starts = lambda n: n == 1  # sim: a pending script cycle start
    engine.start("O1")
    engine.call_at(5.0, engine.cycle_start)
    sim.run()
    assert sim.events("alarm") == []
    assert sim.first("resume", proc=2)["t"] == 5.0
    assert engine.status(2).state is ProcessState.IDLE


def test_without_an_outside_start_it_is_an_orphan_at_once() -> None:
    sim = make_sim(PROGRAMS, main="O3")
    sim.engine.start("O1")
    sim.run()
    alarm = sim.first("alarm", proc=2)
    assert (alarm["code"], alarm["t"], alarm["line"]) == (AlarmCode.ORPHAN_WAIT.label, 0.0, 1)
