"""Modbus RTU on a serial line, byte by byte (Modbus over Serial Line V1.02): the test is the
master on a pty's master side and writes raw frames, the gateway serves the other side.
Every expected answer is written out from the application protocol's PDU layouts; the CRC is
the one whose spec examples tests/unit/gateway/test_modbus_framer.py checks."""

from __future__ import annotations

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.web.status import fieldbus

from .conftest import RawLine, frame


def serial_counts(gw: Gateway) -> dict[str, int]:
    status = fieldbus(gw)["modbus_rtu"]
    (port,) = status["ports"]
    return {k: port[k] for k in ("frames", "answered", "crc_errors", "partial", "exceptions",
                                  "broadcasts", "other_units")}


async def test_a_read_is_answered_with_the_map_and_its_crc(raw_gateway: Gateway,
                                                           raw_line: RawLine) -> None:
    raw_line.send(frame("01 04 0000 0002"))  # input registers 0..1: map version, processes
    assert await raw_line.answer(9) == frame("01 04 04 0001 0004")
    raw_line.send(frame("07 04 0001 0001"))  # the cell's second unit id
    assert await raw_line.answer(7) == frame("07 04 02 0004")
    assert serial_counts(raw_gateway)["answered"] == 2


async def test_a_request_split_over_writes_is_one_frame(raw_gateway: Gateway,
                                                        raw_line: RawLine) -> None:
    whole = frame("01 04 0001 0001")
    for byte in whole:  # no silence between the bytes: one frame
        raw_line.send(bytes((byte,)))
    assert await raw_line.answer(7) == frame("01 04 02 0004")


async def test_a_bad_crc_is_not_answered_and_is_counted(raw_gateway: Gateway,
                                                        raw_line: RawLine) -> None:
    bad = bytearray(frame("01 04 0000 0002"))
    bad[-1] ^= 0xFF
    raw_line.send(bytes(bad))
    await raw_line.silence()
    raw_line.send(frame("01 04 0001 0001"))
    assert await raw_line.answer(7) == frame("01 04 02 0004")  # nothing came before it
    counts = serial_counts(raw_gateway)
    assert (counts["crc_errors"], counts["frames"], counts["answered"]) == (1, 1, 1)


async def test_a_frame_cut_by_a_silence_is_dropped_and_counted(raw_gateway: Gateway,
                                                               raw_line: RawLine) -> None:
    whole = frame("01 03 0000 000A")
    raw_line.send(whole[:4])
    await raw_line.silence()  # the 3.5 characters pass: what was begun is dropped
    raw_line.send(frame("01 04 0001 0001"))
    assert await raw_line.answer(7) == frame("01 04 02 0004")
    assert serial_counts(raw_gateway)["partial"] == 1
    # Its tail after another silence is a frame of its own, whose CRC is wrong: dropped too.
    raw_line.send(whole[4:])
    await raw_line.silence()
    raw_line.send(frame("01 04 0001 0001"))
    assert await raw_line.answer(7) == frame("01 04 02 0004")
    counts = serial_counts(raw_gateway)
    assert (counts["partial"], counts["crc_errors"], counts["answered"]) == (1, 1, 2)


async def test_a_silence_timer_a_little_early_is_the_silence(raw_gateway: Gateway,
                                                             raw_line: RawLine) -> None:
    """uvloop's timers come up to half a millisecond early: the silence timer that found
    the 3.5 characters not quite passed was armed again for the rest, which uvloop rounds
    to a whole millisecond, so the frame's end came later than its silence.  Driven here by
    the link's own clock, not by sleeping: the bytes came 0.3 ms less than the silence ago
    when the timer runs."""
    import time

    link = raw_gateway.adapters["modbus_rtu"].serial.link
    link.received(frame("01 03 0000 000A")[:4])  # a frame begun
    link.last_byte = time.monotonic() - link.silence + 0.0003
    if link.gap_timer is not None:
        link.gap_timer.cancel()
    link._silence()
    assert serial_counts(raw_gateway)["partial"] == 1  # dropped at the silence
    assert link.gap_timer is None  # (not armed again)


@pytest.mark.parametrize("unit", [9, 0xF8, 0xFF])
async def test_another_units_request_is_not_answered(raw_gateway: Gateway, raw_line: RawLine,
                                                     unit: int) -> None:
    """9 is not the cell's; 248..255 are reserved on a serial line (0xFF is "the server
    itself" only on TCP)."""
    raw_line.send(frame(f"{unit:02X} 04 0000 0001"))
    await raw_line.silence()
    raw_line.send(frame("01 04 0001 0001"))
    assert await raw_line.answer(7) == frame("01 04 02 0004")
    counts = serial_counts(raw_gateway)
    assert (counts["other_units"], counts["answered"]) == (1, 1)


