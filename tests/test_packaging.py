"""ncgate as users install it: one import package, the examples inside, a plugin that never
breaks a foreign test run, a version."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

import ncgate
from ncgate.gateway.cli.main import main

ROOT = Path(__file__).resolve().parent.parent


# pyproject.toml's package-dir: each package ncgate installs and the source folder it comes from.
PACKAGE_DIR: dict[str, str] = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"][
    "setuptools"]["package-dir"]
# Added to the copy the wheel is built from, as the next sub-package or an example's sub-folder
# arrives: nothing lists them, and the wheel must take them all the same.
NEWCOMERS = {"gateway/newcomer/__init__.py": "", "gateway/newcomer/inner/__init__.py": "",
             "gateway/newcomer/inner/part.py": "PART = 1\n",
             "examples/scheme3/newcomer/EXTRA.nc": "%EXTRA\nM30\n"}


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the files git knows (as a clone has them), and the NEWCOMERS: the build
    writes its own build/ and *.egg-info, which belong in no work tree."""
    source = tmp_path_factory.mktemp("source")
    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT,
                            capture_output=True, check=True).stdout.decode().split("\0")
    for name in filter(None, listed):
        if (ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    for name, text in NEWCOMERS.items():
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        (source / name).write_text(text)
    return source


@pytest.fixture(scope="module")
def wheel(source: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                    "--no-build-isolation", "-w", str(out), str(source)], check=True,
                   capture_output=True)
    (built,) = out.glob("ncgate-*.whl")
    return built


def installed_name(source: Path, path: Path) -> str:
    """Where a file of a source folder lands in the wheel (package-dir's mapping)."""
    for package, folder in PACKAGE_DIR.items():
        if path.is_relative_to(source / folder):
            return "/".join([*package.split("."), *path.relative_to(source / folder).parts])
    raise AssertionError(f"{path} is in no folder of package-dir")


def test_every_package_and_example_file_is_in_the_wheel(source: Path, wheel: Path) -> None:
    """Every folder with an __init__.py under a source folder, each of its modules, and every
    file of the examples reach the wheel, the NEWCOMERS too: package-dir is the one list, and
    a new sub-package (gateway/plant/) or an example's sub-folder needs no pyproject edit."""
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = [path for folder in PACKAGE_DIR.values()
               for init in (source / folder).rglob("__init__.py")
               for path in init.parent.glob("*.py")]
    shipped += [path for path in (source / PACKAGE_DIR["ncgate.examples"]).rglob("*")
                if path.is_file()]
    assert {source / name for name in NEWCOMERS} <= set(shipped)
    expected = sorted(installed_name(source, path) for path in shipped)
    assert [name for name in expected if name not in names] == []


def test_the_wheel_holds_one_top_level_package_with_its_data(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} == {"ncgate", f"ncgate-{ncgate.__version__}.dist-info"}
    for needed in ("ncgate/gateway/cli/main.py", "ncgate/config/default.toml",
                   "ncgate/config/programs/PROG91.nc",
                   "ncgate/interpreter/nc110/grammar/nc110.lark",
                   "ncgate/examples/scheme3/PROG91.nc", "ncgate/examples/scheme3/script.toml",
                   "ncgate/examples/errors/README.md", "ncgate/py.typed",
                   "ncgate/plc/st/grammar/st.lark", "ncgate/examples/plclogic/plc.st",
                   "ncgate/interpreter/isg/signals.py", "ncgate/examples/isg_ve/VE.nc",
                   "ncgate/gateway/web/static/index.html", "ncgate/gateway/web/static/app.js",
                   "ncgate/gateway/web/static/style.css"):
        assert needed in names


