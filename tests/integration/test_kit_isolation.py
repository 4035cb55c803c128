"""The test kit as a user's own suite meets it (issue 25, items 16 and 17): a small suite of
tests written into ``tmp_path`` and run by pytest in a process of its own -- in turn, again,
and on two pytest-xdist workers at once.  What it checks: a test's RETAIN values and its
CANopen "save" end with the test (never the next test, never the next run), a config path is
relative to the test file, every port and channel is a worker's own, and the README's pytest
settings leave pytest-asyncio nothing to warn about."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from ..conftest import ROOT

CELL = {
    "ncgate.toml": '[nc]\nmain = "MAIN"\n[nc.storage]\nMP0 = "."\n[plc]\nlogic = "plc.st"\n',
    "MAIN.nc": "N1M30\n",
    # Counts the starts of the PLC in a RETAIN variable: 1 in a fresh test, more if a
    # former test's or run's values leaked in.
    "plc.st": ("PROGRAM cell\nVAR RETAIN\n  starts : UDINT;\nEND_VAR\nVAR\n  counted : BOOL;\n"
               "END_VAR\nIF NOT counted THEN\n  starts := starts + 1;\n  counted := TRUE;\n"
               "END_IF\nEND_PROGRAM\n"),
}

CONFTEST = '''
import pytest
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

@pytest.fixture
def ncgate_config(request):
    return ncgate_test_config("cell/ncgate.toml", **getattr(request, "param", {}))
'''

TEST_CELL = '''
async def test_retain_starts_from_its_initial_value(plc_watch):
    assert await plc_watch.until("cell.starts", test=lambda v: v >= 1) == 1

async def test_a_save_to_0x1010_is_kept_in_the_tests_folder(ncgate_gateway, canopen_master,
                                                            tmp_path):
    await canopen_master.download(0x1017, 0, (250).to_bytes(2, "little"))
    await canopen_master.download(0x1010, 1, b"save")
    assert ncgate_gateway.config.canopen.store_file.parent == tmp_path
    assert ncgate_gateway.config.canopen.store_file.exists()

async def test_a_fresh_gateway_has_the_default_heartbeat(canopen_master):
    assert await canopen_master.upload(0x1017, 0) == (1000).to_bytes(2, "little")
'''

# Under KIT_BARRIER (the -n 2 run), each worker's hub stays up until the other worker's is
# up too: with one fixed hub port the second could not start, and both would time out.
TEST_HUB = '''
import asyncio, os
from pathlib import Path
import pytest

@pytest.mark.parametrize("ncgate_config", [{"canopen.hub": True}], indirect=True)
async def test_the_hub_listens_on_a_port_of_its_own(ncgate_gateway):
    host, port = ncgate_gateway.canopen_node.hub_address
    barrier = os.environ.get("KIT_BARRIER")
    if barrier:
        folder = Path(barrier)
        (folder / os.environ["PYTEST_XDIST_WORKER"]).write_text(str(port))
        async with asyncio.timeout(30):
            # Another process's file: the only way to hear of it is to look.
            while len(list(folder.iterdir())) < 2:  # noqa: ASYNC110
                await asyncio.sleep(0.02)
    reader, writer = await asyncio.open_connection(host, port)
    writer.close()
    await writer.wait_closed()
'''


def readme_pytest_settings() -> str:
    """The README's ``[tool.pytest.ini_options]`` block, as a user copies it."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```toml\n(.*?)```", text, re.S)
    (block,) = [b for b in blocks if "[tool.pytest.ini_options]" in b]
    return block


def write_suite(folder: Path) -> Path:
    """A user's project: the README's pytest settings, tests/ with a conftest and a cell."""
    (folder / "tests" / "cell").mkdir(parents=True)
    (folder / "pyproject.toml").write_text(readme_pytest_settings())
    (folder / "tests" / "conftest.py").write_text(CONFTEST)
    (folder / "tests" / "test_cell.py").write_text(TEST_CELL)
    (folder / "tests" / "test_hub.py").write_text(TEST_HUB)
    for name, text in CELL.items():
        (folder / "tests" / "cell" / name).write_text(text)
    return folder


def files_of(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")
            if p.is_file() and "__pycache__" not in p.parts}


def run_suite(suite: Path, cwd: Path, basetemp: Path, *args: str,
              env: dict[str, str] | None = None) -> str:
    """pytest on the suite in a process of its own; its output, after it passed."""
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-rA",
         f"--rootdir={suite}", f"--basetemp={basetemp}", str(suite / "tests"), *args],
        cwd=cwd, capture_output=True, text=True, timeout=110,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1", **(env or {})})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout + proc.stderr


def test_retain_and_a_canopen_save_never_outlive_their_test(tmp_path: Path) -> None:
    suite = write_suite(tmp_path / "project")
    before = files_of(suite)
    for run in (1, 2):  # the second run starts where the first left the files
        out = run_suite(suite, suite / "tests", tmp_path / f"base{run}")
        assert "4 passed" in out
        # The README's settings say the loop scope: pytest-asyncio has nothing to warn.
        assert "PytestDeprecationWarning" not in out and "is unset" not in out
    assert files_of(suite) == before  # nothing beside the config, nothing in the folder run in


def test_a_relative_config_path_is_relative_to_the_test_file(tmp_path: Path) -> None:
    suite = write_suite(tmp_path / "project")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = run_suite(suite, elsewhere, tmp_path / "base", "-k", "retain")
    assert "1 passed" in out
    assert files_of(elsewhere) == set()


def test_the_kit_runs_on_two_xdist_workers_at_once(tmp_path: Path) -> None:
    suite = write_suite(tmp_path / "project")
    barrier = tmp_path / "barrier"
    barrier.mkdir()
    out = run_suite(suite, suite / "tests", tmp_path / "base", "-n", "2", "--dist", "each",
                    env={"KIT_BARRIER": str(barrier)})
    assert "8 passed" in out  # every test on each of the two workers
    assert {p.name for p in barrier.iterdir()} == {"gw0", "gw1"}
    assert len({p.read_text() for p in barrier.iterdir()}) == 2  # two hub ports


def test_two_configs_of_one_test_share_its_files(tmp_path: Path) -> None:
    first, second = ncgate_test_config(), ncgate_test_config()
    assert first.canopen.store_file == second.canopen.store_file == \
        tmp_path / "ncgate-canopen-node16.json"
    assert first.plc.retain_file == second.plc.retain_file == \
        tmp_path / "ncgate-plc-retain.sqlite"
    assert first.canopen.channel != second.canopen.channel
    assert first.canopen.hub_port == first.modbus.port == first.web.port == 0
