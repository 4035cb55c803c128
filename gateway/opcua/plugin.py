"""The OPC UA server as a gateway adapter (``ncgate.gateway.adapters``).  Light: the server
and asyncua are imported only when it is built."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ncgate.gateway.adapters import AdapterPlugin

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.opcua.server import OpcuaServer


def _factory(gw: Gateway) -> OpcuaServer:
    from ncgate.gateway.opcua.server import OpcuaServer

    return OpcuaServer(gw)


def status(server: OpcuaServer) -> dict[str, Any]:
    return {"endpoint": server.endpoint, "security": server.config.security.value,
            "writable": sorted(server.config.writable), "sessions": server.sessions,
            "subscriptions": server.subscriptions, "writes": server.writes,
            "refused": server.refused}


def describe(server: OpcuaServer) -> list[str]:
    if server.endpoint is None:
        return []
    config = server.config
    writable = ", ".join(sorted(config.writable)) or "nothing (read-only)"
    return [f"OPC UA on {server.endpoint}, security {config.security.value}, clients may "
            f"write {writable}"]


PLUGIN = AdapterPlugin(enabled=lambda gw: gw.config.opcua.enabled, factory=_factory,
                       status=status, describe=describe)
