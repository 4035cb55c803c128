"""The frames between the gateway's loop and the OPC UA server's process: a 4-byte length,
then a pickle.  Both ends are ncgate (the same install, started by the adapter), so a pickle
is safe here: nothing else writes to these pipes.  No asyncua here (the loop's side imports
it).

Gateway -> server: ``("start", OpcuaConfig, layout)``, ``("batch", [(kind, item), ...])``,
``("result", n, Reason | None | "error")``, ``("stop",)``.
Server -> gateway: ``("ready", port)``, ``("error", text)``,
``("write", n, key, value, who)``, ``("clients", sessions, subscriptions)``.
"""

from __future__ import annotations

import asyncio
import pickle
import struct
from typing import Any

_LENGTH = struct.Struct(">I")


def frame(message: Any) -> bytes:
    body = pickle.dumps(message, pickle.HIGHEST_PROTOCOL)
    return _LENGTH.pack(len(body)) + body


async def read_frame(reader: asyncio.StreamReader) -> Any:
    """The next message; EOFError when the other end has closed its pipe."""
    try:
        header = await reader.readexactly(_LENGTH.size)
        body = await reader.readexactly(_LENGTH.unpack(header)[0])
    except asyncio.IncompleteReadError:
        raise EOFError from None
    return pickle.loads(body)
