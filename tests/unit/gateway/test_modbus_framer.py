"""The sans-IO Modbus framers, without a socket: bytes in, requests out; answers in, bytes out.

Every frame here is written out by hand.  The PDUs are the examples of the Modbus Application
Protocol Specification V1.1b3 (section 6, one per function code, and section 7 for an
exception); the RTU CRCs are those of the examples of Modbus over Serial Line V1.02 and of
the Simply Modbus pages, which quote them byte by byte.
"""

from __future__ import annotations

import pytest

from ncgate.gateway.modbus.framer import (
    Framer,
    FramingError,
    MbapFramer,
    Request,
    RtuFramer,
    address_ranges,
    crc16,
    drain,
    exception_pdu,
    request_pdu_length,
)

H = bytes.fromhex

# (function code, request PDU, answer PDU, the addresses the request names) from the spec.
SPEC = [
    pytest.param(H("01 0013 0013"), H("01 03 CD 6B 05"), ((19, 37),), id="6.1 FC01"),
    pytest.param(H("02 00C4 0016"), H("02 03 AC DB 35"), ((196, 217),), id="6.2 FC02"),
    pytest.param(H("03 006B 0003"), H("03 06 022B 0000 0064"), ((107, 109),), id="6.3 FC03"),
    pytest.param(H("04 0008 0001"), H("04 02 000A"), ((8, 8),), id="6.4 FC04"),
    pytest.param(H("05 00AC FF00"), H("05 00AC FF00"), ((172, 172),), id="6.5 FC05"),
    pytest.param(H("06 0001 0003"), H("06 0001 0003"), ((1, 1),), id="6.6 FC06"),
    pytest.param(H("0F 0013 000A 02 CD01"), H("0F 0013 000A"), ((19, 28),), id="6.11 FC15"),
    pytest.param(H("10 0001 0002 04 000A 0102"), H("10 0001 0002"), ((1, 2),),
                 id="6.12 FC16"),
    pytest.param(H("16 0004 00F2 0025"), H("16 0004 00F2 0025"), ((4, 4),), id="6.16 FC22"),
    pytest.param(H("17 0003 0006 000E 0003 06 00FF 00FF 00FF"),
                 H("17 0C 00FE 0ACD 0001 0003 000D 00FF"), ((3, 8), (14, 16)), id="6.17 FC23"),
    pytest.param(H("2B 0E 01 00"),
                 H("2B 0E 01 01 00 00 03") + b"\x00\x16Company identification"
                 + b"\x01\x0fProduct code XX" + b"\x02\x05V2.11", (), id="6.21 FC43/14"),
]


def mbap(tid: int, unit: int, pdu: bytes) -> bytes:
    """The header written out field by field (implementation guide 3.1.3)."""
    length = len(pdu) + 1
    return bytes((tid >> 8, tid & 0xFF, 0, 0, length >> 8, length & 0xFF, unit)) + pdu


# -- MBAP: the stream ------------------------------------------------------------------------

def test_a_header_example_is_cut_field_by_field() -> None:
    framer = MbapFramer()
    framer.feed(H("1501 0000 0006 11 03006B0003"))  # tid 0x1501, unit 0x11: FC3 of 6.3
    assert framer.next_request() == (0x11, H("03006B0003"), 0x1501)
    assert framer.next_request() is None and framer.buffered == 0


def test_a_request_fed_a_byte_at_a_time_comes_out_once_whole() -> None:
    framer = MbapFramer()
    frame = mbap(7, 1, H("03 006B 0003"))
    for i, byte in enumerate(frame[:-1]):
        framer.feed(bytes((byte,)))
        assert framer.next_request() is None
        assert framer.buffered == i + 1
    framer.feed(frame[-1:])
    assert framer.next_request() == (1, H("03 006B 0003"), 7)
    assert framer.next_request() is None and framer.buffered == 0


def test_several_requests_in_one_feed_come_out_in_order() -> None:
    framer = MbapFramer()
    pdus = [H("03 0000 0001"), H("06 0001 0003"), H("2B 0E 01 00")]
    framer.feed(b"".join(mbap(tid, 7, p) for tid, p in zip((0xFFFE, 0xFFFF, 0), pdus,
                                                             strict=True)))
    assert drain(framer) == [(7, pdus[0], 0xFFFE), (7, pdus[1], 0xFFFF), (7, pdus[2], 0)]


