"""A session driven over Modbus, recorded (``run --record`` / ``Gateway(record=...)``), replayed
on the virtual clock (``sim --replay``, the kit's ``replay``): it matches; a changed program
diverges at the block that changed."""

from __future__ import annotations

import json
import shutil
from importlib import resources
from pathlib import Path

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.cli.main import main
from ncgate.gateway.record import COMPARED, read_record
from ncgate.gateway.record import replay as run_replay
from ncgate.gateway.testing import replay
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    """The built-in cell as a user's folder: ncgate.toml and its programs, 50x faster."""
    programs = tmp_path / "programs"
    programs.mkdir()
    for name in ("PROG91.nc", "PROG92.nc", "PROG93.nc"):
        shutil.copy(Path(str(resources.files("ncgate.config").joinpath("programs", name))),
                    programs)
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nmain = "PROG91"\ntime_scale = 50.0\n'
                      '[nc.storage]\nMP0 = "programs"\n')
    return config


async def record_session(config: Path, record: Path) -> None:
    """A commissioning engineer's session: cycle start and SA10 from a PLC over Modbus."""
    overrides = {"modbus.port": 0}
    cfg = ncgate_test_config(config, **overrides)
    async with Gateway(cfg, record=record, overrides=overrides) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        await plc.command(1)
        await plc.wait_state(2, "WAIT_COND")
        await plc.set("SA10", 1)
        await gw.wait_idle(timeout_s=30)


async def test_a_recorded_session_replays_and_matches(cell: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    record = tmp_path / "session.jsonl"
    await record_session(cell, record)
    recording = read_record(record)
    assert recording.header["config"] == str(cell)
    assert set(recording.header["programs"]) == {
        str((cell.parent / "programs" / n).resolve()) for n in
        ("PROG91.nc", "PROG92.nc", "PROG93.nc")}
    kinds = [(i["input"], i.get("word"), i.get("changes")) for i in recording.inputs]
    assert kinds == [("command", 1, None), ("write", None, [["SA", 10, "bit", 1]])]
    assert all(i["who"].startswith("modbus 127.0.0.1:") for i in recording.inputs)
    assert recording.stop is not None
    assert recording.events[-1]["event"] == "end"

    result = run_replay(record)
    assert result.divergence is None and result.warnings == []
    assert result.compared == sum(1 for e in recording.events
                                  if e["proc"] and e["event"] in COMPARED)
    assert result.compared > 30

    assert main(["sim", "--replay", str(record)]) == 0
    out = capsys.readouterr().out
    assert f"the replay matches: {result.compared} events" in out

    replay(record)  # the kit's helper: a field session as a regression test


async def test_a_changed_program_diverges_at_the_changed_block(
        cell: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    record = tmp_path / "session.jsonl"
    await record_session(cell, record)
    prog92 = cell.parent / "programs" / "PROG92.nc"
    prog92.write_text(prog92.read_text().replace("N40(WAI,SA10=1)", "N40(WAI,SA11=1)"))

    assert main(["sim", "--replay", str(record)]) == 1
    captured = capsys.readouterr()
    assert f"warning: {prog92.resolve()}: changed since the recording" in captured.err
    assert "replay diverges at P2's event 2:" in captured.out
    assert 'recorded: t=' in captured.out
    assert ('wait at PROG92.nc:8 N40 (on {"cond": "SA10=1", "value": 0})'
            in captured.out)
    assert 'wait at PROG92.nc:8 N40 (on {"cond": "SA11=1", "value": 0})' in captured.out
    with pytest.raises(AssertionError, match="replay diverges at P2's event 2"):
        replay(record)


async def test_a_slower_move_diverges_by_time_beyond_the_tolerance(
        cell: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    record = tmp_path / "session.jsonl"
    await record_session(cell, record)
    prog93 = cell.parent / "programs" / "PROG93.nc"
    prog93.write_text(prog93.read_text().replace("N30G1X0Y0", "N30G1X0Y0F150"))
    result = run_replay(record)
    assert result.divergence is not None
    # The SND at N80 acts at decode time (look-ahead): the first to come later is the end,
    # which waits for the motion.
    assert "replay diverges at P3's event 8:" in result.divergence
    assert 'end at PROG93.nc:11 N95 (how "REL")' in result.divergence
    assert "ms apart" in result.divergence
    # With a tolerance wider than the delay, the same events in the same order match.
    late = [float(line.split("t=")[1].split()[0])
            for line in result.divergence.splitlines()[1:3]]
    assert late[1] > late[0]
    # Every later event of P1 and P3 waits for that SND: two cycles, twice the delay.
    wide = 2 * (late[1] - late[0]) * 1000 + 50
    assert main(["sim", "--replay", str(record), "--tolerance-ms", str(wide)]) == 0
    assert f"within {wide:g} ms" in capsys.readouterr().out


async def test_a_record_cut_by_a_kill_replays_up_to_its_last_whole_line(
        cell: Path, tmp_path: Path) -> None:
    record = tmp_path / "session.jsonl"
    await record_session(cell, record)
    lines = record.read_text().splitlines(keepends=True)
    # No stop line (the process was killed) and half a line at the end.
    cut = lines[:len(lines) // 2]
    cut_text = "".join(cut[:-1]) + cut[-1][: len(cut[-1]) // 2]
    record.write_text(cut_text)
    recording = read_record(record)
    assert recording.stop is None
    assert len(recording.events) + len(recording.inputs) == len(cut) - 2
    result = run_replay(record)
    assert result.divergence is None, result.divergence


@pytest.mark.parametrize(("text", "said"), [
    ("", "empty"),
    ('{"seq": 1}\n', "not an ncgate session record"),
    ('{"ncgate_record": 1}\nnot json\n{"stop": 1}\n', ":2: not a JSON line"),
    ('{"ncgate_record": 1}\n{"what": 1}\n', ":2: neither an input"),
])
def test_a_file_that_is_not_a_record_is_a_usage_error(
        tmp_path: Path, text: str, said: str, capsys: pytest.CaptureFixture[str]) -> None:
    record = tmp_path / "r.jsonl"
    record.write_text(text)
    assert main(["sim", "--replay", str(record)]) == 2
    assert said in capsys.readouterr().err


def test_replay_goes_without_a_program_or_a_script(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    record = tmp_path / "r.jsonl"
    record.write_text(json.dumps({"ncgate_record": 1}) + "\n")
    assert main(["sim", "PROG91", "--replay", str(record)]) == 2
    assert "--replay takes its programs" in capsys.readouterr().err
