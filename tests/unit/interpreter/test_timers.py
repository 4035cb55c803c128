"""The engine's timer heap (interpreter/engine/timers.py): timers of one time fire in arm
order, and a late one after every other timer of its time -- a script's entry, which a replay
applies after them (docs/decisions.md, "Script entries act after the timers of their
instant")."""

from __future__ import annotations

from ncgate.interpreter.engine.timers import TimerHeap


def fire_all(heap: TimerHeap, t: float) -> None:
    while (timer := heap.pop_due(t)) is not None:
        assert timer.callback is not None
        timer.callback()


def test_late_timers_fire_after_every_other_timer_of_their_time_in_arm_order() -> None:
    heap = TimerHeap()
    fired: list[str] = []

    def arm(t: float, name: str, late: bool = False) -> None:
        heap.push(t, lambda: fired.append(name), late)

    arm(2.0, "late a", late=True)
    arm(2.0, "scan")
    arm(1.0, "late before", late=True)
    arm(2.0, "late b", late=True)
    arm(2.0, "tick")
    fire_all(heap, 2.0)
    assert fired == ["late before", "scan", "tick", "late a", "late b"]


def test_a_timer_armed_while_a_time_fires_comes_before_its_late_ones() -> None:
    """A timer armed by a callback of the instant, for the instant: a plain one fires before
    the late ones still waiting there, a late one after them."""
    heap = TimerHeap()
    fired: list[str] = []

    def scan() -> None:
        fired.append("scan")
        heap.push(5.0, lambda: fired.append("armed by the scan"))
        heap.push(5.0, lambda: fired.append("late, armed by the scan"), late=True)

    def late_a() -> None:
        fired.append("late a")
        heap.push(5.0, lambda: fired.append("armed by late a"))
        heap.push(5.0, lambda: fired.append("late, armed by late a"), late=True)

    heap.push(5.0, late_a, late=True)
    heap.push(5.0, lambda: fired.append("late b"), late=True)
    heap.push(5.0, scan)
    heap.push(5.01, lambda: fired.append("next scan"))
    fire_all(heap, 5.0)
    assert fired == ["scan", "armed by the scan", "late a", "armed by late a", "late b",
                     "late, armed by the scan", "late, armed by late a"]
    assert heap.next_time() == 5.01


def test_a_cancelled_late_timer_does_not_fire() -> None:
    heap = TimerHeap()
    fired: list[str] = []
    heap.push(1.0, lambda: fired.append("late"), late=True).cancel()
    heap.push(1.0, lambda: fired.append("plain"))
    assert heap.live() == 1
    fire_all(heap, 1.0)
    assert fired == ["plain"] and heap.next_time() is None