def test_requests_straddling_feeds_are_cut_where_their_lengths_say() -> None:
    framer = MbapFramer()
    stream = b"".join(mbap(tid, 1, H("10 0001 0002 04 000A 0102")) for tid in range(1, 6))
    got: list[Request] = []
    for at in range(0, len(stream), 5):  # 5-byte segments: every frame is split somewhere
        framer.feed(stream[at:at + 5])
        got += drain(framer)
    assert got == [(1, H("10 0001 0002 04 000A 0102"), tid) for tid in range(1, 6)]


@pytest.mark.parametrize("header", [
    pytest.param(H("0001 0001 0006 01"), id="protocol id 1"),
    pytest.param(H("0001 FFFF 0006 01"), id="protocol id 0xFFFF"),
    pytest.param(H("0001 0000 0000 01"), id="length 0"),
    pytest.param(H("0001 0000 0001 01"), id="length 1: no function code"),
    pytest.param(H("0001 0000 00FF 01"), id="length 255: a PDU over 253 bytes"),
    pytest.param(H("0001 0000 FFFF 01"), id="length 65535"),
])
def test_a_bad_header_is_a_framing_error_as_soon_as_it_is_whole(header: bytes) -> None:
    framer = MbapFramer()
    framer.feed(mbap(1, 1, H("03 0000 0001")) + header[:6])
    assert framer.next_request() == (1, H("03 0000 0001"), 1)  # the good one first
    assert framer.next_request() is None  # six bytes: not a header yet
    framer.feed(header[6:])  # the header is whole, its PDU has not come: already refused
    with pytest.raises(FramingError, match="bad MBAP header") as caught:
        framer.next_request()
    assert isinstance(caught.value, ValueError)


@pytest.mark.parametrize("pdu_length", [1, 253])
def test_the_lengths_at_the_limits_are_frames(pdu_length: int) -> None:
    framer = MbapFramer()
    pdu = bytes((3,)) + bytes(pdu_length - 1)
    framer.feed(mbap(9, 1, pdu))
    assert framer.next_request() == (1, pdu, 9)


def test_whole_takes_exactly_one_request_when_nothing_is_buffered() -> None:
    framer = MbapFramer()
    frame = mbap(3, 1, H("04 0008 0001"))
    assert framer.whole(frame) == (1, H("04 0008 0001"), 3)
    assert framer.buffered == 0  # nothing kept
    assert framer.whole(frame + frame) is None  # two: feed them
    assert framer.whole(frame[:-1]) is None  # a part
    assert framer.whole(H("0003 0001 0006 01 04 0008 0001")) is None  # protocol id 1
    framer.feed(frame[:3])
    assert framer.whole(frame) is None  # it would come before what is buffered
    assert framer.buffered == 3


# -- each function code: the request as framed, its addresses, the answer's bytes -------------

@pytest.mark.parametrize(("request_pdu", "answer", "ranges"), SPEC)
def test_each_function_code_of_the_spec(request_pdu: bytes, answer: bytes,
                                        ranges: tuple[tuple[int, int], ...]) -> None:
    framer = MbapFramer()
    framer.feed(mbap(0x0102, 0xFF, request_pdu))
    request = framer.next_request()
    assert request == (0xFF, request_pdu, 0x0102)
    assert request_pdu_length(request_pdu) == len(request_pdu)
    assert address_ranges(request_pdu) == ranges
    length = len(answer) + 1
    assert framer.encode(request, answer) == (H("0102 0000") + bytes((0, length, 0xFF))
                                              + answer)


def test_an_exception_answer() -> None:
    """Section 7's example: a read of coils at 0x04A1 the server does not have: 02."""
    framer = MbapFramer()
    framer.feed(H("0021 0000 0006 01 01 04A1 0001"))
    request = framer.next_request()
    assert request is not None
    assert exception_pdu(request[1][0], 2) == H("81 02")
    assert framer.encode(request, exception_pdu(request[1][0], 2)) == H("0021 0000 0003 01 8102")
    assert exception_pdu(0x2B, 6) == H("AB 06")  # busy, to FC43
    assert exception_pdu(0x83, 4) == H("83 04")  # an exception code's bit is set once


def test_pdu_lengths_that_wait_for_their_byte_count() -> None:
    assert request_pdu_length(H("10 0001 0002")) is None  # FC16's byte count not here yet
    assert request_pdu_length(H("10 0001 0002 04")) == 10
    assert request_pdu_length(H("2B")) is None  # the MEI type decides
    assert request_pdu_length(H("2B 0D")) == -1  # CANopen general reference: not known
    assert request_pdu_length(H("64 0000")) == -1  # function code 100: not known
    assert request_pdu_length(b"") is None
    assert address_ranges(H("03 0001")) == ()  # too short to name an address


