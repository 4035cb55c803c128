"""Issue 9.4, 9.6, 9.7: what `ncgate sim` reports -- the verdict after alarms, the hazards of
plain syncs that overtake queued motion, several programs in their own processes, Ctrl-C."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway import sim as sim_module
from ncgate.gateway.cli.main import main
from ncgate.gateway.sim import run_sim
from ncgate.interpreter.engine import Engine, run_virtual

from ..conftest import EXAMPLES
from ..helpers import write_cell

EXAMPLE_MAINS = [("conditional", "COND1"), ("mutual", "MUT1"), ("scheme3", "PROG91"),
                 ("section4", "PR90")]


def sim_example(folder: str, main_program: str, **overrides: Any) -> list[dict[str, Any]]:
    config = load_config(EXAMPLES / folder / "ncgate.toml", overrides=overrides)
    script_path = EXAMPLES / folder / "script.toml"
    result = run_sim(config, main_program, load_script(script_path if script_path.exists()
                                                       else None))
    assert result.exit_status == 0
    return result.events


@pytest.mark.parametrize(("folder", "main_program"), EXAMPLE_MAINS)
def test_the_shipped_examples_run_as_narrated_with_no_hazard(folder: str,
                                                             main_program: str) -> None:
    events = sim_example(folder, main_program)
    assert [e for e in events if e["event"] == "hazard"] == []


def test_the_mutual_example_as_shipped_meets_after_the_longest_motion() -> None:
    events = sim_example("mutual", "MUT1")
    releases = {e["t"] for e in events if e["event"] == "snd" and e["proc"] == 1}
    assert releases == {3.0}  # P3's 10 mm at 200 mm/min come first, as the README says


def test_with_lookahead_every_plain_sync_behind_queued_motion_is_a_hazard() -> None:
    events = sim_example("mutual", "MUT1", **{"nc.lookahead": 16})
    hazards = {(e["proc"], e["n"]): e["message"] for e in events if e["event"] == "hazard"}
    # MUT1 N108/N109 (WAI) and N110/N111 (SND) behind N107's move; MUT2 N231/N232 behind
    # N230; MUT3 N331/N332 behind N330.
    assert set(hazards) == {(1, 108), (1, 109), (1, 110), (1, 111), (2, 231), (2, 232),
                            (3, 331), (3, 332)}
    assert hazards[(1, 108)].startswith("(WAI,2) acted at decode time while motion programmed "
                                        "above it (N107) was still queued; mark the block #")


def test_a_hash_block_and_lookahead_0_are_no_hazard(tmp_path: Path) -> None:
    program = "N1G1X10F600\nN2#(SND,2)\nN3#SYVAR1=1\nN4M30\n"
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n',
               {"A": "N0(EXE,2,B)\n" + program, "B": "N1(WAI,1)\nN2M30\n"})
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "A", load_script(None))
    assert result.exit_status == 0
    assert [e for e in result.events if e["event"] == "hazard"] == []
    plain = "N0(EXE,2,B)\nN1G1X10F600\nN2(SND,2)\nN3SYVAR1=1\nN4M30\n"
    (tmp_path / "A.nc").write_text(plain)
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "A", load_script(None))
    assert [e["n"] for e in result.events if e["event"] == "hazard"] == [2, 3]
    result = run_sim(load_config(tmp_path / "ncgate.toml", overrides={"nc.lookahead": 0}),
                     "A", load_script(None))
    assert [e for e in result.events if e["event"] == "hazard"] == []


def test_the_summary_lists_each_hazard_once_with_its_count(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    program = '"L"\nN1G1X10F6000\nN2SYVAR1=E1\nN3G1X0\nN4E1=E1+1\nN5(BLT,E1,3,L)\nN6M30\n'
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n', {"A": program})
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 0
    out = capsys.readouterr().out
    hazard_lines = [line for line in out.splitlines() if " hazard " in line]
    assert hazard_lines == [
        "[0.000] P1 hazard A.nc:3 N2: SYVAR1=0 acted at decode time while motion programmed "
        "above it (N1) was still queued; mark the block # to act in motion order, or set "
        "nc.lookahead = 0",
        "[0.000] P1 hazard A.nc:3 N2: SYVAR1=1 acted at decode time while motion programmed "
        "above it (N1) was still queued; mark the block # to act in motion order, or set "
        "nc.lookahead = 0",
        "[0.000] P1 hazard A.nc:3 N2: SYVAR1=2 acted at decode time while motion programmed "
        "above it (N1) was still queued; mark the block # to act in motion order, or set "
        "nc.lookahead = 0",
    ]


def test_after_an_alarm_the_verdict_says_so_and_reports_no_stall(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n',
               {"A": "N1E1=0\nN2E2=1/E1\nN3M30\n"})
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"),
                 "--trace", str(tmp_path / "t.jsonl")]) == 1
    out = capsys.readouterr().out
    assert "stall" not in out
    assert out.rstrip().endswith("simulated 0.000 s: ended with alarms")
    events = [json.loads(line) for line in (tmp_path / "t.jsonl").read_text().splitlines()]
    assert [e["event"] for e in events if e["event"] in ("alarm", "stall")] == ["alarm"]


def test_a_stall_beside_an_alarm_names_only_the_blocked(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n',
               {"A": "N1(EXE,2,B)\nN2(WAI,SA1=1)\nN3M30\n", "B": "N1E1=1/0\n"})
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 1
    out = capsys.readouterr().out
    assert "P1 A.nc:2 N2 (WAI,SA1=1) waits for SA1=1 (now 0)" in out
    assert out.rstrip().endswith("simulated 0.000 s: stall, 1 alarm")


def test_several_programs_start_each_in_its_own_process(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, '[nc.storage]\nMP0 = "."\n', {
        "A": "N1(WAI,2)\nN2(WAI,3)\nN3M30\n",
        "B": "N1G1X6F600\nN2#(SND,1)\nN3M30\n",
        "C": "N1G1X12F600\nN2#(SND,1)\nN3M30\n",
    })
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"), "A", "B", "C",
                 "--trace", str(tmp_path / "t.jsonl")]) == 0
    events = [json.loads(line) for line in (tmp_path / "t.jsonl").read_text().splitlines()]
    starts = [(e["proc"], e["prog"], e["by"]) for e in events if e["event"] == "start"]
    assert starts == [(1, "A", "script"), (2, "B", "script"), (3, "C", "script")]
    assert [e["t"] for e in events if e["event"] == "end" and e["proc"] == 1] == [1.2]
    capsys.readouterr()
    # More programs than processes, or one for an external process: a usage error.
    (tmp_path / "ncgate.toml").write_text('[nc]\nprocesses = 2\n[nc.storage]\nMP0 = "."\n')
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"), "A", "B", "C"]) == 2
    assert "3 programs for 2 processes" in capsys.readouterr().err
    (tmp_path / "ncgate.toml").write_text('[nc.storage]\nMP0 = "."\n'
                                          '[[nc.process]]\nnumber = 2\nexternal = true\n')
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"), "A", "B"]) == 2
    assert "process 2 is external" in capsys.readouterr().err


def test_ctrl_c_still_reports_and_writes_the_trace(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\nblock_time_ms = 250\n[nc.storage]\nMP0 = "."\n',
               {"A": '"L"\nN1(DIS,"tick")\nN2(BNC,L)\n'})

    def interrupted(engine: Engine, until: float | None = None) -> str:
        run_virtual(engine, until=2.0)
        raise KeyboardInterrupt  # as Ctrl-C arrives in the middle of a run

    monkeypatch.setattr(sim_module, "run_virtual", interrupted)
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"),
                 "--trace", str(tmp_path / "t.jsonl")]) == 1
    assert capsys.readouterr().out.rstrip().endswith("simulated 2.000 s: interrupted (Ctrl-C)")
    lines = (tmp_path / "t.jsonl").read_text().splitlines()
    assert sum(json.loads(line)["event"] == "display" for line in lines) == 5  # 0 ... 2.0 s
