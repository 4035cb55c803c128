"""The engine's timer heap (interpreter/engine/timers.py): timers of one time fire in arm
order, and a late one after every other timer of its time -- a script's entry, which a replay
applies after them (docs/decisions.md, "Script entries act after the timers of their
instant")."""

from __future__ import annotations

from ncgate.interpreter.engine.timers import TimerHeap, due_time, snapped


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


def test_one_instant_worked_out_two_ways_is_one_time_its_timers_in_arm_order() -> None:
    """A relay switched by the scan at 2.01 s (201 * 0.01) that waits 200 ms is due at
    2.2100000000000004; the scan at 2.21 s (221 * 0.01) is 2.21.  On the nanosecond grid they
    are one time, and the relay, armed first, fires first: the scan sees it."""
    assert 201 * 0.01 + 0.2 != 221 * 0.01  # (the float noise the grid takes out)
    heap = TimerHeap()
    fired: list[str] = []
    heap.push(201 * 0.01 + 0.2, lambda: fired.append("relay"))
    heap.push(221 * 0.01, lambda: fired.append("scan"))
    assert heap.next_time() == 2.21
    fire_all(heap, 2.21)
    assert fired == ["relay", "scan"]


def test_a_late_timer_of_an_instant_worked_out_two_ways_comes_after_its_scan() -> None:
    """A script's entry 1 s after a scan at 3.27 s is due with the scan at 4.27 s, whichever
    float each came to: the entry acts after the scan (late), the next scan sees it."""
    heap = TimerHeap()
    fired: list[str] = []
    heap.push(327 * 0.01 + 1.0, lambda: fired.append("entry"), late=True)
    heap.push(427 * 0.01, lambda: fired.append("scan"))
    fire_all(heap, 4.27)
    assert fired == ["scan", "entry"]


def test_due_time_is_on_the_grid_and_never_before_a_now_on_it() -> None:
    assert due_time(2.2100000000000004, 2.01) == snapped(2.21) == 2.21
    assert due_time(1.0, 2.21) == 2.21  # passed: now
    # An off-grid now (the wall clock's) may give a hair before it: due at once.
    now = 1.0000000002
    assert due_time(now, now) == 1.0 <= now


def test_early_timers_fire_before_every_other_timer_of_their_time_in_arm_order() -> None:
    """The plant's tick is early: armed long before (its cadence) or just now (past a
    quiet tail), it fires before the scan of its instant, and early ones in arm order."""
    heap = TimerHeap()
    fired: list[str] = []
    heap.push(2.0, lambda: fired.append("scan"))
    heap.push(2.0, lambda: fired.append("entry"), late=True)
    heap.push(2.0, lambda: fired.append("tick"), early=True)
    heap.push(1.0, lambda: fired.append("plain before"))
    heap.push(2.0, lambda: fired.append("tick 2"), early=True)
    fire_all(heap, 2.0)
    assert fired == ["plain before", "tick", "tick 2", "scan", "entry"]


def test_first_timers_come_after_the_early_ones_and_before_the_rest() -> None:
    """run --script's start at a scan's instant: after the plant's tick of that instant,
    however long before the tick it was armed, and before the scan; pop_early (a replay,
    applying the recorded start first) takes the early ones only."""
    heap = TimerHeap()
    fired: list[str] = []
    heap.push(2.0, lambda: fired.append("start"), first=True)
    heap.push(2.0, lambda: fired.append("scan"))
    heap.push(2.0, lambda: fired.append("tick"), early=True)
    heap.push(2.0, lambda: fired.append("entry at 0"), first=True)
    while (timer := heap.pop_early(2.0)) is not None:
        assert timer.callback is not None
        timer.callback()
    assert fired == ["tick"]
    fire_all(heap, 2.0)
    assert fired == ["tick", "start", "entry at 0", "scan"]
