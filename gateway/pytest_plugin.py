"""The ncgate pytest plugin (entry point ``pytest11``): a gateway and a virtual PLC as fixtures.

In your tests::

    async def test_p2_waits_for_the_plc(ncgate_gateway, virtual_plc):
        await ncgate_gateway.start("PROG91")
        await virtual_plc.wait_state(2, "WAIT_COND")
        await virtual_plc.set("SA10", 1)
        await ncgate_gateway.wait_idle(timeout_s=60)

``canopen_master`` is a canopen master on the gateway's CAN bus (``upload``, ``download``,
``next_frame``, ``nmt``).  The gateway runs the config of the ``ncgate_config`` fixture --
the built-in default on a free port unless you override it in your conftest.py, e.g.::

    @pytest.fixture
    def ncgate_config():
        return ncgate_test_config("cell/ncgate.toml", **{"nc.time_scale": 50.0})
"""

from __future__ import annotations

import itertools
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio

from config import Config, load_config
from gateway.app import Gateway
from gateway.canopen_testkit import CanopenMaster
from gateway.modbus_testkit import VirtualPLC


def ncgate_test_config(path: str | Path | None = None, **overrides: Any) -> Config:
    """A config for a test: the file (None: built-in) with Modbus on a free port and the
    CANopen node on a virtual CAN channel of its own (so tests never hear each other)."""
    channel = f"ncgate-test-{next(_channels)}"
    return load_config(path, overrides={"modbus.port": 0, "canopen.channel": channel,
                                        **overrides})


_channels = itertools.count(1)


@pytest.fixture
def ncgate_config() -> Config:
    """Override in your conftest.py to run your own cell."""
    return ncgate_test_config()


@pytest_asyncio.fixture
async def ncgate_gateway(ncgate_config: Config) -> AsyncIterator[Gateway]:
    """A running gateway (soft PLC, processes, Modbus TCP on a free loopback port)."""
    async with Gateway(ncgate_config) as gateway:
        yield gateway


@pytest.fixture
def canopen_master(ncgate_gateway: Gateway) -> Iterator[CanopenMaster]:
    """A canopen master on the gateway's CAN bus, hearing TPDO1, TPDO2 and EMCY."""
    node_id = ncgate_gateway.config.canopen.node_id
    master = CanopenMaster(ncgate_gateway.config,
                           listen=(0x180 + node_id, 0x280 + node_id, 0x80 + node_id))
    yield master
    master.close()


@pytest_asyncio.fixture
async def virtual_plc(ncgate_gateway: Gateway) -> AsyncIterator[VirtualPLC]:
    """A Modbus client connected to ``ncgate_gateway``, with PLC helpers."""
    host, port = ncgate_gateway.modbus_address
    async with VirtualPLC(host, port, ncgate_gateway.config) as plc:
        yield plc
