"""ncgate's composition root and fieldbus adapters.

``gateway`` wires the packages together: it may import ``plc``, ``interpreter`` and
``config``; none of them imports ``gateway``.  The public API (spec 4.5):
``from ncgate import Gateway, load_config`` (or ``from ncgate.gateway import ...``).

Importing the package is cheap, as ``import ncgate`` is: ``Gateway`` (and with it pymodbus,
canopen and aiohttp) is imported on first use, so that ``ncgate --version`` and the
commands that serve nothing do not load the fieldbus libraries.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ncgate.config import load_config
from ncgate.gateway.errors import GatewayError, ProcessAlarmError, WaitIdleTimeout

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway

__all__ = ["Gateway", "GatewayError", "ProcessAlarmError", "WaitIdleTimeout", "load_config"]


def __getattr__(name: str) -> Any:
    if name == "Gateway":
        from ncgate.gateway.app import Gateway

        return Gateway
    raise AttributeError(f"module 'ncgate.gateway' has no attribute {name!r}")
