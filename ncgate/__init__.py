"""ncgate: a Modbus/CAN I/O gateway and PLC-logic co-simulator for multi-process CNC part
programs.

The public API (spec 4.5)::

    from ncgate import Gateway, load_config

The sub-packages, and which way their imports point (``tests/test_layering.py`` holds them to
it): ``ncgate.gateway`` (the composition root: the API, the CLI, Modbus, CANopen, the test
kit) imports ``ncgate.plc`` (the I/O image), ``ncgate.interpreter`` (the part-program
languages and the engine that runs them) and ``ncgate.config`` (the schema and its loader);
none of those three imports ``gateway``, and the interpreter imports neither ``plc`` nor
``config``.  Every exception ncgate raises derives from :class:`ncgate.errors.NcgateError`.

``import ncgate`` is cheap: the gateway (and with it pymodbus and canopen) is imported on the
first use of ``Gateway``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ncgate.errors import NcgateError

__version__ = "0.2.0"

if TYPE_CHECKING:
    from ncgate.config import Config, load_config
    from ncgate.gateway import Gateway

__all__ = ["Config", "Gateway", "NcgateError", "__version__", "load_config"]


def __getattr__(name: str) -> Any:
    if name in ("Config", "load_config"):
        from ncgate import config

        return getattr(config, name)
    if name == "Gateway":
        from ncgate.gateway import Gateway

        return Gateway
    raise AttributeError(f"module 'ncgate' has no attribute {name!r}")
