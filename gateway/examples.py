"""The examples installed with ncgate (package data ``ncgate.examples``): what ``ncgate
examples`` lists and what ``--example NAME`` of ``sim`` and ``check`` runs.

An example is a folder with an ``ncgate.toml`` (whose ``nc.main`` is the program to start), its
programs, an optional ``script.toml`` playing the PLC, and a README whose title says what it
shows.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from ncgate.config import load_config
from ncgate.gateway.errors import UsageError


@dataclass(frozen=True, slots=True)
class Example:
    name: str
    folder: Path
    main: str | None  # None: nothing to run (the errors example)
    summary: str

    @property
    def config(self) -> Path:
        return self.folder / "ncgate.toml"

    @property
    def script(self) -> Path | None:
        path = self.folder / "script.toml"
        return path if path.is_file() else None

    @property
    def scripts(self) -> list[Path]:
        """What ``sim --example`` plays: its scenario suite (``scenarios/*.toml``, each an
        independent run), else its ``script.toml``."""
        suite = sorted((self.folder / "scenarios").glob("*.toml"))
        if suite:
            return suite
        return [self.script] if self.script is not None else []


def examples_folder() -> Path:
    return Path(str(resources.files("ncgate.examples")))


def examples() -> list[Example]:
    out = []
    for folder in sorted(p for p in examples_folder().iterdir() if (p / "ncgate.toml").is_file()):
        main = load_config(folder / "ncgate.toml").nc.main
        runnable = any(p.stem.upper() == main.upper() for p in folder.glob("*.nc"))
        readme = folder / "README.md"
        title = readme.read_text(encoding="utf-8").splitlines()[0] if readme.is_file() else ""
        summary = title.lstrip("# ").partition(": ")[2] or title.lstrip("# ")
        out.append(Example(folder.name, folder, main if runnable else None, summary))
    return out


def find_example(name: str) -> Example:
    found = {e.name: e for e in examples()}
    if name not in found:
        raise UsageError(f"no example {name!r} (there are: {', '.join(found)})")
    return found[name]
