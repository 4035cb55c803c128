"""The program store keeps the latest version of each file: a program edited all shift long
does not pile up in memory, and an edit is what runs next."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from ncgate.config import load_config
from ncgate.errors import InputRefused
from ncgate.gateway import Gateway
from ncgate.gateway.cli.check import start_problems
from ncgate.gateway.programs import CheckedFile, ProgramStore
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.interpreter.diagnostics import ProgramSyntaxError
from ncgate.interpreter.nc110.dialect import CHILD_BYTES
from ncgate.interpreter.storage import file_version


def test_each_edit_replaces_the_version_kept(tmp_path: Path) -> None:
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n')
    store = ProgramStore(load_config(tmp_path / "ncgate.toml"))
    program = tmp_path / "A.nc"
    for i in range(20):
        program.write_text(f"N1E1={i}\nN2M30\n")
        os.utime(program, ns=(i * 10**9, i * 10**9))  # a new version, whatever the clock
        loaded = store.load("A", None, 1)
        assert loaded.lines[0] == f"N1E1={i}"
        assert store.load("A", None, 1) is loaded  # an unchanged file is not read again
    store.load("A", None, 2)  # checked for another process: a second entry
    assert len(store._cache) == 2


@pytest.mark.parametrize("blocks", [1, CHILD_BYTES // 10], ids=["small", "big"])
def test_a_version_checked_at_start_is_read_without_a_second_check(
        tmp_path: Path, blocks: int) -> None:
    """``run``'s start-up check hands the store the file versions it found no error in: the
    store reads such a version for its process without checking it again, in this process
    or (a big one) in a child, and checks any other process or version.  The file has an
    error that only a check finds, so a program read shows that no check ran."""
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n')
    store = ProgramStore(load_config(tmp_path / "ncgate.toml"))
    program = tmp_path / "A.nc"
    program.write_text("N1G1X10F0\n" + "N2G1X20F600\n" * blocks + "N3M30\n")  # F0: NC034
    version = file_version(program)
    store.add_checked([CheckedFile(program, version, 1)])
    for process in (1, 2):
        store.preload("A", process)  # a start's read: a big file is checked in a child
    assert store.load("A", None, 1).lines[0] == "N1G1X10F0"
    with pytest.raises(ProgramSyntaxError) as found:
        store.load("A", None, 2)
    assert [d.code.code for d in found.value.diagnostics] == ["NC034"]
    os.utime(program, ns=(version[0] + 10**9, version[0] + 10**9))  # edited since the check
    with pytest.raises(ProgramSyntaxError):
        store.load("A", None, 1)


async def test_runs_start_up_check_spares_the_autostart_a_second_check(tmp_path: Path) -> None:
    """With ``nc.autostart`` the main program was read and checked twice before ``run``
    served: by its start-up check, then by the autostart (2.5 s each for 3 MB).  The check's
    verdict, for the file's version, goes to the gateway's store: the autostart does not
    check it again.  Shown by an edit the version does not tell (same size, same time)
    that brings an error: checked again, the start would be refused."""
    main = tmp_path / "A.nc"
    main.write_text("N1G1X10F6000\nN2M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\nautostart = true\n[nc.storage]\nMP0 = "."\n'
        '[modbus]\nenabled = false\n[canopen]\nenabled = false\n')
    config = ncgate_test_config(tmp_path / "ncgate.toml")
    found = start_problems(config)
    version = file_version(main)
    assert found.checked == (CheckedFile(main, version, 1),)
    main.write_text("N1G1X10F0000\nN2M30\n")  # F0: NC034
    os.utime(main, ns=(version[0], version[0]))
    async with Gateway(config, checked=found.checked) as gw:
        assert [e["prog"] for e in gw.trace if e["event"] == "start"] == ["A"]
    with pytest.raises(InputRefused, match="NC034"):
        async with Gateway(config):
            pass