def test_installed_it_shadows_no_generic_module(wheel: Path, tmp_path: Path) -> None:
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target",
                    str(target), str(wheel)], check=True, capture_output=True)
    assert {p.name for p in target.iterdir()} - {"bin"} == {
        "ncgate", f"ncgate-{ncgate.__version__}.dist-info"}
    env = {**os.environ, "PYTHONPATH": str(target)}

    def python(code: str) -> subprocess.CompletedProcess[str]:
        # -P: not the current folder first on the path (ours is an empty one anyway)
        return subprocess.run([sys.executable, "-P", "-c", code], cwd=tmp_path, env=env,
                              capture_output=True, text=True, check=False)

    for generic in set(PACKAGE_DIR.values()) - {"ncgate"}:
        done = python(f"import {generic}")
        assert "ModuleNotFoundError" in done.stderr, generic
    done = python("import ncgate, ncgate.gateway; print(ncgate.__file__); "
                  "from ncgate import Gateway, load_config; "
                  "print(load_config(None).nc.main, Gateway.__name__)")
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == [str(target / "ncgate" / "__init__.py"), "PROG91 Gateway"]
    done = python("import sys; sys.argv = ['ncgate', 'sim', '--example', 'mutual'];"
                  "import runpy; runpy.run_module('ncgate', run_name='__main__')")
    assert "every program ended" in done.stdout, done.stderr


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"ncgate {ncgate.__version__}"
    from importlib.metadata import version

    assert version("ncgate") == ncgate.__version__


USER_SUITE = {
    # A user's own modules with the names ncgate once took over.
    "config.py": "def load_config():\n    return 'the user config'\n",
    "plc.py": "NAME = 'the user plc'\n",
    "test_mine.py": (
        "from config import load_config\nimport plc\n\n"
        "def test_mine():\n    assert load_config() == 'the user config'\n"
        "    assert plc.NAME == 'the user plc'\n\n"
        "def test_asks_for_the_gateway(ncgate_gateway):\n    pass\n"
    ),
}


def test_the_plugin_never_breaks_a_foreign_suite(tmp_path: Path) -> None:
    """A user's config.py and plc.py, and no pytest-asyncio: their tests still run; only the
    one that asks for an ncgate fixture fails, saying what to install."""
    for name, text in USER_SUITE.items():
        (tmp_path / name).write_text(text)
    blocker = tmp_path / "blocker"
    blocker.mkdir()
    (blocker / "pytest_asyncio.py").write_text("raise ImportError('not installed here')\n")
    env = {**os.environ, "PYTHONPATH": str(blocker)}
    # -p no:asyncio: pytest-asyncio's own plugin is absent too, as it would be
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p",
                           "no:asyncio",
                           "-c", os.devnull, "--rootdir", str(tmp_path), str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, check=False)
    assert "1 passed" in done.stdout and "1 error" in done.stdout, done.stdout + done.stderr
    assert "pip install 'ncgate[pytest]'" in done.stdout


def test_examples_are_listed_and_run(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["examples"]) == 0
    listed = capsys.readouterr().out.splitlines()
    assert [line.split()[:2] for line in listed] == [
        ["commissioning", "PROG91"], ["conditional", "COND1"], ["errors", "-"],
        ["hazard", "HAZ1"],
        ["isg_dec_interp", "DECINT"],
        ["isg_decoders", "DECODERS"], ["isg_flush", "FLUSH"], ["isg_no_flush", "NOFLUSH"],
        ["isg_params", "PARAMS"], ["isg_paths", "PATHS"], ["isg_ve", "VE"],
        ["isg_waits", "WAITS"], ["machine", "PART"], ["mutual", "MUT1"], ["plclogic", "PROG91"],
        ["scheme3", "PROG91"], ["section4", "PR90"]]
    assert main(["sim", "--example", "scheme3"]) == 0
    assert "every program ended" in capsys.readouterr().out
    assert main(["check", "--example", "errors"]) == 1
    assert main(["sim", "--example", "errors"]) == 2
    assert main(["sim", "--example", "nowhere"]) == 2
    assert "no example 'nowhere'" in capsys.readouterr().err


def test_nothing_in_the_repository_reaches_outside_it() -> None:
    """Users' clones have only the repository: no file may point at a folder beside it."""
    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout.split()
    outside = "../" + "shared"  # spelled apart so that this test does not find itself
    offenders = [name for name in listed if (ROOT / name).is_file()
                 and outside in (ROOT / name).read_text(errors="replace")]
    assert not offenders
