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

The fixtures come with the ``ncgate[pytest]`` extra (pytest-asyncio).  Without it this plugin,
which pytest loads wherever ncgate is installed, defines the fixtures as ones that fail with
that advice, and nothing else: it never breaks a test run that does not use them.
"""

from __future__ import annotations

import itertools
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from ncgate.config import Config, load_config

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.testing.canopen_kit import CanopenMaster
    from ncgate.gateway.testing.modbus_kit import VirtualPLC
    from ncgate.gateway.testing.plc_kit import PlcWatch

try:
    import pytest_asyncio

    HAVE_PYTEST_ASYNCIO = True
except ImportError:  # the ncgate[pytest] extra is not installed
    HAVE_PYTEST_ASYNCIO = False


def ncgate_test_config(path: str | Path | None = None, **overrides: Any) -> Config:
    """A config for a test: the file (None: built-in) with Modbus (and Modbus/TCP Security,
    if configured) on free ports and the CANopen node on a virtual CAN channel of its own (so
    tests never hear each other)."""
    channel = f"ncgate-test-{next(_channels)}"
    return load_config(path, overrides={"modbus.port": 0, "modbus.tls.port": 0,
                                        "canopen.channel": channel, **overrides})


_channels = itertools.count(1)


@pytest.fixture
def ncgate_config() -> Config:
    """Override in your conftest.py to run your own cell."""
    return ncgate_test_config()


if HAVE_PYTEST_ASYNCIO:

    @pytest_asyncio.fixture
    async def ncgate_gateway(ncgate_config: Config) -> AsyncIterator[Gateway]:
        """A running gateway (soft PLC, processes, Modbus TCP on a free loopback port)."""
        from ncgate.gateway.app import Gateway

        async with Gateway(ncgate_config) as gateway:
            yield gateway

    @pytest.fixture
    def canopen_master(ncgate_gateway: Gateway) -> Iterator[CanopenMaster]:
        """A canopen master on the gateway's CAN bus, hearing TPDO1, TPDO2 and EMCY."""
        from ncgate.gateway.testing.canopen_kit import CanopenMaster

        node_id = ncgate_gateway.config.canopen.node_id
        master = CanopenMaster(ncgate_gateway.config,
                               listen=(0x180 + node_id, 0x280 + node_id, 0x80 + node_id))
        yield master
        master.close()

    @pytest.fixture
    def plc_watch(ncgate_gateway: Gateway) -> PlcWatch:
        """The gateway's PLC logic variables: ``read(path)``, ``await until(path, value)``."""
        from ncgate.gateway.testing.plc_kit import PlcWatch

        return PlcWatch(ncgate_gateway)

    @pytest_asyncio.fixture
    async def virtual_plc(ncgate_gateway: Gateway) -> AsyncIterator[VirtualPLC]:
        """A Modbus client connected to ``ncgate_gateway``, with PLC helpers."""
        from ncgate.gateway.testing.modbus_kit import VirtualPLC

        host, port = ncgate_gateway.modbus_address
        async with VirtualPLC(host, port, ncgate_gateway.config) as plc:
            yield plc

else:
    _MISSING = "the ncgate fixtures need pytest-asyncio: pip install 'ncgate[pytest]'"

    @pytest.fixture
    def ncgate_gateway() -> None:
        pytest.fail(_MISSING)

    @pytest.fixture
    def canopen_master() -> None:
        pytest.fail(_MISSING)

    @pytest.fixture
    def plc_watch() -> None:
        pytest.fail(_MISSING)

    @pytest.fixture
    def virtual_plc() -> None:
        pytest.fail(_MISSING)
