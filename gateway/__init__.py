"""ncgate's composition root and fieldbus adapters.

``gateway`` wires the packages together: it may import ``plc``, ``interpreter`` and
``config``; none of them imports ``gateway``.
"""

from config import load_config

__all__ = ["load_config"]