# -- RTU: the frame format alone --------------------------------------------------------------

def test_rtu_crc_of_the_spec_examples() -> None:
    assert crc16(H("11 03 006B 0003")).to_bytes(2, "little") == H("76 87")
    assert crc16(H("01 03 0000 000A")).to_bytes(2, "little") == H("C5 CD")


def test_rtu_a_request_fed_a_byte_at_a_time_and_two_in_one_feed() -> None:
    framer: Framer = RtuFramer()
    frame = H("11 03 006B 0003 7687")
    for byte in frame[:-1]:
        framer.feed(bytes((byte,)))
        assert framer.next_request() is None
    framer.feed(frame[-1:])
    assert framer.next_request() == (0x11, H("03 006B 0003"), 0)
    framer.feed(frame + H("01 03 0000 000A C5CD"))
    assert drain(framer) == [(0x11, H("03 006B 0003"), 0), (1, H("03 0000 000A"), 0)]
    assert framer.buffered == 0


def test_rtu_a_bad_crc_is_dropped_with_what_follows_until_the_gap() -> None:
    framer = RtuFramer()
    framer.feed(H("11 03 006B 0003 7688") + H("01 03 0000 000A C5CD"))
    assert framer.next_request() is None and (framer.crc_errors, framer.partial) == (1, 0)
    framer.feed(H("01 03 0000 000A C5CD"))  # still the same burst: dropped
    assert framer.next_request() is None and framer.buffered == 0
    assert framer.gap() is None  # the silence: the next frame begins
    framer.feed(H("01 03 0000 000A C5CD"))
    assert framer.next_request() == (1, H("03 0000 000A"), 0)


def test_rtu_a_frame_whose_code_gives_no_length_ends_at_the_gap() -> None:
    framer = RtuFramer()
    frame = H("01 64 0102")  # function code 100, two data bytes
    crc = crc16(frame)
    framer.feed(frame + bytes((crc & 0xFF, crc >> 8)))
    assert framer.next_request() is None  # its end is the line's silence
    assert framer.gap() == (1, H("64 0102"), 0)
    framer.feed(H("01 03 00"))  # begun, then cut off
    assert framer.gap() is None and framer.buffered == 0
    assert (framer.crc_errors, framer.partial, framer.discarded) == (0, 1, 1)


def test_rtu_noise_longer_than_any_frame_is_dropped_until_the_gap() -> None:
    framer = RtuFramer()
    framer.feed(bytes((1, 100)) + bytes(300))  # a code with no known length, 302 bytes long
    assert framer.buffered == 0 and framer.partial == 1
    framer.feed(H("01 03 0000 000A C5CD"))  # the same burst: dropped
    assert framer.next_request() is None and framer.gap() is None
    framer.feed(H("01 03 0000 000A C5CD"))
    assert framer.next_request() == (1, H("03 0000 000A"), 0)
    assert (framer.crc_errors, framer.partial) == (0, 1)


def test_rtu_a_frame_ended_by_the_gap_with_a_bad_crc_does_not_mute_the_next() -> None:
    framer = RtuFramer()
    framer.feed(H("01 64 0102 0000"))  # function code 100: its end is the gap; a bad CRC
    assert framer.gap() is None and (framer.crc_errors, framer.partial) == (1, 0)
    assert framer.idle
    framer.feed(H("01 03 0000 000A C5CD"))
    assert framer.next_request() == (1, H("03 0000 000A"), 0)


def test_rtu_encode_and_whole() -> None:
    framer = RtuFramer()
    request = framer.whole(H("11 03 006B 0003 7687"))
    assert request == (0x11, H("03 006B 0003"), 0)
    answer = framer.encode(request, H("03 06 022B 0000 0064"))
    assert answer[:-2] == H("11 03 06 022B 0000 0064")
    assert crc16(answer[:-2]).to_bytes(2, "little") == answer[-2:]
    assert framer.whole(H("11 03 006B 0003 7688")) is None  # bad CRC: fed, it is dropped
    assert framer.whole(H("11 03 006B 0003")) is None  # a part
    assert framer.encode((1, b"", 0), exception_pdu(3, 2)) == H("01 83 02 C0F1")
