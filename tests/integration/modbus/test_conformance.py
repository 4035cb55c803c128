"""The conformance matrix of spec 3.2 on raw sockets: every bad request gets its exception
code (or, for a bad MBAP header, a closed connection), nothing of it is stored, and the server
answers the next good request."""

from __future__ import annotations

import struct
from collections.abc import AsyncIterator

import pytest
import pytest_asyncio
from pymodbus.client import AsyncModbusTcpClient

from ncgate import __version__
from ncgate.gateway import Gateway
from ncgate.gateway.canopen.dictionary import build_dictionary
from ncgate.gateway.modbus.map import ModbusMap, Table

from .rawclient import Raw, mbap, pdu

GOOD = pdu(4, "HH", 0, 2)  # read input registers 0..1: map version, process count


@pytest_asyncio.fixture
async def raw(ncgate_gateway: Gateway) -> AsyncIterator[Raw]:
    client = await Raw.open(*ncgate_gateway.modbus_address)
    yield client
    client.close()


async def still_serves(gw: Gateway, raw: Raw, before: object) -> None:
    assert await raw.ask(GOOD) == b"\x04\x04\x00\x01\x00\x04"
    assert gw.image.snapshot() == before


def exc(fc: int, code: int) -> bytes:
    return bytes((fc | 0x80, code))


READ_LIMITS = {1: 2000, 2: 2000, 3: 125, 4: 125}


@pytest.mark.parametrize("fc", sorted(READ_LIMITS))
@pytest.mark.parametrize("quantity", ["zero", "max+1"])
async def test_read_quantity_zero_and_above_limit(ncgate_gateway: Gateway, raw: Raw, fc: int,
                                                  quantity: str) -> None:
    before = ncgate_gateway.image.snapshot()
    count = 0 if quantity == "zero" else READ_LIMITS[fc] + 1
    assert await raw.ask(pdu(fc, "HH", 0, count)) == exc(fc, 3)
    await still_serves(ncgate_gateway, raw, before)


@pytest.mark.parametrize(("fc", "limit"), [(15, 1968), (16, 123)])
@pytest.mark.parametrize("quantity", ["zero", "max+1"])
async def test_write_quantity_zero_and_above_limit(ncgate_gateway: Gateway, raw: Raw, fc: int,
                                                   limit: int, quantity: str) -> None:
    before = ncgate_gateway.image.snapshot()
    count = 0 if quantity == "zero" else limit + 1
    # A full FC16 of 124 registers would not fit an MBAP frame (length <= 254): like
    # libmodbus's tests, send the quantity with a short body; quantity is checked first.
    request = pdu(fc, "HHB", 0, count, 2) + b"\x00\x01"
    assert await raw.ask(request) == exc(fc, 3)
    await still_serves(ncgate_gateway, raw, before)


@pytest.mark.parametrize(("read_count", "write_count"), [(0, 1), (126, 1), (1, 0), (1, 122)])
async def test_read_write_quantities(ncgate_gateway: Gateway, raw: Raw, read_count: int,
                                     write_count: int) -> None:
    before = ncgate_gateway.image.snapshot()
    request = pdu(23, "HHHHB", 0, read_count, 0, write_count, 2) + b"\x00\x01"
    assert await raw.ask(request) == exc(23, 3)
    await still_serves(ncgate_gateway, raw, before)


@pytest.mark.parametrize("request_pdu", [
    pdu(15, "HHB", 0, 9, 1) + b"\xff",  # 9 coils need 2 bytes
    pdu(15, "HHB", 0, 8, 1) + b"\xff\xff",  # count right, data too long
    pdu(16, "HHB", 0, 2, 3) + b"\x00\x01\x00\x02",  # 2 registers need 4 bytes
    pdu(16, "HHB", 0, 2, 4) + b"\x00\x01",  # data too short
    pdu(23, "HHHHB", 0, 1, 0, 2, 2) + b"\x00\x01\x00\x02",
    pdu(3, "HHB", 0, 1, 0),  # a fixed-length request one byte too long
    pdu(6, "H", 0),  # one too short
])
async def test_byte_count_and_length_mismatch(ncgate_gateway: Gateway, raw: Raw,
                                             request_pdu: bytes) -> None:
    before = ncgate_gateway.image.snapshot()
    assert await raw.ask(request_pdu) == exc(request_pdu[0], 3)
    await still_serves(ncgate_gateway, raw, before)


