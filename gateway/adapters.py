"""The adapters as plug-ins: one registry of what serves the cell to the outside.

Each adapter is a folder beside this module whose package exposes ``PLUGIN``, an
:class:`AdapterPlugin`: whether the config enables it, how to build it on a running
:class:`~ncgate.gateway.Gateway`, what its status is (the console's ``fieldbus`` entry) and
what ``ncgate run`` logs once it serves.  :data:`ADAPTERS` names each one's module, as
python-can's ``BACKENDS`` table names its interfaces: a module is imported only when its
adapter is enabled, so a cell without a console never loads aiohttp.  A new fieldbus is one
folder plus one line here (ARCHITECTURE.md; ``tests/integration/test_adapters.py`` builds a
toy one in a temporary package).

``Gateway`` starts the enabled adapters in this order, each after the previous one started,
and closes them in reverse; the console comes last, so that it can show the others.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ncgate.gateway.errors import GatewayError
from ncgate.gateway.lifecycle import Adapter

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.plant import ActiveFault


@dataclass(frozen=True, slots=True)
class AdapterPlugin:
    """What the gateway needs of an adapter.

    ``enabled(gw)``: whether this gateway serves it (its config section, the gateway's own
    options such as ``console=True``); ``factory(gw)``: the adapter, not started yet;
    ``status(adapter)``: a JSON-able summary for the console and ``/api/status`` (None: it has
    none); ``describe(adapter)``: the lines ``ncgate run`` logs once it serves (where it
    listens); ``faults(adapter, faults)``: the plant's fieldbus faults in force
    (docs/plant.md), each time they change -- an adapter takes those of its own target,
    ``fault_target`` (``modbus``, ``canopen``): a fault of a target no adapter serving takes
    is said to have no effect."""

    enabled: Callable[[Gateway], bool]
    factory: Callable[[Gateway], Adapter]
    status: Callable[[Any], dict[str, Any] | None] = lambda adapter: None
    describe: Callable[[Any], list[str]] = lambda adapter: []
    faults: Callable[[Any, list[ActiveFault]], None] | None = None
    fault_target: str | None = None


# name -> "module:attribute" of its AdapterPlugin, in start order.
ADAPTERS: dict[str, str] = {
    "modbus": "ncgate.gateway.modbus.plugin:PLUGIN",
    "modbus_rtu": "ncgate.gateway.rtu.plugin:PLUGIN",
    "canopen": "ncgate.gateway.canopen.plugin:PLUGIN",
    "opcua": "ncgate.gateway.opcua.plugin:PLUGIN",
    "web": "ncgate.gateway.web.plugin:PLUGIN",
}


def plugin(name: str) -> AdapterPlugin:
    """The registered adapter ``name``'s plug-in (its module imported now)."""
    try:
        where = ADAPTERS[name]
    except KeyError:
        raise GatewayError(f"no adapter {name!r} (registered: {', '.join(ADAPTERS)})") \
            from None
    module, _, attribute = where.partition(":")
    found = getattr(importlib.import_module(module), attribute or "PLUGIN")
    if not isinstance(found, AdapterPlugin):
        raise GatewayError(f"{where}: not an AdapterPlugin")
    return found
