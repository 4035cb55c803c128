"""The I/O image (spec 3.1, 1.3): views, atomic writes, writers, waits woken by index."""

from __future__ import annotations

import pytest

from ncgate.plc.image import FrozenImage, ImageAddressError, ImageValueError, IOImage


def test_views_of_sa_and_k() -> None:
    image = IOImage(sa_bits=32, k_bytes=8, syvars=4)
    image.write([("SA", 1, "BY", 0b0000_0100)], "t")  # bits 8..15: bit 10 set
    assert image.read("SA", 10, "bit") == 1
    assert image.read("SA", 9, "bit") == 0
    image.write([("SK", 2, "IN", -2)], "t")  # little-endian: byte 2 = 0xFE, byte 3 = 0xFF
    assert (image.read("SK", 2, "BY"), image.read("SK", 3, "BY")) == (0xFE, 0xFF)
    assert image.read("SK", 2, "IN") == -2
    image.write([("SA", 0, "IN", 0x0102)], "t")
    assert image.read("SA", 0, "BY") == 2 and image.read("SA", 1, "BY") == 1
    assert image.read("SA", 9, "bit") == 0 and image.read("SA", 8, "bit") == 1


def test_bounds_and_ranges() -> None:
    image = IOImage(sa_bits=16, k_bytes=4, syvars=2)
    for var in (("SA", 16, "bit"), ("SA", 2, "BY"), ("SA", 1, "IN"), ("SK", 4, "BY"),
                ("SK", 3, "IN"), ("SYVAR", 2, "IN")):
        with pytest.raises(ImageAddressError):
            image.read(*var)
    for var, value in ((("SA", 3, "bit"), 2), (("SK", 0, "BY"), 256), (("SK", 0, "BY"), -1),
                       (("SYVAR", 0, "IN"), 32768), (("SK", 0, "IN"), -32769)):
        with pytest.raises(ImageValueError):
            image.write([(*var, value)], "t")


def test_a_request_is_all_or_nothing() -> None:
    image = IOImage(k_bytes=4)
    with pytest.raises(ImageValueError):
        image.write([("SK", 0, "BY", 7), ("SK", 1, "BY", 300)], "t")
    assert image.read("SK", 0, "BY") == 0
    assert image.last_writer("SK", 0, "BY") is None


def test_last_writer_across_views() -> None:
    image = IOImage()
    image.write([("SA", 10, "bit", 1)], "modbus 127.0.0.1:5000")
    assert image.last_writer("SA", 1, "BY") == "modbus 127.0.0.1:5000"
    image.write([("SA", 1, "BY", 0)], "plc")
    assert image.last_writer("SA", 10, "bit") == "plc"
    image.write([("SYVAR", 3, "IN", 5)], "P1 N60")
    assert image.last_writer("SYVAR", 3, "IN") == "P1 N60"


def test_wait_is_level_triggered_and_woken_once_after_the_whole_write() -> None:
    image = IOImage()
    image.write([("SYVAR", 1, "IN", 10)], "t")
    assert image.wait("SYVAR", 1, "IN", lambda v: v == 10, lambda: None) is None  # already true
    seen: list[tuple[int, int]] = []
    wait = image.wait("SYVAR", 1, "IN", lambda v: v > 20,
                      lambda: seen.append((image.read("SYVAR", 1, "IN"),
                                           image.read("SYVAR", 2, "IN"))))
    assert wait is not None
    image.write([("SYVAR", 1, "IN", 15)], "t")
    assert seen == []
    image.write([("SYVAR", 1, "IN", 21), ("SYVAR", 2, "IN", 7)], "t")
    assert seen == [(21, 7)]  # the second value was stored before the wake
    image.write([("SYVAR", 1, "IN", 30)], "t")
    assert seen == [(21, 7)]  # woken once
    assert image.wait_count == 0


def test_bit_waits_see_byte_and_word_writes() -> None:
    image = IOImage()
    woke: list[str] = []
    image.wait("SA", 10, "bit", lambda v: v == 1, lambda: woke.append("bit"))
    image.wait("SA", 0, "IN", lambda v: v != 0, lambda: woke.append("word"))
    image.write([("SA", 1, "BY", 0b100)], "t")
    assert woke == ["word", "bit"]


