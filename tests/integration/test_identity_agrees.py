"""The two fieldbuses name the same release (issue 25, item 18): Modbus device identification
(FC43/14, object 0x02 MajorMinorRevision) and CANopen's manufacturer software version
(0x100A), each read with its own protocol's client."""

from __future__ import annotations

from pymodbus.client import AsyncModbusTcpClient

from ncgate import __version__
from ncgate.gateway import Gateway
from ncgate.gateway.testing.canopen_kit import CanopenMaster


async def test_fc43_revision_and_canopen_0x100a_give_the_same_version(
        ncgate_gateway: Gateway, canopen_master: CanopenMaster) -> None:
    host, port = ncgate_gateway.modbus_address
    client = AsyncModbusTcpClient(host, port=port, retries=0)
    await client.connect()
    try:
        answer = await client.read_device_information(read_code=4, object_id=2, device_id=1)
    finally:
        client.close()
    software = await canopen_master.upload(0x100A, 0)
    assert answer.information[2] == software == __version__.encode()