def edges(mmap: ModbusMap) -> list[tuple[Table, int, int]]:
    """For each region: a range reaching one below its start and one past its end."""
    out = []
    for r in mmap.regions:
        if r.start > 0 and not any(o.table is r.table and o.start <= r.start - 1 < o.end
                                   for o in mmap.regions):
            out.append((r.table, r.start - 1, 2))
        if not any(o.table is r.table and o.start <= r.end < o.end for o in mmap.regions):
            out.append((r.table, r.end - 1, 2))
    return out


READ_FC = {Table.COILS: 1, Table.DISCRETE_INPUTS: 2, Table.HOLDING: 3, Table.INPUT: 4}


async def test_unmapped_just_below_and_above_every_region(ncgate_gateway: Gateway,
                                                         raw: Raw) -> None:
    before = ncgate_gateway.image.snapshot()
    cases = edges(ncgate_gateway.map)
    assert len(cases) >= 12  # every region has a border that faces unmapped space
    for table, address, count in cases:
        fc = READ_FC[table]
        assert await raw.ask(pdu(fc, "HH", address, count)) == exc(fc, 2), (table, address)
        if table is Table.COILS:
            request = pdu(15, "HHB", address, count, 1) + b"\x03"
            assert await raw.ask(request) == exc(15, 2)
        if table is Table.HOLDING:
            request = pdu(16, "HHB", address, count, 4) + b"\x00\x01\x00\x01"
            assert await raw.ask(request) == exc(16, 2), address
    await still_serves(ncgate_gateway, raw, before)


async def test_the_whole_of_each_region_is_served(ncgate_gateway: Gateway, raw: Raw) -> None:
    for r in ncgate_gateway.map.regions:
        fc = READ_FC[r.table]
        limit = READ_LIMITS[fc]
        for start in range(r.start, r.end, limit):
            count = min(limit, r.end - start)
            answer = await raw.ask(pdu(fc, "HH", start, count))
            assert answer[0] == fc, (r, start, answer)


async def test_fc5_only_takes_0000_and_ff00(ncgate_gateway: Gateway, raw: Raw) -> None:
    before = ncgate_gateway.image.snapshot()
    for value in (0x0001, 0x00FF, 0xFF01, 0x1234, 0xFFFF):
        assert await raw.ask(pdu(5, "HH", 3, value)) == exc(5, 3)
    await still_serves(ncgate_gateway, raw, before)
    assert await raw.ask(pdu(5, "HH", 3, 0xFF00)) == pdu(5, "HH", 3, 0xFF00)
    assert ncgate_gateway.image.read("SA", 3, "bit") == 1


async def test_values_out_of_range_store_nothing(ncgate_gateway: Gateway, raw: Raw) -> None:
    before = ncgate_gateway.image.snapshot()
    assert await raw.ask(pdu(6, "HH", 7, 256)) == exc(6, 3)  # K byte
    assert await raw.ask(pdu(16, "HHBHHH", 10, 3, 6, 1, 2, 999)) == exc(16, 3)  # last bad
    assert await raw.ask(pdu(6, "HH", 1500, 300)) == exc(6, 3)  # SA byte
    assert await raw.ask(pdu(22, "HHH", 7, 0x0000, 0x0100)) == exc(22, 3)  # mask -> 256
    assert await raw.ask(pdu(6, "HH", 2000, 17)) == exc(6, 3)  # no command 17
    assert await raw.ask(pdu(6, "HH", 2000, 0x0900)) == exc(6, 3)  # nor 0 (of process 9)
    await still_serves(ncgate_gateway, raw, before)


@pytest.mark.parametrize("fc", [0, 7, 8, 11, 12, 17, 20, 21, 24, 43, 65, 100, 127])
async def test_unknown_function_codes(ncgate_gateway: Gateway, raw: Raw, fc: int) -> None:
    before = ncgate_gateway.image.snapshot()
    assert await raw.ask(bytes((fc, 0, 0, 0, 1))) == exc(fc, 1)
    await still_serves(ncgate_gateway, raw, before)


