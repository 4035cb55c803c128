"""Forcing in the image: every view of a forced variable keeps the forced value."""

from __future__ import annotations

from ncgate.plc.image import IOImage


def test_forces_hold_through_every_view_and_report_what_they_overrode() -> None:
    image = IOImage()
    told: list[tuple[str, int, str, int]] = []
    image.on_overridden = lambda changes, writer: told.extend(changes)
    image.force("SA", 9, "bit", 1, "test")  # byte 1, bit 1
    image.force("SYVAR", 3, "IN", -7, "test")
    image.force("SK", 4, "BY", 0x55, "test")
    image.write([("SA", 1, "BY", 0x00), ("SYVAR", 3, "IN", 12), ("SK", 4, "IN", 0x1234)], "w")
    assert image.read("SA", 1, "BY") == 0x02  # the forced bit stays set, the others clear
    assert image.read("SYVAR", 3, "IN") == -7
    assert image.read("SK", 4, "BY") == 0x55 and image.read("SK", 5, "BY") == 0x12
    assert told == [("SA", 1, "BY", 0x00), ("SYVAR", 3, "IN", 12), ("SK", 4, "IN", 0x1234)]
    told.clear()
    image.write([("SA", 9, "bit", 1)], "w")  # what it is forced to: nothing overridden
    assert told == []
    image.unforce("SA", 9, "bit")
    image.write([("SA", 9, "bit", 0)], "w")
    assert image.read("SA", 9, "bit") == 0
    image.unforce()  # every one
    image.write([("SYVAR", 3, "IN", 12)], "w")
    assert image.read("SYVAR", 3, "IN") == 12 and image.forced == {}
