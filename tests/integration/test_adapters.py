"""Adapters as plug-ins (ncgate.gateway.adapters): a fourth adapter is one folder plus one
registry line -- proved with a toy one in a temporary package -- and an adapter that is not
enabled is not imported, nor its library."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.adapters import ADAPTERS, AdapterPlugin, plugin
from ncgate.gateway.errors import GatewayError
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.gateway.web.status import fieldbus

TOY = '''
"""A toy fieldbus: it hears the trace, writes through the door, and says how it is."""
from ncgate.gateway.adapters import AdapterPlugin
from ncgate.inputs import Source, SourceKind, Write

LOG = []


class ToyBus:
    def __init__(self, gw):
        self.gw = gw
        self.heard = 0
        self.faults = None

    async def start(self):
        LOG.append("start")
        self._unsubscribe = self.gw.runtime.trace.subscribe(self._hear)

    async def close(self):
        self._unsubscribe()
        LOG.append("close")

    def _hear(self, event):
        self.heard += 1

    def write(self, var, value):  # what a frame from the toy bus would do
        self.gw.apply(Write(var, value, Source(SourceKind.API, "toy")))


PLUGIN = AdapterPlugin(
    enabled=lambda gw: True,
    factory=ToyBus,
    status=lambda bus: {"heard": bus.heard},
    describe=lambda bus: ["toy bus on nothing"],
    faults=lambda bus, faults: setattr(bus, "faults", [f.kind for f in faults]),
)
'''


async def test_a_toy_adapter_is_one_folder_and_one_registry_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = tmp_path / "toybus"
    folder.mkdir()
    (folder / "__init__.py").write_text(TOY)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(ADAPTERS, "toy", "toybus:PLUGIN")  # the one registry line
    config = ncgate_test_config(None, **{"modbus.port": 0})
    async with Gateway(config) as gw:
        toy = gw.adapters["toy"]
        import toybus  # type: ignore[import-not-found]

        assert toybus.LOG == ["start"]
        toy.write("SA10", 1)  # through the door: traced, attributed
        assert gw.read("SA10") == 1
        write = next(e for e in gw.trace if e["event"] == "write" and e["var"] == "SA10")
        assert write["who"] == "api toy"
        shown = fieldbus(gw)
        assert shown["toy"]["heard"] >= 1 and shown["modbus"] is not None
        assert plugin("toy").describe(toy) == ["toy bus on nothing"]
        gw.fault("modbus", "delay", ms=5)  # the plant's fieldbus faults reach every adapter
        assert toy.faults == ["delay"]
    assert toybus.LOG == ["start", "close"]


def test_an_unknown_adapter_or_a_wrong_entry_is_said(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(GatewayError, match="no adapter 'nope'"):
        plugin("nope")
    monkeypatch.setitem(ADAPTERS, "bad", "ncgate.gateway.adapters:ADAPTERS")
    with pytest.raises(GatewayError, match="not an AdapterPlugin"):
        plugin("bad")
    assert isinstance(plugin("modbus"), AdapterPlugin)


def test_an_adapter_that_is_not_enabled_is_not_imported(tmp_path: Path) -> None:
    """In a fresh interpreter: a gateway with every adapter off loads none of their modules
    and none of their libraries."""
    script = textwrap.dedent('''
        import asyncio, sys
        from ncgate.config import load_config
        from ncgate.gateway import Gateway

        async def main():
            config = load_config(None, overrides={"modbus.enabled": False,
                                                  "canopen.enabled": False})
            async with Gateway(config) as gw:
                assert gw.adapters == {}, gw.adapters
        asyncio.run(main())
        loaded = [m for m in ("pymodbus", "canopen", "can", "aiohttp", "serial", "asyncua",
                              "ncgate.gateway.modbus.server", "ncgate.gateway.canopen.node",
                              "ncgate.gateway.rtu.server", "ncgate.gateway.web.console",
                              "ncgate.gateway.opcua.server")
                  if m in sys.modules]
        print("loaded:", loaded)
    ''')
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert "loaded: []" in done.stdout, done.stdout
