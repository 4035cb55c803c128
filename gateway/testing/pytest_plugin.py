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

import dataclasses
import itertools
import os
import tempfile
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from ncgate.config import Config, load_config
from ncgate.gateway.canopen.store import default_path as store_path
from ncgate.plc.retain import default_path as retain_path

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.testing.canopen_kit import CanopenMaster
    from ncgate.gateway.testing.modbus_kit import VirtualPLC
    from ncgate.gateway.testing.plant_kit import PlantKit
    from ncgate.gateway.testing.plc_kit import PlcWatch
    from ncgate.gateway.testing.rtu_kit import PtyPair

try:
    import pytest_asyncio

    HAVE_PYTEST_ASYNCIO = True
except ImportError:  # the ncgate[pytest] extra is not installed
    HAVE_PYTEST_ASYNCIO = False


def ncgate_test_config(path: str | Path | None = None, **overrides: Any) -> Config:
    """A config for a test: the file (None: built-in; a relative path is relative to the
    test file's folder) with every port the gateway opens free (``modbus.port``,
    ``modbus.tls.port``, ``canopen.hub_port``, ``web.port``, ``opcua.port``: 0), its CANopen
    node on a virtual CAN channel of its own (so tests, and pytest-xdist workers, never hear each
    other), and every file the gateway writes (``plc.retain_file``, ``canopen.store_file``,
    ``trace.file`` when set) in the test's ``tmp_path``, unless ``overrides`` names it: RETAIN
    values and a 0x1010 "save" last as long as the test (two configs made in one test share
    them), never into the next test or run.

    Outside a test (at import, in a session fixture) a relative path is relative to the
    current folder and the files go into a new temporary folder of the session."""
    path = from_test_folder(path)
    channel = f"ncgate-test-{os.environ.get('PYTEST_XDIST_WORKER', 'main')}-{next(_channels)}"
    config = load_config(path, overrides={"modbus.port": 0, "modbus.tls.port": 0,
                                          "canopen.hub_port": 0, "web.port": 0,
                                          "opcua.port": 0,
                                          "canopen.channel": channel, **overrides})
    folder = _files_folder()
    plc, canopen, trace = config.plc, config.canopen, config.trace
    if "plc.retain_file" not in overrides:
        plc = dataclasses.replace(plc, retain_file=retain_path(folder))
    if "canopen.store_file" not in overrides:
        canopen = dataclasses.replace(canopen,
                                      store_file=store_path(folder, canopen.node_id))
    if trace.file is not None and "trace.file" not in overrides:
        trace = dataclasses.replace(trace, file=folder / trace.file.name)
    return dataclasses.replace(config, plc=plc, canopen=canopen, trace=trace)


_channels = itertools.count(1)


class _Current:
    """The test being set up or run (the autouse fixture below), for ncgate_test_config,
    which is a plain function: its tmp_path is asked for only when a config is made."""

    request: pytest.FixtureRequest | None = None
    session_tmp: pytest.TempPathFactory | None = None


_current = _Current()


def from_test_folder(path: str | Path | None) -> Path | None:
    """A relative path as relative to the folder of the current test's file (outside a
    test: as it is, relative to the current folder)."""
    if path is None:
        return None
    test = _current.request
    if test is None or Path(path).is_absolute():
        return Path(path)
    return test.path.parent / path


def _files_folder() -> Path:
    if _current.request is not None:
        tmp_path: Path = _current.request.getfixturevalue("tmp_path")
        return tmp_path
    if _current.session_tmp is not None:
        return _current.session_tmp.mktemp("ncgate")
    return Path(tempfile.mkdtemp(prefix="ncgate-test-"))


@pytest.fixture(scope="session", autouse=True)
def _ncgate_session_tmp(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    _current.session_tmp = tmp_path_factory
    yield
    _current.session_tmp = None


@pytest.fixture(autouse=True)
def _ncgate_current_test(request: pytest.FixtureRequest) -> Iterator[None]:
    _current.request = request
    yield
    _current.request = None


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

    @pytest.fixture
    def plant(ncgate_gateway: Gateway) -> PlantKit:
        """The gateway's plant (docs/plant.md): ``await plant.fault("clamp", "never")``,
        ``await plant.clear()``, ``plant.state("clamp")``, ``await plant.wait_state(...)``;
        beside ``virtual_plc``, the faults act on what the PLC reads over Modbus."""
        from ncgate.gateway.testing.plant_kit import PlantKit

        return PlantKit(ncgate_gateway)

    @pytest_asyncio.fixture
    async def virtual_plc(ncgate_gateway: Gateway) -> AsyncIterator[VirtualPLC]:
        """A Modbus client connected to ``ncgate_gateway``, with PLC helpers."""
        from ncgate.gateway.testing.modbus_kit import VirtualPLC

        host, port = ncgate_gateway.modbus_address
        async with VirtualPLC(host, port, ncgate_gateway.config) as plc:
            yield plc

    @pytest_asyncio.fixture
    async def ncgate_rtu_line() -> AsyncIterator[PtyPair]:
        """A serial line of two ptys, relayed in this process: give ``gateway_end`` to the
        gateway (``modbus.rtu.port`` in your ``ncgate_config``) and ``plc_end`` to the
        master (``rtu_plc`` does)."""
        from ncgate.gateway.testing.rtu_kit import PtyPair

        async with PtyPair() as line:
            yield line

    @pytest_asyncio.fixture
    async def rtu_plc(ncgate_gateway: Gateway, ncgate_rtu_line: PtyPair
                      ) -> AsyncIterator[VirtualPLC]:
        """``virtual_plc`` as a Modbus RTU master on ``ncgate_rtu_line``'s other end."""
        from ncgate.gateway.testing.modbus_kit import VirtualPLC

        if ncgate_gateway.config.modbus.rtu.port != ncgate_rtu_line.gateway_end:
            pytest.fail("rtu_plc: the gateway does not serve ncgate_rtu_line: give "
                        "ncgate_test_config(..., **{'modbus.rtu.port': "
                        "ncgate_rtu_line.gateway_end}) in your ncgate_config fixture")
        async with VirtualPLC.rtu(ncgate_rtu_line.plc_end, ncgate_gateway.config) as plc:
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

    @pytest.fixture
    def plant() -> None:
        pytest.fail(_MISSING)

    @pytest.fixture
    def ncgate_rtu_line() -> None:
        pytest.fail(_MISSING)

    @pytest.fixture
    def rtu_plc() -> None:
        pytest.fail(_MISSING)
