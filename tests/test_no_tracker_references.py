"""Code and user docs cite what a clone holds (CONTRIBUTING.md): a decision by its heading in
docs/decisions.md, a standard by its clause -- never an issue tracker's number, which a
user's clone does not have."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TRACKER = re.compile(r"\bissues? \d+\b|\bin later issues\b", re.IGNORECASE)
WHERE = ("ncgate", "config", "plc", "interpreter", "gateway", "examples", "docs")
FILES = ("README.md", "ARCHITECTURE.md", "CONTRIBUTING.md")
SUFFIXES = (".py", ".md", ".js", ".html", ".toml", ".st", ".nc", ".lark")


def found(text: str) -> list[str]:
    return [m.group(0) for m in TRACKER.finditer(text)]


def test_no_code_or_user_doc_points_at_a_tracker() -> None:
    paths = [ROOT / name for name in FILES]
    for folder in WHERE:
        paths += [p for p in (ROOT / folder).rglob("*") if p.suffix in SUFFIXES]
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}"
            for p in paths for i, line in enumerate(p.read_text(encoding="utf-8",
                                                               errors="replace").splitlines(), 1)
            if found(line)]
    assert hits == [], "\n".join(hits)


def test_the_check_sees_a_reference() -> None:
    assert found("Breakpoints (issue 27, item 3): where") == ["issue 27"]
    assert found("fieldbus servers in later issues") == ["in later issues"]
    assert found("the issue leaves the form open") == []