def test_listeners_hear_before_waits_wake() -> None:
    image = IOImage()
    order: list[str] = []
    image.subscribe(lambda changes, writer: order.append(f"write {writer}"))
    image.wait("SK", 5, "BY", lambda v: v == 1, lambda: order.append("wake"))
    image.write([("SK", 5, "BY", 1)], "plc")
    assert order == ["write plc", "wake"]


def test_a_write_looks_only_at_waits_on_what_it_changed() -> None:
    image = IOImage(k_bytes=512)
    calls: list[int] = []
    for i in range(100):
        image.wait("SK", i, "BY", lambda v: v == 1, lambda i=i: calls.append(i))
    evaluated: list[int] = []
    original = image.read

    def spy(area: str, index: int, view: str) -> int:
        evaluated.append(index)
        return original(area, index, view)

    image.read = spy  # type: ignore[method-assign]
    image.write([("SK", 300, "BY", 1)], "t")  # no wait there
    image.write([("SK", 7, "BY", 2)], "t")  # a wait there, not satisfied
    reads_for_waits = [i for i in evaluated if i == 7]
    assert calls == []
    assert 300 not in [i for i in evaluated if i < 100]
    assert len(reads_for_waits) >= 1 and set(evaluated) <= {7, 300}
    assert image.wait_count == 100


def test_unchanged_value_wakes_nothing_but_is_heard_and_records_the_writer() -> None:
    image = IOImage()
    heard: list[object] = []
    image.subscribe(lambda changes, writer: heard.extend((c.value, c.old) for c in changes))
    image.wait("SK", 1, "BY", lambda v: v != 0, lambda: heard.append("woken"))
    assert image.write([("SK", 1, "BY", 0)], "plc") == []
    assert heard == [(0, 0)] and image.last_writer("SK", 1, "BY") == "plc"
    assert image.generation == 0


def test_a_write_that_fails_part_way_moves_the_generation() -> None:
    # A change "checked" by a caller that was not: the first value is stored before the
    # second fails.  Whoever keeps what it read at a generation (the Modbus server's answers
    # to reads of the image) must see the image moved.
    image = IOImage()
    with pytest.raises(ValueError):
        image.write([("SK", 1, "BY", 5), ("SK", 2, "BY", 300)], "t", checked=True)
    assert image.k[1] == 5 and image.generation == 1


# -- the frozen image (the cell view's image: gateway/view.py) ------------------------------


def test_a_frozen_image_keeps_its_moment_after_writes() -> None:
    image = IOImage(sa_bits=16, k_bytes=4, syvars=4)
    image.write([("SA", 3, "bit", 1), ("SK", 1, "BY", 7), ("SYVAR", 2, "IN", -5)], "plc")
    frozen = image.frozen()  # nothing read of it before the writes below
    image.write([("SA", 3, "bit", 0), ("SK", 1, "BY", 9), ("SYVAR", 2, "IN", 4)], "modbus")
    image.write([("SYVAR", 0, "IN", 1)], "P1 N10")
    assert frozen.sa == bytes([0b1000, 0]) and frozen.k == bytes([0, 7, 0, 0])
    assert frozen.syvar == (0, 0, -5, 0)
    assert frozen.writers() == {"SA": {3: "plc"}, "SK": {1: "plc"}, "SYVAR": {2: "plc"}}
    now = image.frozen()
    assert now.syvar == (1, 0, 4, 0) and now.writers()["SYVAR"] == {0: "P1 N10", 2: "modbus"}
    assert now.writers() == image.writers()
    assert (frozen.version, now.version) == (1, 3) == (1, image.writes)


def test_a_frozen_image_is_one_object_until_the_next_write() -> None:
    image = IOImage()
    frozen = image.frozen()
    assert image.frozen() is frozen
    image.write([("SYVAR", 1, "IN", 0)], "plc")  # no value changes; its writer does
    assert image.frozen() is not frozen and frozen.writers()["SYVAR"] == {}


