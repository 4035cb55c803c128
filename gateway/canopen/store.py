"""Store and restore of the communication parameters (CiA 301 7.5.2.13/14, 0x1010/0x1011).

A master writes the signature "save" to 0x1010 (sub 1 all, sub 2 communication) and the
node keeps the communication parameters (0x1000..0x1FFF) it was given -- PDO COB-IDs,
types, mappings, SYNC COB-ID, heartbeat times -- in a file next to the config
(``canopen.store_file``; for the built-in config or one inside a package, in the per-user
state folder: ``ncgate.config.state``).  They are the node's power-on values from then on:
at start and after reset node / reset communication.  "load" written to 0x1011 removes the file: the
defaults return with the next reset, as CiA 301 says.

The file is written whole or not at all (``ncgate.gateway.atomic``): a temporary file in
the same folder, flushed and fsynced, then renamed over the old one (``os.replace`` is
atomic), then the folder fsynced.  A ``kill -9`` at any moment leaves the old file or the new
one.  A file that cannot be read or does not fit the dictionary (a config changed since) is
reported and ignored.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
from pathlib import Path

from ncgate.gateway.atomic import write_atomic

log = logging.getLogger("ncgate.canopen")

SAVE = int.from_bytes(b"save", "little")  # 0x65766173
LOAD = int.from_bytes(b"load", "little")  # 0x64616F6C
FORMAT = "ncgate-canopen-parameters/1"

Parameters = dict[int, dict[int, bytes]]


def default_path(folder: Path, node_id: int) -> Path:
    """The file when ``canopen.store_file`` is not set, in the config's state folder
    (``ncgate.config.state.state_folder``: beside the user's config, never in a package)."""
    return folder / f"ncgate-canopen-node{node_id}.json"


def save(path: Path, parameters: Parameters) -> None:
    document = {
        "format": FORMAT,
        "parameters": {f"0x{index:04X}": {str(sub): data.hex()
                                          for sub, data in sorted(subs.items())}
                       for index, subs in sorted(parameters.items())},
    }
    write_atomic(path, (json.dumps(document, indent=1) + "\n").encode("utf-8"))


def load(path: Path) -> Parameters | None:
    """The stored parameters, or None (no file, or one that cannot be used: logged)."""
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
        if document["format"] != FORMAT:
            raise ValueError(f"format {document['format']!r}, expected {FORMAT!r}")
        return {int(index, 16): {int(sub): bytes.fromhex(data) for sub, data in subs.items()}
                for index, subs in document["parameters"].items()}
    except FileNotFoundError:
        return None
    except (OSError, KeyError, TypeError, ValueError, AttributeError) as exc:
        log.warning("%s: stored CANopen parameters not used (%s); the defaults apply", path,
                    exc)
        return None


def remove(path: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)
