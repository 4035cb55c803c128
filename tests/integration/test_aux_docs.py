"""The timelines of docs/interfacing-a-plc.md are the tool's own and current: drawn again by
docs/interfacing-a-plc/make.py (``ncgate sim --gantt``), they are the files the page shows."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from ..conftest import ROOT

FOLDER = ROOT / "docs" / "interfacing-a-plc"


def test_the_handshake_pictures_are_what_the_tool_draws_now(tmp_path: Path) -> None:
    spec = importlib.util.spec_from_file_location("make_aux_pictures", FOLDER / "make.py")
    assert spec is not None and spec.loader is not None
    make = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make)
    make.build(tmp_path)
    page = (ROOT / "docs" / "interfacing-a-plc.md").read_text(encoding="utf-8")
    for name in make.PICTURES:
        assert f"interfacing-a-plc/{name}" in page, f"the page does not show {name}"
        assert (tmp_path / name).read_text() == (FOLDER / name).read_text(), (
            f"docs/interfacing-a-plc/{name} is stale: run .venv/bin/python "
            "docs/interfacing-a-plc/make.py")
