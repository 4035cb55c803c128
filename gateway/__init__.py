"""ncgate's composition root and fieldbus adapters.

``gateway`` wires the packages together: it may import ``plc``, ``interpreter`` and
``config``; none of them imports ``gateway``.  The public API (spec 4.5):
``from ncgate import Gateway, load_config`` (or ``from ncgate.gateway import ...``).
"""

from ncgate.config import load_config
from ncgate.gateway.app import Gateway, GatewayError, ProcessAlarmError, WaitIdleTimeout

__all__ = ["Gateway", "GatewayError", "ProcessAlarmError", "WaitIdleTimeout", "load_config"]
