"""The I/O image (spec 3.1, 1.3): views, atomic writes, writers, waits woken by index."""

from __future__ import annotations

import pytest

from ncgate.plc.image import ImageAddressError, ImageValueError, IOImage


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