async def test_unit_ids_as_the_modbus_tcp_guide_says(ncgate_gateway: Gateway,
                                                     raw: Raw) -> None:
    """0xFF is the server itself and 0 is answered (libmodbus's defaults); others get 0x0B
    and store nothing."""
    before = ncgate_gateway.image.snapshot()
    for unit in (2, 3, 254):  # the fixture serves 1 and 7
        assert await raw.ask(pdu(6, "HH", 7, 9), unit=unit) == exc(6, 0x0B)
    await still_serves(ncgate_gateway, raw, before)
    for unit, value in ((0xFF, 9), (0, 10)):
        assert await raw.ask(pdu(6, "HH", 7, value), unit=unit) == pdu(6, "HH", 7, value)
        assert ncgate_gateway.image.read("SK", 7, "BY") == value


@pytest.mark.parametrize("ncgate_config", [{"modbus.strict_unit_id": True}], indirect=True)
async def test_strict_unit_id_refuses_0_but_not_0xff(ncgate_gateway: Gateway, raw: Raw) -> None:
    assert await raw.ask(pdu(6, "HH", 7, 9), unit=0) == exc(6, 0x0B)
    assert await raw.ask(pdu(6, "HH", 7, 9), unit=0xFF) == pdu(6, "HH", 7, 9)


@pytest.mark.parametrize(("protocol", "length"), [(1, None), (0xFFFF, None), (0, 0), (0, 1),
                                                  (0, 255), (0, 300)])
async def test_bad_mbap_closes_only_that_connection(ncgate_gateway: Gateway, raw: Raw,
                                                    protocol: int, length: int | None) -> None:
    before = ncgate_gateway.image.snapshot()
    other = await Raw.open(*ncgate_gateway.modbus_address)
    try:
        await raw.send(mbap(1, 1, pdu(6, "HH", 7, 9), protocol=protocol, length=length)
                       + bytes(300))
        assert await raw.closed_by_peer()
        await still_serves(ncgate_gateway, other, before)
    finally:
        other.close()


@pytest.mark.parametrize("n", [2, 3, 4, 5])
async def test_several_requests_in_one_segment(ncgate_gateway: Gateway, raw: Raw,
                                               n: int) -> None:
    frames = [mbap(100 + i, 1, pdu(6, "HH", 20 + i, i + 1)) for i in range(n)]
    frames[1] = mbap(101, 1, pdu(3, "HH", 0, 0))  # a bad one among them
    await raw.send(b"".join(frames))
    answers = [await raw.recv() for _ in range(n)]
    assert [tid for tid, _, _ in answers] == [100 + i for i in range(n)]
    assert answers[1][2] == exc(3, 3)
    for i, (_, _, answer) in enumerate(answers):
        if i != 1:
            assert answer == pdu(6, "HH", 20 + i, i + 1)
            assert ncgate_gateway.image.read("SK", 20 + i, "BY") == i + 1


async def test_one_request_dribbled_byte_by_byte(ncgate_gateway: Gateway, raw: Raw) -> None:
    frame = mbap(77, 1, pdu(16, "HHBHH", 1000, 2, 4, 0xFFFF, 5))
    for byte in frame:
        await raw.send(bytes((byte,)))
    tid, _, answer = await raw.recv()
    assert (tid, answer) == (77, pdu(16, "HH", 1000, 2))
    assert ncgate_gateway.image.read("SYVAR", 0, "IN") == -1
    assert ncgate_gateway.image.read("SYVAR", 1, "IN") == 5


async def test_read_write_multiple_writes_first_then_reads(ncgate_gateway: Gateway,
                                                           raw: Raw) -> None:
    answer = await raw.ask(pdu(23, "HHHHBHH", 30, 3, 31, 2, 4, 8, 9))
    assert answer == bytes((23, 6)) + struct.pack(">HHH", 0, 8, 9)
    before = ncgate_gateway.image.snapshot()
    # a bad read range stops the write too
    assert await raw.ask(pdu(23, "HHHHBH", 600, 1, 31, 1, 2, 1)) == exc(23, 2)
    await still_serves(ncgate_gateway, raw, before)


