"""Where a config's run keeps what it writes on its own: the folder for the default RETAIN file
(``plc.retain_file``) and the default CANopen store (``canopen.store_file``).

Beside the user's config file, so that a cell's state travels with the cell.  Never inside
ncgate itself or any installed package (the built-in config, ``run --config
<site-packages>/ncgate/examples/...``): those may be read-only, are shared by every user, and
are replaced by the next install.  Their state goes into a folder of their own in the per-user
state directory, ``$XDG_STATE_HOME/ncgate`` (default ``~/.local/state/ncgate``), named after
where the config lives (``built-in``, ``examples/plclogic``).  docs/decisions.md says why.

Stdlib only.
"""

from __future__ import annotations

import importlib.util
import os
import sysconfig
from pathlib import Path


def user_state_dir() -> Path:
    """``$XDG_STATE_HOME/ncgate``, or ``~/.local/state/ncgate`` (XDG Base Directory)."""
    base = os.environ.get("XDG_STATE_HOME") or ""
    root = Path(base) if os.path.isabs(base) else Path.home() / ".local" / "state"
    return root / "ncgate"


def state_folder(source: Path | None) -> Path:
    """The folder for the files a run of the config at ``source`` (None: the built-in one)
    writes by default."""
    if source is None:
        return user_state_dir() / "built-in"
    folder = source.resolve().parent
    for label, root in _package_roots():
        if folder.is_relative_to(root):
            return user_state_dir() / label / folder.relative_to(root)
    return folder


def _package_roots() -> list[tuple[str, Path]]:
    """The folders ncgate ships (installed or an editable clone's), then site-packages."""
    roots: list[tuple[str, Path]] = []
    for name in ("ncgate.examples", "ncgate.config"):
        spec = importlib.util.find_spec(name)
        for location in (spec.submodule_search_locations or []) if spec else []:
            roots.append((name.rsplit(".", 1)[1], Path(location).resolve()))
    for key in ("purelib", "platlib"):
        roots.append(("site-packages", Path(sysconfig.get_paths()[key]).resolve()))
    return roots
