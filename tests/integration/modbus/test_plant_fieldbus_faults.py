"""The plant's Modbus faults through the door (``gw.fault("modbus", ...)``, a script's
``[[fault]]``), as an independent client sees them: mbpoll (Debian) and pymodbus."""

from __future__ import annotations

import asyncio
import os
import shutil

import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.gateway import Gateway

from .test_mbpoll import mbpoll

NEEDS_MBPOLL = pytest.mark.skipif(
    shutil.which("mbpoll") is None and not os.environ.get("CI"),
    reason="mbpoll not installed (apt-get install mbpoll); CI runs these")


@NEEDS_MBPOLL
async def test_mbpoll_sees_exception_06_while_the_fault_is_in_force(
        ncgate_gateway: Gateway) -> None:
    gw = ncgate_gateway
    rc, values, _ = await mbpoll(gw, "coils", 10)
    assert rc == 0 and values == {10: 0}
    gw.fault("modbus", "exception", code=6, addresses=[0, 99])
    rc, values, text = await mbpoll(gw, "coils", 10)
    assert rc != 0 and values == {} and "Slave device or server is busy" in text, text
    rc, values, _ = await mbpoll(gw, "holding", 1000)  # outside the range: answered
    assert rc == 0 and values == {1000: 0}
    gw.clear_fault("modbus")
    rc, values, _ = await mbpoll(gw, "coils", 10)
    assert rc == 0 and values == {10: 0}
    events = [(e["event"], e["target"], e["kind"]) for e in gw.trace
              if e["event"] in ("fault", "fault_clear")]
    assert events == [("fault", "modbus", "exception"), ("fault_clear", "modbus", "exception")]


async def test_a_write_under_an_exception_fault_stores_nothing_and_for_s_ends_it(
        ncgate_gateway: Gateway) -> None:
    gw = ncgate_gateway
    host, port = gw.modbus_address
    client = AsyncModbusTcpClient(host, port=port, retries=0)
    assert await client.connect()
    try:
        gw.fault("modbus", "exception", code=4, unit=1)
        answer = await client.write_coil(10, True, device_id=1)
        assert answer.isError() and answer.exception_code == 4
        assert gw.read("SA10") == 0
        gw.clear_fault()
        gw.fault("modbus", "delay", ms=50, for_s=100.0)
        answer = await client.write_coil(10, True, device_id=1)
        assert not answer.isError() and gw.read("SA10") == 1
        assert gw.modbus_server is not None
        assert gw.modbus_server.fault_counts["delay"] == 1
        from ncgate.gateway.web.status import fieldbus

        shown = fieldbus(gw)["modbus"]
        assert shown["faults"] == [{"kind": "delay", "ms": 50.0, "unit": None,
                                    "addresses": None}]  # (no exception code: none is sent)
        assert shown["fault_counts"]["exception"] == 1 and shown["fault_counts"]["delay"] == 1
    finally:
        client.close()


async def test_a_connection_made_a_turn_after_its_protocol_obeys_a_fault_set_between(
        ncgate_gateway: Gateway) -> None:
    """uvloop makes a connection's protocol at the accept and calls connection_made a turn
    later; a fault table set in between must hold for it too (it answered past the faults:
    found by run --script under uvloop).  The order forced here, on a real socket."""
    import socket

    from ncgate.gateway.modbus.faults import ModbusFault
    from ncgate.gateway.modbus.server import _Connection

    gw = ncgate_gateway
    server = gw.modbus_server
    assert server is not None
    protocol = _Connection(server)  # made at the accept: no fault yet
    server.set_faults([ModbusFault("exception", code=6)])  # ... then a fault, before it is known
    loop = asyncio.get_running_loop()
    ours, theirs = socket.socketpair()
    transport, _ = await loop.connect_accepted_socket(lambda: protocol, ours)  # connection_made
    reader, writer = await asyncio.open_connection(sock=theirs)
    try:
        writer.write(bytes.fromhex("0001 0000 0006 01 01 000A 0001"))  # FC1, coil 10
        answer = await asyncio.wait_for(reader.readexactly(9), 10)
        assert answer[7:9] == bytes((0x81, 6)), answer.hex()  # exception 06
    finally:
        writer.close()
        transport.close()
        server.set_faults(())