async def test_read_write_multiple_reads_across_adjacent_regions_as_fc3(
        ncgate_gateway: Gateway, raw: Raw) -> None:
    """Issue 10.1: the command (2000) and the mailbox (2001..2002) are adjacent regions; FC3
    reads across them (docs/decisions.md), and so does FC23's read."""
    fc3 = await raw.ask(pdu(3, "HH", 2000, 3))
    assert fc3 == bytes((3, 6)) + struct.pack(">HHH", 0, 0, 0)
    answer = await raw.ask(pdu(23, "HHHHBH", 2000, 3, 31, 1, 2, 4))
    assert answer == bytes((23,)) + fc3[1:]
    assert ncgate_gateway.image.read("SK", 31, "BY") == 4
    # A bad write value with that read: 03 (the value), not 02, and nothing stored.
    before = ncgate_gateway.image.snapshot()
    assert await raw.ask(pdu(23, "HHHHBH", 2000, 3, 31, 1, 2, 256)) == exc(23, 3)
    await still_serves(ncgate_gateway, raw, before)


async def test_mask_write(ncgate_gateway: Gateway, raw: Raw) -> None:
    ncgate_gateway.write("SK40", 0b1010_1010)
    answer = await raw.ask(pdu(22, "HHH", 40, 0x00F0, 0x0005))
    assert answer == pdu(22, "HHH", 40, 0x00F0, 0x0005)
    assert ncgate_gateway.image.read("SK", 40, "BY") == 0b1010_0101


@pytest.mark.parametrize("ncgate_config", [{"modbus.read_only": True}], indirect=True)
async def test_read_only(ncgate_gateway: Gateway, raw: Raw) -> None:
    before = ncgate_gateway.image.snapshot()
    for request in (pdu(5, "HH", 1, 0xFF00), pdu(6, "HH", 1, 1), pdu(6, "HH", 2000, 1),
                    pdu(15, "HHBB", 0, 1, 1, 1), pdu(16, "HHBH", 1000, 1, 2, 1),
                    pdu(22, "HHH", 1, 0, 1), pdu(23, "HHHHBH", 0, 1, 0, 1, 2, 1)):
        assert await raw.ask(request) == exc(request[0], 2)
    assert (await raw.ask(pdu(3, "HH", 0, 1)))[0] == 3  # reads still work
    await still_serves(ncgate_gateway, raw, before)


@pytest.mark.parametrize("ncgate_config", [{"nc.cell": "test cell"}], indirect=True)
async def test_device_identification_as_hmis_ask_for_it(ncgate_gateway: Gateway) -> None:
    """Issue 10.4: FC43/14 with pymodbus's client: basic and regular streams, one object at a
    time, the same identity as CANopen 0x1018 and the config's cell name."""
    host, port = ncgate_gateway.modbus_address
    client = AsyncModbusTcpClient(host, port=port, retries=0)
    await client.connect()
    try:
        basic = await client.read_device_information(read_code=1, object_id=0, device_id=1)
        assert basic.information == {0: b"ncgate", 1: b"NCGT", 2: __version__.encode()}
        assert basic.conformity == 0x82 and basic.more_follows == 0
        regular = await client.read_device_information(read_code=2, object_id=0, device_id=1)
        assert regular.information == {
            0: b"ncgate", 1: b"NCGT", 2: __version__.encode(),
            4: b"ncgate CNC co-simulator gateway",
            5: f"ncgate {__version__}".encode(), 6: b"test cell"}
        one = await client.read_device_information(read_code=4, object_id=6, device_id=1)
        assert one.information == {6: b"test cell"}
        missing = await client.read_device_information(read_code=4, object_id=3, device_id=1)
        assert missing.isError() and missing.exception_code == 2
    finally:
        client.close()
    od = build_dictionary(ncgate_gateway.config)
    assert od[0x1018][2].default == int.from_bytes(b"NCGT", "big")  # the same product code
    assert od[0x1018][3].default >> 16 == 1 and od[0x1018][3].default & 0xFFFF == 0  # map 1.0


async def test_device_identification_errors(ncgate_gateway: Gateway, raw: Raw) -> None:
    before = ncgate_gateway.image.snapshot()
    assert await raw.ask(bytes((43, 0x0D, 1, 0))) == exc(43, 1)  # CANopen reference: not served
    assert await raw.ask(bytes((43, 0x0E, 5, 0))) == exc(43, 3)  # no read code 5
    assert await raw.ask(bytes((43, 0x0E, 1))) == exc(43, 3)  # too short
    # Stream access from an object the category does not hold restarts at object 0.
    answer = await raw.ask(bytes((43, 0x0E, 1, 0x05)))
    assert answer[:7] == bytes((43, 0x0E, 1, 0x82, 0, 0, 3)) and answer[7:9] == bytes((0, 6))
    await still_serves(ncgate_gateway, raw, before)
