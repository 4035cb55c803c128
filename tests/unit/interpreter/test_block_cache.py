"""A long program keeps only its last blocks, parsed and compiled (interpreter/cache.py): the
garbage collector walks a bounded table, not half a million blocks, and a block that runs
again after it was dropped is parsed and compiled again -- with the same effect."""

from __future__ import annotations

import pytest

from ncgate.interpreter import cache
from ncgate.interpreter.cache import BlockCache, block_table
from ncgate.interpreter.nc110.parser import Program

from ...helpers import simulate


def test_the_cache_answers_none_for_what_it_does_not_keep_and_drops_the_oldest() -> None:
    table: BlockCache[str] = BlockCache(limit=3)
    assert table[7] is None and len(table) == 0  # asking keeps nothing
    for i in range(5):
        table[i] = f"b{i}"
    assert dict(table) == {2: "b2", 3: "b3", 4: "b4"}
    table[3] = "again"  # a block kept is replaced in place: nothing is dropped
    assert dict(table) == {2: "b2", 3: "again", 4: "b4"}
    assert table[0] is None


def test_a_short_program_keeps_every_block_in_a_list() -> None:
    assert block_table(10) == [None] * 10
    assert isinstance(block_table(cache.BIG_LINES + 1), BlockCache)


@pytest.fixture
def small_limits(monkeypatch: pytest.MonkeyPatch) -> None:
    """A "long" program of 200 lines keeping 16 blocks: the same code as 65,536 and 1,024."""
    monkeypatch.setattr(cache, "BIG_LINES", 100)
    monkeypatch.setattr(cache, "CACHED_BLOCKS", 16)


def long_program(lines: int) -> str:
    """E1 counts the passes of a loop over ``lines`` blocks, each adding its own number to
    E2: every block runs three times, long after it left the table."""
    body = "".join(f"N{n}E2=E2+{n}\n" for n in range(1, lines + 1))
    return f'"TOP" N0E1=E1+1\n{body}N9000(BLT,E1,3,TOP)\nN9001M30\n'


def test_a_long_program_runs_as_a_short_one_with_a_bounded_table(small_limits: None) -> None:
    sim = simulate({"A": long_program(200)})
    assert sim.outcome == "idle"
    p = sim.engine.processes[1]
    assert p.E[1] == 3 and p.E[2] == 3 * sum(range(1, 201))  # as the numbers say
    loaded = next(iter(sim.engine._loaded.values()))
    assert isinstance(loaded.blocks, BlockCache) and len(loaded.blocks) <= 16
    assert loaded.length == 203
    program = loaded.program
    assert isinstance(program, Program) and len(program._blocks) <= 16


def test_a_long_programs_every_block_is_checked_still(small_limits: None) -> None:
    program = Program("A", "A.nc", long_program(200) + "N9002G1X\n")
    blocks, diagnostics = program.parse_all()
    assert len(blocks) == 204 and blocks[1] is not None and blocks[-1] is None
    assert [d.span.line for d in diagnostics] == [204]  # G1X: an address without a value
