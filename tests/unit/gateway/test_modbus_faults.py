"""The fault table's rows, without a server: what a row accepts and which requests it
matches (its unit, and its address range against the request's, in any table)."""

from __future__ import annotations

from typing import Any

import pytest

from ncgate.gateway.modbus.faults import FaultError, FaultTable, ModbusFault

H = bytes.fromhex


@pytest.mark.parametrize("bad", [
    {"code": 0}, {"code": 256}, {"code": -1}, {"code": True}, {"code": 6.0},
    {"ms": -1}, {"ms": float("nan")}, {"ms": float("inf")}, {"ms": "5"},
    {"unit": 256}, {"unit": -1}, {"unit": False},
    {"addresses": (5, 4)}, {"addresses": (-1, 4)}, {"addresses": (0, 65536)},
    {"addresses": (1,)}, {"addresses": (1, 2, 3)}, {"addresses": 7}, {"addresses": (1.0, 2)},
])
def test_a_bad_row_is_refused(bad: dict[str, Any]) -> None:
    with pytest.raises(FaultError) as caught:
        ModbusFault("exception", **bad)
    assert isinstance(caught.value, ValueError)


def test_the_kinds_and_the_limits() -> None:
    with pytest.raises(ValueError, match="fault kind"):
        ModbusFault("stall")  # type: ignore[arg-type]
    assert ModbusFault("exception").code == 6  # Server Device Busy
    assert ModbusFault("exception", code=255, unit=0, addresses=(0, 0xFFFF)).code == 255
    assert ModbusFault("delay", ms=0).ms == 0
    assert ModbusFault("no_reply", unit=255).unit == 255
    row = ModbusFault("exception", addresses=[0, 99])  # type: ignore[arg-type]  # from TOML
    assert row.addresses == (0, 99) and hash(row) == hash(ModbusFault("exception",
                                                                      addresses=(0, 99)))


@pytest.mark.parametrize(("request_pdu", "matched"), [
    (H("03 0000 0005"), False),  # 0..4
    (H("03 0000 0006"), True),  # 0..5
    (H("01 000A 0001"), True),  # coil 10: the range is of any table
    (H("04 000B 0001"), False),
    (H("05 0007 FF00"), True),  # a single coil
    (H("06 000B 0005"), False),  # a single register: its value is no count
    (H("10 0000 0006 0C" + "0000" * 6), True),
    (H("16 0008 00F2 0025"), True),  # mask write: one register
    (H("17 0000 0001 000A 0001 02 0000"), True),  # its write range meets
    (H("17 0008 0001 0014 0001 02 0000"), True),  # its read range meets
    (H("17 0000 0001 0014 0001 02 0000"), False),
    (H("2B 0E 01 00"), False),  # no address: only a row without a range
])
def test_a_row_with_a_range_matches_requests_that_meet_it(request_pdu: bytes,
                                                           matched: bool) -> None:
    assert ModbusFault("exception", addresses=(5, 10)).matches(1, request_pdu) is matched
    assert ModbusFault("exception").matches(1, request_pdu)  # no range: every request


def test_the_strongest_matching_row_decides_whatever_the_order() -> None:
    table = FaultTable()
    slow, slower = ModbusFault("delay", ms=5), ModbusFault("delay", ms=50)
    busy, silent = ModbusFault("exception", code=4), ModbusFault("no_reply", unit=3)
    for rows in ([slow, slower, busy, silent], [silent, busy, slower, slow]):
        table.set(rows)
        assert table.match(3, H("03 0000 0001")) is silent
        assert table.match(1, H("03 0000 0001")) is busy
    table.set([slow, slower])
    assert table.match(1, H("03 0000 0001")) is slower  # the longest delay
    table.set([slow, ModbusFault("delay", ms=5, unit=1)])
    assert table.match(1, H("03 0000 0001")) is slow  # of equals, the first


def test_a_row_of_one_unit_and_the_table_order() -> None:
    table = FaultTable()
    busy, slow = ModbusFault("exception", unit=7), ModbusFault("delay", ms=5)
    table.set([busy, slow])
    assert table.match(7, H("03 0000 0001")) is busy
    assert table.match(1, H("03 0000 0001")) is slow
    table.set([busy])
    assert table.match(1, H("03 0000 0001")) is None
    assert table.counts == {"exception": 1, "delay": 1, "no_reply": 0, "silenced": 0}
    with pytest.raises(FaultError):
        table.set([busy, ("delay", 5)])  # type: ignore[list-item]
    assert table.rows == (busy,)