def test_a_frozen_image_is_copied_only_when_read_or_held_across_a_write(
        monkeypatch: pytest.MonkeyPatch) -> None:
    copies: list[str] = []
    for name in ("_take_areas", "_take_stamps"):
        real = getattr(FrozenImage, name)
        monkeypatch.setattr(FrozenImage, name, lambda self, _real=real, _name=name: (
            copies.append(_name), _real(self))[1])
    image = IOImage()
    for value in range(5):
        image.frozen()  # dropped unread: never copied
        image.write([("SYVAR", 1, "IN", value)], "plc")
    assert copies == []
    held = image.frozen()
    assert held.syvar[1] == 4 and copies == ["_take_areas"]  # read: its values, not writers
    image.write([("SYVAR", 1, "IN", 9)], "plc")
    assert copies == ["_take_areas", "_take_stamps"]  # held across the write: the rest
    assert held.writers()["SYVAR"] == {1: "plc"} and held.syvar[1] == 4
    image.write([("SYVAR", 1, "IN", 10)], "plc")
    assert len(copies) == 2  # taken whole: nothing to copy again


def test_a_holder_that_drops_its_frozen_image_before_a_write_costs_no_copy(
        monkeypatch: pytest.MonkeyPatch) -> None:
    copies: list[int] = []
    real = FrozenImage._take_all
    monkeypatch.setattr(FrozenImage, "_take_all", lambda self: (copies.append(1), real(self)))
    image = IOImage()
    kept: list[FrozenImage] = []
    told: list[int] = []

    def drop() -> None:
        told.append(1)
        kept.clear()

    unsubscribe = image.before_freeze(drop)
    kept.append(image.frozen())
    image.write([("SYVAR", 1, "IN", 1)], "plc")
    assert told == [1] and copies == []
    image.write([("SYVAR", 1, "IN", 2)], "plc")  # no frozen image: nobody told
    assert told == [1]
    unsubscribe()
    kept.append(image.frozen())
    image.write([("SYVAR", 1, "IN", 3)], "plc")
    assert told == [1] and copies == [1] and kept[0].syvar[1] == 2


def test_a_frozen_image_read_on_another_thread_is_of_its_moment() -> None:
    # The loop writes SYVAR1 and SYVAR2 together, always equal to the write's number, and
    # hands a frozen image to another thread now and then, writing on; the thread reads each
    # when it gets to it (mostly some writes later, some while the loop writes) and finds
    # the pair as it was when the image was frozen.
    import queue
    import sys
    import threading

    image = IOImage(syvars=4)
    handed: queue.SimpleQueue[FrozenImage | None] = queue.SimpleQueue()
    values: list[tuple[int, tuple[int, ...]]] = []

    def reader() -> None:
        while (frozen := handed.get()) is not None:
            values.append((frozen.version, frozen.syvar))

    thread = threading.Thread(target=reader)
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # the threads take turns as often as they can
    thread.start()
    try:
        for value in range(1, 20000):
            image.write([("SYVAR", 1, "IN", value), ("SYVAR", 2, "IN", value)], "plc")
            if value % 7 == 0:
                handed.put(image.frozen())
    finally:
        handed.put(None)
        thread.join()
        sys.setswitchinterval(interval)
    assert len(values) == 19999 // 7
    assert all(syvar[1] == syvar[2] == version for version, syvar in values)


def test_a_watch_counts_the_writes_that_changed_what_it_watches() -> None:
    image = IOImage(64, 16, 8)
    bytes_ = image.watch([("SA", 1), ("SYVAR", 2)])
    area = image.watch(areas=["SK"])
    image.write([("SA", 3, "bit", 1), ("SYVAR", 1, "IN", 5)], "x")  # neither
    image.write([("SA", 9, "bit", 1)], "x")  # SA9 is in byte 1
    image.write([("SA", 9, "bit", 1)], "x")  # the same value: no change
    image.write([("SK", 7, "BY", 3)], "x")
    image.write([("SYVAR", 2, "IN", -1)], "x")
    assert (bytes_.generation, area.generation) == (2, 1)
    area.close()
    image.write([("SK", 7, "BY", 4)], "x")
    assert area.generation == 1


def test_a_released_force_over_a_held_variable_shows_the_holds_value_again() -> None:
    """A write of a held variable is kept aside, so after the force's release nothing put
    the fault's value back: SA40 read the released force's 1 under a stuck-at-0."""
    image = IOImage()
    image.hold("SA", 40, "bit", 0, "fault stuck SA40")
    image.force("SA", 40, "bit", 1, "web")
    assert image.read("SA", 40, "bit") == 1  # a force wins over a fault
    image.unforce("SA", 40, "bit")
    assert image.read("SA", 40, "bit") == 0
    assert image.last_writer("SA", 40, "bit") == "fault stuck SA40"
    image.write([("SA", 40, "bit", 1)], "plc")
    assert image.read("SA", 40, "bit") == 0