async def test_a_broadcast_write_is_applied_and_not_answered(raw_gateway: Gateway,
                                                             raw_line: RawLine) -> None:
    gw = raw_gateway
    raw_line.send(frame("00 05 000A FF00"))  # SA10 = 1, to every slave
    raw_line.send(frame("00 03 0000 0001"))  # a broadcast read: nothing at all
    await raw_line.silence()
    raw_line.send(frame("01 01 000A 0001"))  # read coil 10 back as unit 1
    assert await raw_line.answer(6) == frame("01 01 01 01")  # the first bytes sent at all
    counts = serial_counts(gw)
    assert (counts["broadcasts"], counts["answered"]) == (1, 1)
    writes = [e for e in gw.trace if e["event"] == "write"]
    assert writes and writes[-1]["who"] == f"modbus-rtu {raw_line.device}"


async def test_exceptions_are_those_of_modbus_tcp(raw_gateway: Gateway,
                                                  raw_line: RawLine) -> None:
    raw_line.send(frame("01 03 0258 0001"))  # holding 600: not mapped
    assert await raw_line.answer(5) == frame("01 83 02")
    raw_line.send(frame("01 06 0007 012C"))  # SK7 = 300: not a byte
    assert await raw_line.answer(5) == frame("01 86 03")
    raw_line.send(frame("01 2B 0D 01 00"))  # MEI 0x0D (CANopen reference): not served
    assert await raw_line.answer(5) == frame("01 AB 01")
    assert raw_gateway.image.k[7] == 0
    assert serial_counts(raw_gateway)["exceptions"] == 3


async def test_the_plants_modbus_faults_apply_to_the_serial_line(raw_gateway: Gateway,
                                                                 raw_line: RawLine) -> None:
    gw = raw_gateway
    gw.fault("modbus", "exception", code=6, addresses=[0, 99])
    raw_line.send(frame("01 06 0005 00C8"))  # SK5 = 200: busy, and not stored
    assert await raw_line.answer(5) == frame("01 86 06")
    assert gw.image.k[5] == 0
    gw.clear_fault("modbus")
    gw.fault("modbus", "no_reply")
    raw_line.send(frame("01 04 0001 0001"))
    await raw_line.silence(0.1)
    assert raw_line.received == b""  # silent while the fault is in force
    gw.fault("canopen", "pdo_stop")  # another fieldbus's fault: the line stays silent
    raw_line.send(frame("01 04 0001 0001"))
    await raw_line.silence(0.1)
    assert raw_line.received == b""
    gw.clear_fault("modbus")
    raw_line.send(frame("01 04 0001 0001"))
    assert await raw_line.answer(7) == frame("01 04 02 0004")
    status = fieldbus(gw)["modbus_rtu"]
    # As Modbus TCP counts them: the request that met the fault, and those dropped after it
    # (the first was counted as both).
    counts = status["fault_counts"]
    assert (counts["exception"], counts["no_reply"], counts["silenced"]) == (1, 1, 1)
    assert status["silenced"] == 1


async def test_a_clear_answers_a_request_a_delay_holds_at_once(raw_gateway: Gateway,
                                                               raw_line: RawLine) -> None:
    gw = raw_gateway
    gw.fault("modbus", "delay", ms=3_600_000, addresses=[0, 0])
    raw_line.send(frame("01 04 0000 0001"))
    await raw_line.silence(0.1)
    assert raw_line.received == b""
    gw.clear_fault("modbus")
    assert await raw_line.answer(7) == frame("01 04 02 0001")


async def test_a_delay_fault_answers_late_and_in_order(raw_gateway: Gateway,
                                                       raw_line: RawLine) -> None:
    gw = raw_gateway
    gw.fault("modbus", "delay", ms=50, addresses=[0, 0])
    raw_line.send(frame("01 04 0000 0001"))  # delayed: input 0 is in the fault's range
    raw_line.send(frame("01 04 0001 0001"))  # not in it, but behind it on the line
    assert await raw_line.answer(14) == frame("01 04 02 0001") + frame("01 04 02 0004")
    assert fieldbus(gw)["modbus_rtu"]["fault_counts"]["delay"] == 1
