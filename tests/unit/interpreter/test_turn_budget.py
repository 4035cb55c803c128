"""A turn of the engine on the wall clock ends when its driver says it has taken long
enough (``Engine.turn_over``), not only after ``blocks`` timers: timers differ in weight."""

from __future__ import annotations

from ...helpers import make_sim


def test_a_turn_ends_when_the_driver_says_so_and_the_next_goes_on_from_there() -> None:
    sim = make_sim({"A": "N1M30\n"})
    engine = sim.engine
    fired: list[float] = []
    for i in range(10):
        engine.call_at(0.001 * i, lambda i=i: fired.append(i))
    asks = []

    def over() -> bool:
        asks.append(len(fired))
        return len(fired) >= 3  # "long enough" after the third timer

    engine.turn_over = over
    assert engine.advance_to(1.0, blocks=1_000) is True  # work left: the caller comes back
    assert fired == [0, 1, 2]
    engine.turn_over = None
    assert engine.advance_to(1.0, blocks=1_000) is False
    assert fired == list(range(10))  # in order, none lost, none twice
    assert asks == [1, 2, 3]


def test_without_a_say_only_blocks_bound_a_turn() -> None:
    sim = make_sim({"A": "N1M30\n"})
    engine = sim.engine
    fired: list[int] = []
    for i in range(10):
        engine.call_at(0.001 * i, lambda i=i: fired.append(i))
    assert engine.advance_to(1.0, blocks=4) is True
    assert len(fired) == 4
