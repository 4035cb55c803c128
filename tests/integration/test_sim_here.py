"""``ncgate sim FILE`` without ``--config`` finds the program where the user points, as
``check`` does, and a path given with ``--set`` is relative to the current folder."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.gateway.cli.main import main


@pytest.fixture
def here(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "A.nc").write_text("N1G1X10F600\nN2M30\n")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("name", ["work/A.nc", "work/A"])
def test_sim_runs_a_program_named_by_its_path(here: Path, name: str,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", name]) == 0
    out = capsys.readouterr().out
    assert "every program ended" in out and "P1           1" in out


def test_a_storage_folder_given_with_set_is_the_current_folders(
        here: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "A", "--set", "nc.storage.MP0=work"]) == 0
    assert "every program ended" in capsys.readouterr().out


def test_the_built_in_programs_still_run_by_name(here: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "PROG91"]) == 0  # no PROG91 here: the built-in storage's, its script
    assert "every program ended" in capsys.readouterr().out
