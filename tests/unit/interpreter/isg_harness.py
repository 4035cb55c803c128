"""Runs ISG programs given as text: a folder with the file and its config, then ``run_sim``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway.sim import SimResult, run_sim


def isg_sim(tmp_path: Path, text: str, processes: int = 3, name: str = "PROG",
            config: str = "", script: str | None = None, until: float | None = None,
            **overrides: Any) -> SimResult:
    (tmp_path / f"{name}.nc").write_text(text, encoding="utf-8")
    (tmp_path / "ncgate.toml").write_text(
        f'[nc]\ndialect = "isg"\nprocesses = {processes}\nmain = "{name}"\n{config}\n',
        encoding="utf-8")
    script_path = None
    if script is not None:
        script_path = tmp_path / "script.toml"
        script_path.write_text(script, encoding="utf-8")
    cfg = load_config(tmp_path / "ncgate.toml", overrides=overrides)
    return run_sim(cfg, name, load_script(script_path), until)


def events(result: SimResult, kind: str, **match: Any) -> list[dict[str, Any]]:
    return [e for e in result.events
            if e["event"] == kind and all(e.get(k) == v for k, v in match.items())]
