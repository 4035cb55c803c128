"""Block search and synchronisation codes (seed 000, section 4, note 4: "search is impossible
on programs containing EXE, WAI, SND"): refused in such a program by default; with
``block_search_sync = SKIPPED`` only when the skipped blocks hold one."""

from __future__ import annotations

import pytest

from ncgate.interpreter.nc110.search import SearchRefused
from ncgate.interpreter.settings import BlockSearchSync

from ...helpers import make_sim

PROGRAM = "N1G1X5F600\nN2X10\nN3(WAI,SA1=1)\nN4M30\n"  # the WAI after the target


@pytest.mark.parametrize("code", ["(WAI,SA1=1)", "(SND,2)", "(EXE,2,B)", "(WAI,2)"])
def test_a_block_search_in_a_program_with_a_sync_code_is_refused(code: str) -> None:
    sim = make_sim({"A": f"N1G1X5F600\nN2X10\nN3{code}\nN4M30\n", "B": "N1M30\n"})
    with pytest.raises(SearchRefused, match=r"^A\.nc:3: .*block search is impossible"):
        sim.engine.start("A", at="N2")
    assert sim.engine.processes[1].loaded is None  # nothing started


def test_a_program_without_sync_codes_is_searched() -> None:
    sim = make_sim({"A": "N1G1X5F600\nN2X10\nN3SYVAR1=3\nN4M30\n"})
    sim.engine.start("A", at="N2")
    sim.run()
    assert sim.image.read("SYVAR", 1, "IN") == 3 and sim.engine.processes[1].actual[0] == 10.0


def test_the_skipped_rule_searches_past_no_sync_code() -> None:
    sim = make_sim({"A": PROGRAM}, block_search_sync=BlockSearchSync.SKIPPED)
    sim.engine.start("A", at="N2")
    sim.run()
    assert sim.engine.status(1).line == 3  # it runs N2 and waits in N3
    with pytest.raises(SearchRefused, match=r"A\.nc:3: \(WAI,SA1=1\) is a synchronisation"):
        make_sim({"A": PROGRAM}, block_search_sync=BlockSearchSync.SKIPPED).engine.start(
            "A", at="N4")
