"""The dependency rules of STYLE.md, checked on the source: they fail when a rule breaks.

- interpreter: stdlib + lark; never plc, gateway or config.
- plc: stdlib only.
- config: stdlib only.
- only gateway/modbus*.py imports pymodbus; only gateway/canopen*.py imports canopen or can.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
STDLIB = set(sys.stdlib_module_names)


def imports_of(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
    return found


def modules(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


ALLOWED = {
    "interpreter": STDLIB | {"interpreter", "lark"},
    "plc": STDLIB | {"plc"},
    "config": STDLIB | {"config"},
}


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_what_it_may(package: str) -> None:
    offenders = {
        f"{path.relative_to(ROOT)}: {name}"
        for path in modules(package)
        for name in imports_of(path) - ALLOWED[package]
    }
    assert not offenders


def test_fieldbus_libraries_stay_in_their_adapters() -> None:
    for path in [p for pkg in ("gateway", "plc", "interpreter", "config") for p in modules(pkg)]:
        names = imports_of(path)
        if "pymodbus" in names:
            assert path.parent.name == "gateway" and path.name.startswith("modbus"), path
        if names & {"canopen", "can"}:
            assert path.parent.name == "gateway" and path.name.startswith("canopen"), path


def test_importing_the_interpreter_loads_no_other_package() -> None:
    code = (
        "import sys, interpreter.parser, interpreter.checker, interpreter.formatter;"
        "bad = [m for m in ('plc', 'gateway', 'config', 'pymodbus', 'canopen', 'can')"
        " if m in sys.modules]; print(bad); sys.exit(1 if bad else 0)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, check=False)
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_rule_checker_sees_a_violation(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("from gateway import cli\nimport plc.image as image\n")
    assert imports_of(bad) - ALLOWED["interpreter"] == {"gateway", "plc"}
