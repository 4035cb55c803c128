"""What the docs show the tools printing is what they print (issue 25, item 18): the `check`
example in the README and docs/language.md, the script error in docs/script.md, run as
processes; and the README's `[modbus.map]` block names every key of the schema."""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from ncgate.config import ModbusMapConfig

from ..conftest import ROOT

PROG92 = ROOT / "config" / "programs" / "PROG92.nc"


def ncgate(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ncgate", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("page", ["README.md", "docs/language.md"])
def test_the_check_example_is_what_check_prints(page: str, tmp_path: Path) -> None:
    text = (ROOT / page).read_text(encoding="utf-8")
    (block,) = re.findall(r"```\n(PROG92\.nc:.*?)```", text, re.S)
    # The example: PROG92 with the ')' of its N40 missing.
    source = PROG92.read_text(encoding="utf-8").replace("N40(WAI,SA10=1)", "N40(WAI,SA10=1")
    (tmp_path / "PROG92.nc").write_text(source, encoding="utf-8")
    done = ncgate("check", "PROG92.nc", cwd=tmp_path)
    assert done.returncode == 1
    *diagnostic, summary = block.splitlines()
    assert done.stdout.splitlines() == diagnostic  # the diagnostic, on stdout
    assert summary in done.stderr.splitlines()  # the summary, on stderr


def test_the_script_error_in_docs_script_md_is_what_sim_prints(tmp_path: Path) -> None:
    text = (ROOT / "docs" / "script.md").read_text(encoding="utf-8")
    (shown,) = re.findall(r"`(script\.toml: write\[\d+\]\.set: [^`]*)`", text)
    (tmp_path / "script.toml").write_text('[[write]]\nat = 1.0\nset = "SA10"\n')
    done = ncgate("sim", "--script", "script.toml", cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip() == f"ncgate sim: {shown}"


def test_the_readme_modbus_map_block_names_every_key() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    (block,) = [b for b in re.findall(r"```toml\n(.*?)```", text, re.S)
                if b.startswith("[modbus.map]")]
    shown = tomllib.loads(block)["modbus"]["map"]
    assert list(shown) == [f.name for f in dataclasses.fields(ModbusMapConfig)]


def _curl_posts() -> list[tuple[str, str]]:
    """Each documented curl command that posts a body: a line of a fenced block, or an
    inline code span (which may be folded over lines)."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
             *sorted((ROOT / "examples").glob("*/README.md"))]
    found = []
    for page in pages:
        text = page.read_text()
        blocks = re.findall(r"```[^\n]*\n(.*?)```", text, re.S)
        commands = [line for block in blocks for line in block.splitlines()]
        rest = re.sub(r"```[^\n]*\n.*?```", "", text, flags=re.S)
        commands += [" ".join(span.split()) for span in re.findall(r"`([^`]+)`", rest)]
        for command in commands:
            command = command.strip()
            if command.startswith("curl ") and "/api/" in command and (
                    " -d " in command or "--data" in command):
                found.append((page.relative_to(ROOT).as_posix(), command))
    return found


def test_every_curl_in_the_docs_that_posts_a_body_sends_it_as_json() -> None:
    """The console's API takes JSON only (415 otherwise: a plain form cannot post to it,
    docs/console.md); curl's -d alone sends a form, so a documented command without the
    header fails for whoever copies it."""
    posts = _curl_posts()
    assert len(posts) >= 4  # README's fault, docs/plant.md's two, docs/console.md's two
    wrong = [f"{page}: {command}" for page, command in posts
             if "Content-Type: application/json" not in command]
    assert not wrong, "\n".join(wrong)
