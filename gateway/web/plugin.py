"""The commissioning console as a gateway adapter (``ncgate.gateway.adapters``): served when
the gateway is asked for it (``Gateway(console=True)``, ``ncgate run``) and ``[web]`` enables
it; aiohttp is imported only when a client first connects (``port.py``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ncgate.gateway.adapters import AdapterPlugin

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.lifecycle import Adapter
    from ncgate.gateway.web.port import ConsolePort


def _factory(gw: Gateway) -> Adapter:
    from ncgate.gateway.web.port import ConsolePort

    return ConsolePort(gw, gw.config.web, gw.web_default_port)


def describe(console: ConsolePort) -> list[str]:
    if console.address is None:
        return []
    web = console.config
    return [f"web console on {console.url}" + (" (read-only)" if web.read_only else "")
            + (" (writes need the token)" if web.token else "")]


PLUGIN = AdapterPlugin(enabled=lambda gw: gw.console_wanted and gw.config.web.enabled,
                       factory=_factory, describe=describe)