def test_a_write_of_other_views_of_held_bits_keeps_them_and_names_no_writer_for_them(
        ) -> None:
    image = IOImage()
    heard: list[tuple[list[object], str]] = []
    image.subscribe(lambda changes, writer: heard.append((list(changes), writer)))
    told: list[object] = []
    image.on_overridden = lambda changes, writer: told.append((changes, writer))
    image.hold("SA", 37, "bit", 0, "fault stuck SA37")  # byte 4, bit 5
    image.write([("SA", 4, "BY", 0xFF)], "plc")  # partly held: stored with the bit kept
    assert image.read("SA", 4, "BY") == 0xDF and told == []  # not a force's: no "forced"
    assert image.last_writer("SA", 37, "bit") == "fault stuck SA37"
    assert image.last_writer("SA", 36, "bit") == "plc"
    image.hold("SK", 2, "IN", 300, "fault stuck SK2.IN")
    heard.clear()
    image.write([("SK", 2, "BY", 7), ("SK", 3, "BY", 9)], "modbus")  # all held: nothing
    assert heard == [] and image.read("SK", 2, "IN") == 300
    assert image.last_writer("SK", 3, "BY") == "fault stuck SK2.IN"


def test_a_word_write_keeps_a_held_or_forced_high_byte() -> None:
    """The low byte's masks worked on the whole word: the write's high bits were ORed in
    over a held (or forced) high byte."""
    image = IOImage()
    image.hold("SA", 1, "BY", 0, "fault stuck SA1.BY")
    image.write([("SA", 0, "IN", -1)], "plc")
    assert (image.read("SA", 0, "BY"), image.read("SA", 1, "BY")) == (0xFF, 0)
    image.force("SK", 3, "BY", 0, "op")
    image.write([("SK", 2, "IN", 0x7F00)], "modbus")
    assert image.read("SK", 3, "BY") == 0


def test_overlapping_holds_and_forces_show_what_is_left_of_them() -> None:
    image = IOImage()
    image.hold("SA", 3, "BY", 0, "A")  # SA24..SA31
    image.hold("SA", 30, "bit", 1, "B")
    assert image.read("SA", 30, "bit") == 1 and image.last_writer("SA", 3, "BY") == "B"
    image.unhold("SA", 30, "bit", give_back="clear")
    assert image.read("SA", 30, "bit") == 0  # A's again: it still holds the byte
    assert image.last_writer("SA", 30, "bit") == "A"
    image.force("SA", 28, "bit", 1, "op")
    image.force("SA", 31, "bit", 1, "op")
    image.unforce("SA", 28, "bit")  # SA31 still forced: SA28 shows the hold's 0 again
    assert (image.read("SA", 28, "bit"), image.read("SA", 31, "bit")) == (0, 1)


def test_the_images_own_writes_are_no_forced_events_and_a_clear_names_the_writer() -> None:
    image = IOImage()
    told: list[object] = []
    image.on_overridden = lambda changes, writer: told.append((changes, writer))
    image.force("SA", 30, "bit", 1, "op")
    image.hold("SA", 3, "BY", 0, "fault stuck SA3.BY")  # placed under the force
    image.unhold("SA", 3, "BY", give_back="clear")
    assert told == []
    image.write([("SA", 40, "bit", 0)], "plc")
    image.hold("SA", 40, "bit", 0, "fault stuck SA40")  # the same value
    image.unhold("SA", 40, "bit", give_back="clear")
    assert image.last_writer("SA", 40, "bit") == "plc"  # not the fault that is gone


def test_a_write_a_force_refused_is_not_given_back_at_a_later_clear() -> None:
    image = IOImage()
    image.force("SK", 0, "BY", 255, "op")
    image.hold("SA", 3, "bit", 0, "fault other")  # (the copy kept beside it from here)
    image.write([("SK", 0, "BY", 2)], "modbus")  # refused by the force
    image.unforce("SK", 0, "BY")
    image.hold("SK", 0, "BY", 7, "fault SK0")
    image.unhold("SK", 0, "BY", give_back="clear")
    assert image.read("SK", 0, "BY") == 255  # as the force left it, not the refused 2
