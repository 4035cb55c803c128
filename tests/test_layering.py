"""The dependency rules of ARCHITECTURE.md, checked on the source: they fail when a rule breaks.

- everything is imported as ``ncgate.…``: no top-level ``config``, ``plc``, ``gateway`` or
  ``interpreter`` (they install as sub-packages of ``ncgate``);
- interpreter: stdlib + lark (+ ``ncgate.errors``); never plc, gateway or config; its engine
  imports no dialect's front end;
- plc: stdlib + lark, for its Structured Text compiler (+
  ``ncgate.errors``, and ``ncgate.commands``, the command table its NC outputs give words
  of); config: stdlib (+ ``ncgate.errors``) and ``ncgate.interpreter.settings``, and
  cryptography to read certificates;
- ``ncgate.commands`` and ``ncgate.errors`` are leaves: the standard library only;
- inside gateway: only ``modbus/`` (and the test kit's Modbus client) imports pymodbus, only
  ``canopen/`` (and the test kit's CANopen master) imports canopen or can, only ``rtu/``
  imports pyserial, only ``web/`` imports
  aiohttp (and the gateway imports ``web/`` only when a console is served), only ``opcua/``
  imports asyncua; only ``sweep/`` imports dask, distributed or pyarrow, each when used; the
  CLI and the
  test kit are leaves that nothing else in the gateway imports;
- a dialect is one folder: outside ``interpreter/<dialect>/`` and the registry
  (``interpreter/dialects.py``) nothing imports a dialect's package or branches on a member of
  ``Dialect``.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from ncgate.interpreter.dialects import dialect_of
from ncgate.interpreter.settings import Dialect

ROOT = Path(__file__).resolve().parent.parent
STDLIB = set(sys.stdlib_module_names)
# Source folder -> the package it installs as: pyproject.toml's package-dir, the one list of
# them (setuptools finds the sub-packages under each; dev.py's type-check tree reads it too).
PACKAGES = {folder: package for package, folder in tomllib.loads(
    (ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"].items()}
# The folders that would shadow a generic top-level name if they installed as themselves.
GENERIC = set(PACKAGES) - {"ncgate"}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = [PACKAGES[rel.parts[0]], *rel.parts[1:]]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path, module: str | None = None) -> set[str]:
    """The full names a file imports (relative imports resolved against ``module``)."""
    tree = ast.parse(path.read_text(), str(path))
    package = (module or "").rsplit(".", 1)[0] if path.name != "__init__.py" else module or ""
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            found.add(base)
    return found


def sources(folder: str) -> list[Path]:
    return sorted((ROOT / folder).rglob("*.py"))


def allowed(name: str, prefixes: set[str]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


RULES = {
    "interpreter": STDLIB | {"lark", "ncgate.interpreter", "ncgate.errors"},
    # The PLC's NC outputs give command words: named by the one command table, a leaf.
    "plc": STDLIB | {"lark", "ncgate.plc", "ncgate.errors", "ncgate.commands"},
    # The config names the engine's choices (the SND policy), defined once in its leaf module.
    "config": STDLIB | {"ncgate.config", "ncgate.errors", "ncgate.interpreter.settings",
                        # The OPC UA server's certificates, checked as the TLS files are (with
                        # ssl): a bad one is the config's error, naming its key.
                        "cryptography"},
}


@pytest.mark.parametrize("folder", sorted(RULES))
def test_package_imports_only_what_it_may(folder: str) -> None:
    offenders = {
        f"{path.relative_to(ROOT)}: {name}"
        for path in sources(folder)
        for name in imports_of(path, module_name(path))
        if not (allowed(name, RULES[folder]) or name.split(".")[0] in STDLIB)
    }
    assert not offenders


# Leaves under every layer: they import the standard library only.
LEAVES = ("ncgate/errors.py", "ncgate/commands.py")


@pytest.mark.parametrize("leaf", LEAVES)
def test_the_leaves_import_only_the_standard_library(leaf: str) -> None:
    path = ROOT / leaf
    assert {n for n in imports_of(path, module_name(path))
            if n.split(".")[0] not in STDLIB} == set()


def test_nothing_imports_the_generic_top_level_names() -> None:
    offenders = {
        f"{path.relative_to(ROOT)}: {name}"
        for folder in {*PACKAGES, "tests", "bench", "examples"}
        for path in sources(folder)
        for name in imports_of(path)
        if name.split(".")[0] in GENERIC
    }
    assert not offenders


def gateway_modules() -> dict[str, set[str]]:
    return {module_name(p): imports_of(p, module_name(p)) for p in sources("gateway")}


def test_fieldbus_libraries_stay_in_their_adapters() -> None:
    kit = "ncgate.gateway.testing"
    for module, names in gateway_modules().items():
        tops = {n.split(".")[0] for n in names}
        if "pymodbus" in tops:
            assert module.startswith("ncgate.gateway.modbus.") or module == f"{kit}.modbus_kit"
        if tops & {"canopen", "can", "can_remote"}:
            assert (module.startswith("ncgate.gateway.canopen.")
                    or module == f"{kit}.canopen_kit"), module
        if "aiohttp" in tops:
            assert module.startswith("ncgate.gateway.web."), module
        if "asyncua" in tops:
            assert module.startswith("ncgate.gateway.opcua."), module
        if "serial" in tops:  # pyserial
            assert module.startswith("ncgate.gateway.rtu."), module
        if tops & {"dask", "distributed", "pyarrow"}:
            assert module.startswith("ncgate.gateway.sweep."), module


def test_a_sweep_loads_dask_and_pyarrow_only_when_asked() -> None:
    """A local CSV sweep runs without the extras: the cluster and Parquet load on use."""
    code = ("import sys; import ncgate.gateway.cli.main, ncgate.gateway.sweep.main, "
            "ncgate.gateway.sweep.pool, ncgate.gateway.sweep.table, ncgate.gateway.sweep.cluster\n"
            "bad = [m for m in ('dask', 'distributed', 'pyarrow') if m in sys.modules]\n"
            "sys.exit(f'loaded: {bad}' if bad else 0)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_only_the_cli_imports_the_sweep() -> None:
    for module, names in gateway_modules().items():
        if not module.startswith(("ncgate.gateway.cli", "ncgate.gateway.sweep",
                                  "ncgate.gateway.testing")):
            assert not any(allowed(n, {"ncgate.gateway.sweep"}) for n in names), module


def test_a_gateway_without_console_does_not_load_the_web_library() -> None:
    """The API and the tests run without a console: aiohttp is loaded only to serve one."""
    code = ("import sys, asyncio; from ncgate.gateway import Gateway\n"
            "async def main():\n"
            "    async with Gateway() as gw: pass\n"
            "asyncio.run(main()); sys.exit(1 if 'aiohttp' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def test_a_cell_without_plc_logic_does_not_load_the_st_toolchain() -> None:
    """The ST parser, compiler and PLCopen reader (10 MB resident) load when a cell has
    logic to compile, not for every gateway (bench/modbus.py 3.: `run`'s memory)."""
    code = ("import sys, asyncio; from ncgate.gateway import Gateway\n"
            "async def main():\n"
            "    async with Gateway() as gw: pass\n"
            "asyncio.run(main())\n"
            "heavy = [m for m in ('ncgate.plc.st.compiler', 'ncgate.plc.st.parser', "
            "'ncgate.plc.st.plcopen') if m in sys.modules]\n"
            "sys.exit(f'loaded: {heavy}' if heavy else 0)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_the_cli_and_the_test_kit_are_leaves() -> None:
    for module, names in gateway_modules().items():
        for leaf in ("ncgate.gateway.cli", "ncgate.gateway.testing"):
            if not module.startswith(leaf):
                assert not any(allowed(n, {leaf}) for n in names), (module, leaf)


def test_the_engine_knows_no_dialect() -> None:
    """A dialect's front end talks to the engine through engine.ports: the engine imports no
    front end, so a new dialect is a new folder beside nc110/."""
    for path in sources("interpreter/engine"):
        names = imports_of(path, module_name(path))
        assert not any(allowed(n, {"ncgate.interpreter.nc110", "ncgate.interpreter.isg"})
                       for n in names), path


def test_the_dialects_share_only_the_span() -> None:
    """The ISG front end is a sibling of nc110/, not a variant of it: it takes nothing of the
    NC-110 front end but the Span every diagnostic carries (nc110.nodes), and NC-110 nothing
    of it."""
    for path in sources("interpreter/isg"):
        names = imports_of(path, module_name(path))
        assert {n for n in names if allowed(n, {"ncgate.interpreter.nc110"})} <= {
            "ncgate.interpreter.nc110.nodes"}, path
    for path in sources("interpreter/nc110"):
        assert not any(allowed(n, {"ncgate.interpreter.isg"})
                       for n in imports_of(path, module_name(path))), path


# A dialect is one folder (ARCHITECTURE.md, "Where a new dialect goes"): only its folder and
# the registry name it; everything else asks the registry for a DialectPlugin.
DIALECT_PACKAGES = {f"ncgate.interpreter.{d.value}" for d in Dialect}
REGISTRY = ROOT / "interpreter" / "dialects.py"


def dialect_mentions(path: Path, module: str | None = None) -> set[str]:
    """Where a file names a dialect: an import of a dialect's package, a ``Dialect.<MEMBER>``
    compared, matched or used as a key, or a comparison with a dialect's name (``== "isg"``)."""
    tree = ast.parse(path.read_text(), str(path))
    found = {f"imports {n}" for n in imports_of(path, module) if allowed(n, DIALECT_PACKAGES)}

    def member(node: ast.AST | None) -> bool:
        return (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id == "Dialect" and node.attr in Dialect.__members__)

    def name(node: ast.AST | None) -> bool:
        return (isinstance(node, ast.Constant)
                and node.value in {d.value for d in Dialect} | set(Dialect.__members__))

    for node in ast.walk(tree):
        tested: list[ast.AST | None] = []
        if isinstance(node, ast.Compare):
            tested = [node.left, *node.comparators]
        elif isinstance(node, ast.MatchValue):
            tested = [node.value]
        elif isinstance(node, ast.Dict):
            tested = list(node.keys)
        for operand in tested:
            if member(operand) or (not isinstance(node, ast.Dict) and name(operand)):
                found.add(f"line {node.lineno}: {ast.unparse(operand)}")
    return found


def test_only_a_dialects_folder_and_the_registry_name_it() -> None:
    """Outside ``interpreter/<dialect>/`` and ``interpreter/dialects.py`` nothing imports a
    dialect's package or branches on a member of ``Dialect``: the gateway, the CLI and the
    simulator ask ``dialects.dialect_of(...)``, so a new dialect is its folder and its line in
    ``Dialect``."""
    folders = {ROOT / "interpreter" / d.value for d in Dialect}
    offenders = {
        f"{path.relative_to(ROOT)}: {mention}"
        for folder in PACKAGES
        for path in sources(folder)
        if path != REGISTRY and not any(path.is_relative_to(f) for f in folders)
        for mention in dialect_mentions(path, module_name(path))
    }
    assert not offenders


def test_every_dialect_is_registered_by_its_folder() -> None:
    """Each member of ``Dialect`` is found in its folder, and that folder is a package (so it
    is packaged: tests/test_packaging.py checks that every package reaches the wheel)."""
    for member in Dialect:
        plugin = dialect_of(member)
        assert plugin.name is member and dialect_of(member.value) is plugin
        assert (ROOT / "interpreter" / member.value / "dialect.py").is_file()
        assert (ROOT / "interpreter" / member.value / "__init__.py").is_file(), member


def test_the_dialect_rule_sees_a_violation(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("from ncgate.interpreter.isg.parser import IsgFile\n"
                   "from ncgate.interpreter.settings import Dialect\n"
                   "if config.nc.dialect is Dialect.ISG: pass\n"
                   "if name == 'nc110': pass\n"
                   "table = {Dialect.NC110: 1}\n"
                   "match d:\n    case Dialect.ISG: pass\n"
                   "default = Dialect.NC110  # a default is no branch\n")
    assert dialect_mentions(bad, "ncgate.gateway.bad") == {
        "imports ncgate.interpreter.isg.parser", "line 3: Dialect.ISG", "line 4: 'nc110'",
        "line 5: Dialect.NC110", "line 7: Dialect.ISG"}


def test_importing_the_interpreter_loads_no_other_package() -> None:
    code = (
        "import sys, ncgate.interpreter.nc110.parser, ncgate.interpreter.nc110.checker,"
        " ncgate.interpreter.nc110.formatter, ncgate.interpreter.nc110.compiler,"
        " ncgate.interpreter.engine;"
        "bad = [m for m in ('ncgate.plc', 'ncgate.gateway', 'ncgate.config', 'pymodbus',"
        " 'canopen', 'can') if m in sys.modules]; print(bad); sys.exit(1 if bad else 0)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, check=False)
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_rule_checker_sees_a_violation(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("from ncgate.gateway import cli\nimport ncgate.plc.image as image\n"
                   "from config import load_config\nfrom ..plc import image\n")
    names = imports_of(bad, "ncgate.interpreter.bad")
    assert {n for n in names if not allowed(n, RULES["interpreter"])} == {
        "ncgate.gateway", "ncgate.plc.image", "config", "ncgate.plc"}


def test_the_architecture_box_names_every_module_and_folder_of_the_gateway() -> None:
    """ARCHITECTURE.md's layer box is the map of ``ncgate.gateway``: a module or sub-package
    added without its place on the map fails here (stdout.py once came in unnamed)."""
    text = (ROOT / "ARCHITECTURE.md").read_text(encoding="utf-8")
    start = text.index("ncgate.gateway: the composition root")
    box = text[start:text.index("└", start)]
    gateway = ROOT / "gateway"
    names = [p.name for p in gateway.glob("*.py") if p.name != "__init__.py"]
    names += [f"{p.name}/" for p in gateway.iterdir()
              if p.is_dir() and (p / "__init__.py").is_file()]
    assert [name for name in sorted(names) if name not in box] == []
