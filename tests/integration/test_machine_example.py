"""examples/machine: its scenario suite run as a user runs it (`ncgate sim --example machine`,
a process of its own), every expectation passing and listed in the JUnit file; and a bad case
without its fault failing, so that its expectations say something about the fault."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from ..conftest import EXAMPLES

FOLDER = EXAMPLES / "machine"
SCENARIOS = sorted((FOLDER / "scenarios").glob("*.toml"))


def ncgate(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ncgate", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120, check=False)


def verdict_lines(out: str) -> list[str]:
    return [line for line in out.splitlines() if line.startswith(("PASS ", "FAIL "))]


def expects_of(path: Path) -> list[dict[str, Any]]:
    with path.open("rb") as f:
        expects: list[dict[str, Any]] = tomllib.load(f).get("expect", [])
    return expects


def test_the_suite_passes_and_its_junit_file_lists_every_scenario(tmp_path: Path) -> None:
    junit = tmp_path / "verdicts.xml"
    done = ncgate("sim", "--example", "machine", "--junit", str(junit), cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    lines = verdict_lines(done.stdout)
    assert lines and all(line.startswith("PASS ") for line in lines), done.stdout
    assert len(lines) == sum(len(expects_of(p)) for p in SCENARIOS)
    # a good case and at least five bad ones, each with a fault and an expectation
    assert len(SCENARIOS) >= 6 and (FOLDER / "scenarios" / "good.toml") in SCENARIOS
    for path in SCENARIOS:
        with path.open("rb") as f:
            table = tomllib.load(f)
        assert table.get("expect"), path.name
        assert bool(table.get("fault")) == (path.name != "good.toml"), path.name
    suites = {Path(s.get("name", "")).name: s for s in ET.parse(junit).getroot()}
    assert set(suites) == {p.name for p in SCENARIOS}
    for path in SCENARIOS:
        suite = suites[path.name]
        assert suite.get("failures") == "0"
        assert [case.get("name") for case in suite] == [e["name"] for e in expects_of(path)]


def test_a_bad_case_without_its_fault_fails_its_expectations(tmp_path: Path) -> None:
    """clamp_never_closes expects the PLC's clamp alarm and a held cell: with the clamp
    working they do not come, and the run says so (exit 1, a FAIL line each)."""
    lines = []
    for e in expects_of(FOLDER / "scenarios" / "clamp_never_closes.toml"):
        lines.append("[[expect]]")
        # a TOML basic string is a JSON string; numbers, lists and true are the same in both
        lines += [f"{key} = {json.dumps(value)}" for key, value in e.items()]
    script = tmp_path / "clamp_works.toml"
    script.write_text("\n".join(lines) + "\n", encoding="utf-8")
    done = ncgate("sim", "--example", "machine", "--script", str(script), cwd=tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    failed = {line.split(":")[0].removeprefix("FAIL ")
              for line in verdict_lines(done.stdout) if line.startswith("FAIL ")}
    assert {"clamp alarm", "cell holds", "spindle never starts", "no part counted"} <= failed


def test_the_readme_names_every_scenario() -> None:
    readme = (FOLDER / "README.md").read_text(encoding="utf-8")
    assert readme.splitlines()[0].startswith("# machine: ")
    assert all(f"`{p.name}`" in readme for p in SCENARIOS)
