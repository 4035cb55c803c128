"""The commissioning console as a gateway adapter (``ncgate.gateway.adapters``): served when
the gateway is asked for it (``Gateway(console=True)``, ``ncgate run``) and ``[web]`` enables
it; aiohttp is imported only then."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ncgate.gateway.adapters import AdapterPlugin

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.lifecycle import Adapter
    from ncgate.gateway.web.console import WebConsole


def _factory(gw: Gateway) -> Adapter:
    from ncgate.gateway.web.console import WebConsole  # aiohttp: only when served

    return WebConsole(gw, gw.config.web, gw.web_default_port)


def describe(console: WebConsole) -> list[str]:
    if console.address is None:
        return []
    web = console.config
    return [f"web console on {console.url}" + (" (read-only)" if web.read_only else "")
            + (" (writes need the token)" if web.token else "")]


PLUGIN = AdapterPlugin(enabled=lambda gw: gw.console_wanted and gw.config.web.enabled,
                       factory=_factory, describe=describe)
