"""docs/testing.md is the test kit's reference (issue 25, item 17): every fixture of the plugin
with whether it is sync or async, and every public helper with its signature as Python
states it -- a helper added or changed without its line here fails."""

from __future__ import annotations

import ast
import inspect
from collections.abc import Callable
from typing import Any

import pytest

import ncgate.gateway.testing as testing
from ncgate.gateway.canopen.clock import ManualClock
from ncgate.gateway.testing import pytest_plugin
from ncgate.gateway.testing.canopen_kit import CanopenMaster
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.plc_kit import PlcWatch

from .conftest import ROOT

DOC = (ROOT / "docs" / "testing.md").read_text(encoding="utf-8").replace("\\|", "|")


def signature(name: str, fn: Callable[..., Any], constructor: bool = False) -> str:
    """``async VirtualPLC.wait_state(process: int, ...) -> None``, as the page writes it."""
    text = str(inspect.signature(fn)).replace("'", "")
    text = text.replace("(self, ", "(").replace("(self)", "()")
    if constructor:
        text = text.removesuffix(" -> None")
    return ("async " if inspect.iscoroutinefunction(fn) else "") + name + text


def helpers() -> list[str]:
    lines = [signature("ncgate_test_config", pytest_plugin.ncgate_test_config),
             signature("replay", testing.replay),
             signature("ncgate_sweep", testing.ncgate_sweep)]
    for cls in (VirtualPLC, CanopenMaster, PlcWatch, ManualClock):
        lines.append(signature(cls.__name__, cls.__init__, constructor=True))
        lines += [signature(f"{cls.__name__}.{name}", fn) for name, fn in vars(cls).items()
                  if callable(fn) and not name.startswith("_")]
    return lines


@pytest.mark.parametrize("line", helpers())
def test_every_helper_is_in_docs_testing_md_with_its_signature(line: str) -> None:
    assert f"`{line}`" in DOC


def fixtures() -> list[tuple[str, bool]]:
    """(name, async) of every public fixture the plugin defines."""
    tree = ast.parse(inspect.getsource(pytest_plugin))
    found = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and any(
                "fixture" in ast.unparse(d) for d in node.decorator_list) \
                and not node.name.startswith("_"):
            found[node.name] = found.get(node.name, False) or isinstance(node,
                                                                         ast.AsyncFunctionDef)
    return sorted(found.items())


@pytest.mark.parametrize(("name", "is_async"), fixtures())
def test_every_fixture_is_in_docs_testing_md_as_sync_or_async(name: str,
                                                              is_async: bool) -> None:
    (row,) = [line for line in DOC.splitlines() if line.startswith(f"| `{name}` |")]
    assert row.split("|")[2].strip().startswith("async" if is_async else "sync")


def test_the_page_names_each_import_path() -> None:
    for where in ("from ncgate.gateway.testing.pytest_plugin import ncgate_test_config",
                  "from ncgate.gateway.testing.modbus_kit import VirtualPLC",
                  "from ncgate.gateway.testing.canopen_kit import CanopenMaster",
                  "from ncgate.gateway.testing.plc_kit import PlcWatch",
                  "from ncgate.gateway.canopen.clock import ManualClock",
                  "from ncgate.gateway.testing import replay",
                  "from ncgate.gateway.testing import ncgate_sweep"):
        assert where in DOC
