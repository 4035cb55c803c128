"""The timelines of docs/interfacing-a-plc.md, drawn by the tool: ``ncgate sim --gantt`` on the
cell beside this file (its PLC logic answers the coolant's M08 and M09), once as it is and once
with the valve stuck (M09 never acknowledged: a stall)::

    .venv/bin/python docs/interfacing-a-plc/make.py     # writes docs/interfacing-a-plc/*.svg

tests/integration/test_aux_docs.py draws them again and fails when these are not current.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
PICTURES = {"handshake.svg": (), "missing-ack.svg": ("--set", "plc.logic=stuck.st")}


def build(out: Path) -> None:
    """Draw every picture into the folder ``out``."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name in ("ncgate.toml", "COOLANT.nc", "plc.st"):
            (folder / name).write_bytes((HERE / name).read_bytes())
        stuck = (HERE / "plc.st").read_text(encoding="utf-8").replace(
            "  stuck : BOOL;", "  stuck : BOOL := TRUE;")
        (folder / "stuck.st").write_text(stuck, encoding="utf-8")
        for picture, extra in PICTURES.items():
            done = subprocess.run(
                [sys.executable, "-m", "ncgate", "sim", "--config", str(folder / "ncgate.toml"),
                 *extra, "--gantt", str(out / picture)],
                capture_output=True, text=True, timeout=120, cwd=folder)
            if done.returncode not in (0, 1):  # 1: the stall the second picture shows
                raise RuntimeError(f"ncgate sim failed for {picture}:\n{done.stderr}")


if __name__ == "__main__":
    build(HERE)
