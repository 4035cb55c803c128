"""The plant's Modbus faults through the door (``gw.fault("modbus", ...)``, a script's
``[[fault]]``), as an independent client sees them: mbpoll (Debian) and pymodbus."""

from __future__ import annotations

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
        assert shown["faults"] == [{"kind": "delay", "code": 6, "ms": 50.0, "unit": None,
                                    "addresses": None}]
        assert shown["fault_counts"]["exception"] == 1 and shown["fault_counts"]["delay"] == 1
    finally:
        client.close()
