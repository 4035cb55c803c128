"""A session driven over Modbus, recorded (``run --record`` / ``Gateway(record=...)``), replayed
on the virtual clock (``sim --replay``, the kit's ``replay``): it matches; a changed program
diverges at the block that changed."""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import json
import shutil
import socket
import time
import types
from importlib import resources
from pathlib import Path

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.cli.main import main
from ncgate.gateway.errors import GatewayError
from ncgate.gateway.record import COMPARED, read_record
from ncgate.gateway.record import replay as run_replay
from ncgate.gateway.testing import replay, wait_event
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.inputs import Command, CommandKind, Var, Writes
from ncgate.interpreter.engine import events as ev

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


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


async def record_session(config: Path, record: Path, source: Path | None = None) -> None:
    """A commissioning engineer's session: cycle start and SA10 from a PLC over Modbus.
    ``source``: the config's name as `run` was given it (relative, from its folder)."""
    overrides = {"modbus.port": 0}
    cfg = ncgate_test_config(config, **overrides)
    if source is not None:
        cfg = dataclasses.replace(cfg, source=source)
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
    # The files the session used, and only those: the config, then each program it read.
    assert set(recording.header["files"]) == {str(cell)}
    assert set(recording.programs) == {
        str((cell.parent / "programs" / n).resolve()) for n in
        ("PROG91.nc", "PROG92.nc", "PROG93.nc")}
    inputs = [i.input for i in recording.inputs]
    assert inputs == [Command(CommandKind.CYCLE_START, None, inputs[0].source),
                      Writes(((Var("SA", 10, "bit"), 1),), inputs[1].source)]
    assert all(str(i.source).startswith("modbus 127.0.0.1:") for i in inputs)
    # Each input's line comes before the events it caused.
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    command = next(n for n, line in enumerate(lines) if line.get("input") == "command")
    first_start = next(n for n, line in enumerate(lines) if line.get("event") == "start")
    write = next(n for n, line in enumerate(lines) if line.get("input") == "write")
    sa10 = next(n for n, line in enumerate(lines)
                if line.get("event") == "write" and line["var"] == "SA10")
    assert command < first_start and write < sa10
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


async def test_the_machine_started_after_an_idle_gap_replays_and_matches(
        tmp_path: Path) -> None:
    """The machine example (PLC logic with TON timers, six plant models) stands idle, then a
    PLC's cycle start over Modbus machines one part.  The replay scans the PLC logic and runs
    the plant through the idle gap on their grids, as the session did: no alarm of a TON that
    saw the clock leap at the start, every event in time (the coolant's pressure, sampled on
    the plant's grid and read on the PLC's, decides when N70 resumes)."""
    folder = tmp_path / "machine"
    shutil.copytree(EXAMPLES / "machine", folder, ignore=shutil.ignore_patterns("scenarios"))
    record = tmp_path / "session.jsonl"
    overrides = {"modbus.port": 0, "nc.time_scale": 5.0}  # the new user's session
    cfg = ncgate_test_config(folder / "ncgate.toml", **overrides)
    ended = asyncio.Event()

    def on_event(event: ev.Event) -> None:
        if isinstance(event, ev.End) and event.proc == 1:
            ended.set()

    async with Gateway(cfg, record=record, overrides=overrides, listeners=[on_event]) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        # The cell stands idle for 2 s of machine time (beyond the TONs' 1 s and 2 s): the
        # engine's own timer says when, on the session's clock.
        gap = asyncio.Event()
        gw.engine.call_at(gw.engine.now + 2.0, gap.set)
        await asyncio.wait_for(gap.wait(), timeout=30)
        await plc.command(1)  # cycle start (holding register 2000)
        await asyncio.wait_for(ended.wait(), timeout=60)
        counted = asyncio.Event()  # the PLC counts the part at its next scan
        if gw.image.wait("SYVAR", 20, "IN", lambda v: v == 1, counted.set) is None:
            counted.set()
        await asyncio.wait_for(counted.wait(), timeout=30)
        assert gw.image.read("SA", 49, "bit") == 0  # any_alarm: the session was a good part
    recording = read_record(record)
    start = next(i for i in recording.inputs if isinstance(i.input, Command))
    assert start.t >= 2.0  # after the gap
    assert [e["how"] for e in recording.events if e["event"] == "end"] == ["M30"]
    assert not [e for e in recording.events if e["event"] == "alarm"]

    result = run_replay(record)
    assert result.divergence is None, result.divergence
    assert result.warnings == []
    assert result.compared == sum(1 for e in recording.events
                                  if e["proc"] and e["event"] in COMPARED)
    assert result.compared > 20
    image = result.runtime.image
    assert image.read("SA", 49, "bit") == 0 and image.read("SYVAR", 20, "IN") == 1
    assert not [e for e in result.events if e["event"] == "alarm"]


async def test_the_plc_scans_on_in_a_replay_past_a_stall(tmp_path: Path) -> None:
    """The program waits for an operator's bit longer than nc.stall_s: run reports the stall
    and its PLC scans on, and so does the replay's, which then sees the bit and answers."""
    (tmp_path / "MAIN.nc").write_text("N10(WAI,SA10=1)\nN20(WAI,SA31=1)\nN30M30\n")
    (tmp_path / "plc.st").write_text("PROGRAM p\nSA[31] := SA[10];\nEND_PROGRAM\n")
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nmain = "MAIN"\ntime_scale = 10.0\nstall_s = 1.0\n'
                      '[nc.storage]\nMP0 = "."\n[plc]\nlogic = "plc.st"\n')
    record = tmp_path / "session.jsonl"
    overrides = {"modbus.port": 0}
    cfg = ncgate_test_config(config, **overrides)
    async with Gateway(cfg, record=record, overrides=overrides) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        stalled = asyncio.ensure_future(wait_event(gw, "stall", timeout_s=30))
        await plc.command(1)
        await stalled
        await plc.set("SA10", 1)
        await gw.wait_idle(timeout_s=30)
    recording = read_record(record)
    assert [e["event"] for e in recording.events if e["event"] in ("stall", "end")] == [
        "stall", "end"]
    result = run_replay(record)
    assert result.divergence is None, result.divergence
    assert result.compared == sum(1 for e in recording.events
                                  if e["proc"] and e["event"] in COMPARED)


async def test_the_scans_a_session_skipped_are_skipped_in_its_replay(tmp_path: Path) -> None:
    """The loop of run comes 100 ms late: the scans due meanwhile are skipped (overruns), and
    the PLC logic, which counts its scans, answers that much later.  The record says which
    scans were skipped; the replay skips the same ones and matches."""
    (tmp_path / "MAIN.nc").write_text("N10(WAI,SYVAR5=40)\nN20M30\n")
    (tmp_path / "plc.st").write_text(
        "PROGRAM p\nVAR n : INT; END_VAR\n"
        "IF NOT NC.P[1].IDLE THEN n := n + 1; SYVAR[5] := n; END_IF\nEND_PROGRAM\n")
    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nmain = "MAIN"\n[nc.storage]\nMP0 = "."\n'
                      '[plc]\nlogic = "plc.st"\nscan_ms = 10\n')
    record = tmp_path / "session.jsonl"
    overrides = {"modbus.port": 0}
    cfg = ncgate_test_config(config, **overrides)
    async with Gateway(cfg, record=record, overrides=overrides) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        await plc.command(1)
        await gw.wait_state(1, "WAIT_COND")  # N10: the logic counts its scans
        # The loop held for ten scans' time: not a wait, the overruns themselves.
        time.sleep(0.1)  # noqa: ASYNC251
        await gw.wait_idle(timeout_s=30)
        overruns = gw.runtime.plc.status.overruns if gw.runtime.plc else 0
    assert overruns >= 5
    recording = read_record(record)
    # Every overrun (k > 0), and the scans due while the fieldbus started (k = 0), if any.
    assert sum(n for k, n in recording.skipped["plc"].items() if k) == overruns
    result = run_replay(record)
    assert result.divergence is None, result.divergence
    assert result.compared == sum(1 for e in recording.events
                                  if e["proc"] and e["event"] in COMPARED)
    replayed = result.runtime.plc
    assert replayed is not None and replayed.status.overruns == overruns


def test_a_replays_plant_tick_does_not_stretch_with_the_replaying_machines_load(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The plant's tick budget is run's, on the wall clock: a replay on a busy machine (here
    every tick seems to take a second) writes a ramping spindle's speed every plant.scan_ms,
    as a replay on an idle one does -- a stretched tick moved the replay's events."""
    from ncgate.gateway.plant import plant as plant_module

    config = tmp_path / "ncgate.toml"
    config.write_text('[nc]\nprocesses = 1\n[[plant.model]]\nname = "spindle"\n'
                      'kind = "motor"\nrun = "SA21"\nspeed = "SYVAR11"\nat_speed = "SA46"\n'
                      'standstill = "SA47"\nrated_rpm = 6000\nramp_rpm_s = 12000\n')
    record = tmp_path / "session.jsonl"
    header = {"ncgate_record": 2, "config": str(config), "overrides": {}, "files": {}}
    start = {"input": "write", **GOOD, "t": 0.1, "changes": [["SA", 21, "bit", 1]]}
    record.write_text("".join(json.dumps(x) + "\n" for x in (header, start, {"stop": 1.0})))
    seconds = itertools.count()
    monkeypatch.setattr(plant_module, "time",
                        types.SimpleNamespace(perf_counter=lambda: float(next(seconds))))
    result = run_replay(record)
    assert result.runtime.plant is not None and result.runtime.plant.stretched == 0
    speeds = [e["t"] for e in result.events if e["event"] == "write" and e["var"] == "SYVAR11"]
    assert len(speeds) >= 50  # 0.5 s of ramp, every 10 ms


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
    whole = [json.loads(line) for line in cut[1:-1]]
    assert len(recording.events) + len(recording.inputs) == sum(
        1 for line in whole if "seq" in line or "input" in line)
    result = run_replay(record)
    assert result.divergence is None, result.divergence


@pytest.mark.parametrize(("text", "said"), [
    ("", "empty"),
    ('{"seq": 1}\n', "not an ncgate session record"),
    ('{"ncgate_record": 1}\n', "format 1, from an older ncgate"),
    ('{"ncgate_record": 2}\nnot json\n{"stop": 1}\n', ":2: not a JSON line"),
    ('{"ncgate_record": 2}\n{"what": 1}\n', ":2: neither an input"),
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
    record.write_text(json.dumps({"ncgate_record": 2}) + "\n")
    assert main(["sim", "PROG91", "--replay", str(record)]) == 2
    assert "--replay takes its programs" in capsys.readouterr().err


# -- a record that never lies ---------------------------------------------------------------

GOOD = {"t": 0.5, "who": "modbus 127.0.0.1:40312", "peer": "127.0.0.1:40312"}
MALFORMED = [
    ({"input": "teleport", **GOOD}, 'unknown kind "teleport"'),
    ({"input": "write", **GOOD}, '"changes" is missing'),
    ({"input": "write", **GOOD, "changes": [["SA", "10", "bit", 1]]}, "not [area, index"),
    ({"input": "write", **GOOD, "changes": [["XY", 1, "bit", 1]]}, "names no image variable"),
    ({"input": "write", **GOOD, "changes": [["SA", 99999, "bit", 1]]}, "outside the image"),
    ({"input": "command", **GOOD, "command": "launch"}, '"command": expected cycle_start'),
    ({"input": "command", **GOOD}, '"command" is missing'),
    ({"input": "snd", **GOOD, "from": "4", "to": 1}, '"from": expected a process number'),
    ({"input": "start", **GOOD, "proc": 1}, '"prog" is missing'),
    ({"input": "alarm", **GOOD, "code": 150}, '"message" is missing'),
    ({"input": "command", **GOOD, "t": "soon", "command": "reset"}, '"t": expected a time'),
    ({"input": "command", **GOOD, "who": "martian", "command": "reset"}, '"who"'),
    ({"seq": 1, "t": 0.0, "event": "start", "prog": "A"}, '"proc" is missing'),
    ({"seq": 1, "t": "0", "event": "start", "proc": 1}, '"t": expected a time'),
    ({"seq": 1, "t": 0.0, "event": "explode", "proc": 1}, 'unknown event "explode"'),
    # What the live door would have refused can never have been recorded.
    ({"input": "command", **GOOD, "command": "reset", "process": "two"},
     '"process": expected a process number, or null for the cell'),
    ({"input": "alarm", **GOOD, "code": 99999, "message": "x"}, "no alarm"),
    ({"input": "command", **GOOD, "t": 0.1, "command": "reset"}, "in time order"),
    ({"skipped": "hmi", "k": 3, "n": 1, "t": 0.5}, '"skipped": expected "plc" or "plant"'),
    ({"skipped": "plc", "k": 3, "n": 0, "t": 0.5}, "not a run of scans"),
    ({"skipped": "plc", "k": 3, "t": 0.5}, '"n" is missing'),
    # A fault no plant takes, whatever the cell (a hostile try's hand edits: each replayed
    # as a divergence "560 ms apart", the refusal only a hazard in the replay's trace).
    ({"input": "fault", **GOOD, "target": "clamp", "kind": "melt", "params": {}},
     'fault kind "melt": one of stuck, wire_break'),
    ({"input": "fault", **GOOD, "target": "SA30", "kind": "stuck", "params": {"value": 1,
                                                                          "ms": 3}},
     "a stuck fault takes value, not ms"),
    ({"input": "fault", **GOOD, "target": "SA30", "kind": "stuck", "params": {}},
     "stuck.value: missing"),
    ({"input": "fault", **GOOD, "target": "SA30", "kind": "chatter",
      "params": {"period_ms": -5}}, "chatter.period_ms: expected"),
    ({"input": "fault", **GOOD, "target": "SA30", "kind": "never", "params": {},
      "for_s": -1}, "for_s: a time in seconds > 0 and < 1e+09, not -1"),
]


def test_a_stop_before_what_was_recorded_and_deep_nesting_are_malformed(
        cell: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    header = {"ncgate_record": 2, "config": str(cell), "overrides": {}, "files": {}}
    fine = {"input": "command", **GOOD, "command": "cycle_start", "process": None}
    huge = '{"input": "alarm", "t": 0.5, "who": "api", "code": ' + "9" * 5000 + "}"
    for tail, said in (([json.dumps({"stop": 0.1})], "comes before what was recorded"),
                       (["[" * 100_000 + "]" * 100_000, json.dumps({"stop": 1.0})],
                        "not a JSON line"),
                       ([huge, json.dumps({"stop": 1.0})], "not a JSON line")):
        record = tmp_path / "r.jsonl"
        record.write_text("\n".join([json.dumps(header), json.dumps(fine), *tail]) + "\n")
        assert main(["sim", "--replay", str(record)]) == 2
        assert said in capsys.readouterr().err


@pytest.mark.parametrize(("line", "said"), MALFORMED)
def test_a_malformed_line_is_an_error_naming_its_line(
        cell: Path, tmp_path: Path, line: dict[str, object], said: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    record = tmp_path / "r.jsonl"
    header = {"ncgate_record": 2, "config": str(cell), "overrides": {}, "files": {}}
    fine = {"input": "command", **GOOD, "command": "cycle_start", "process": None}
    record.write_text("".join(json.dumps(x) + "\n" for x in (header, fine, line,
                                                             {"stop": 1.0})))
    assert main(["sim", "--replay", str(record)]) == 2  # never a traceback, never a match
    err = capsys.readouterr().err
    assert f"{record}:3: " in err and said in err, err


async def test_every_prefix_of_a_session_replays_as_a_match(cell: Path,
                                                            tmp_path: Path) -> None:
    """Cut at every line, as kill -9 or a full disk may: what is left replays, matches up to
    the cut and never crashes; a cut record never claims more than it saw."""
    record = tmp_path / "session.jsonl"
    await record_session(cell, record)
    lines = record.read_text().splitlines(keepends=True)
    assert len(lines) > 40
    prefix = tmp_path / "prefix.jsonl"
    for n in range(1, len(lines) + 1):
        prefix.write_text("".join(lines[:n]))
        result = run_replay(prefix)
        assert result.divergence is None, (n, lines[n - 1], result.divergence)
        assert result.warnings == []


async def test_a_replay_with_another_config_compares_the_files_it_uses(
        cell: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A record taken home, replayed with --config: the config and the programs it loads are
    compared with the recording, not the files at the recorded paths (a new user's try: an
    edited copy said "ncgate.toml: recorded but not found now" and nothing of the edited
    program).  From another folder the recorded config is found by its absolute path."""
    record = tmp_path / "session.jsonl"
    monkeypatch.chdir(cell.parent)
    await record_session(cell, record, source=Path("ncgate.toml"))  # run from the cell's folder
    _replay_with_another_config(cell, record, tmp_path, capsys, monkeypatch)


def _replay_with_another_config(cell: Path, record: Path, tmp_path: Path,
                                capsys: pytest.CaptureFixture[str],
                                monkeypatch: pytest.MonkeyPatch) -> None:
    assert read_record(record).header["config"] == str(cell.resolve())
    home = tmp_path / "home"
    shutil.copytree(cell.parent / "programs", home / "programs")
    (home / "ncgate.toml").write_text(cell.read_text().replace("time_scale = 50.0",
                                                               "time_scale = 50"))
    prog92 = home / "programs" / "PROG92.nc"
    prog92.write_text(prog92.read_text().replace("N40(WAI,SA10=1)", "N40(WAI,SA11=1)"))
    monkeypatch.chdir(tmp_path)
    assert main(["sim", "--replay", str(record), "--config", str(home / "ncgate.toml")]) == 1
    err = capsys.readouterr().err
    assert "recorded but not found now" not in err, err
    assert f"warning: {cell.resolve()}: changed since the recording" in err  # the config
    assert "PROG92.nc: changed since the recording" in err  # the program it loads
    assert main(["sim", "--replay", str(record)]) == 0  # the cell itself, from elsewhere
    assert "warning" not in capsys.readouterr().err


async def test_a_session_whose_processes_did_nothing_is_no_match_to_claim(
        cell: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    record = tmp_path / "session.jsonl"
    overrides = {"modbus.port": 0}
    async with Gateway(ncgate_test_config(cell, **overrides), record=record,
                       overrides=overrides) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        await plc.set("SA10", 1)
    assert main(["sim", "--replay", str(record)]) == 0
    out = capsys.readouterr().out
    assert "nothing to compare: the session recorded no event of the processes" in out
    assert "the replay matches" not in out


def _hidden(folder: Path) -> list[str]:
    """What is staged in ``folder`` (a record is written beside its path while it starts)."""
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


async def test_a_start_that_fails_leaves_the_file_at_the_records_path_as_it_was(
        cell: Path, tmp_path: Path) -> None:
    """`run --record session.jsonl` over a record of yesterday, with the console's port
    taken: the start failed, and the 103 kB record was a header and a stop line, which
    replayed as a clean empty session (a hostile try)."""
    record = tmp_path / "session.jsonl"
    await record_session(cell, record)
    yesterday = record.read_bytes()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        overrides = {"modbus.port": taken.getsockname()[1]}
        with pytest.raises(GatewayError):
            async with Gateway(ncgate_test_config(cell, **overrides), record=record,
                               overrides=overrides):
                pass
    assert record.read_bytes() == yesterday
    assert _hidden(tmp_path) == []


async def test_a_record_is_at_its_path_once_the_gateway_serves(cell: Path,
                                                                tmp_path: Path) -> None:
    record = tmp_path / "session.jsonl"
    record.write_text("yesterday\n")
    overrides = {"modbus.port": 0}
    async with Gateway(ncgate_test_config(cell, **overrides), record=record,
                       overrides=overrides) as gw:
        assert gw.recorder is not None and gw.recorder.path == record
        gw.recorder.flush()
        assert json.loads(record.read_text().splitlines()[0])["ncgate_record"]
        assert _hidden(tmp_path) == []
    assert json.loads(record.read_text().splitlines()[-1])["stop"] >= 0


def test_the_record_and_the_trace_file_may_not_be_one_file_nor_the_record_a_folder(
        cell: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Each overwrote the other, and the replay then refused the record."""
    same = cell.parent / "same.jsonl"
    assert main(["run", "--config", str(cell), "--record", str(same), "--set",
                 f"trace.file={same}", "--port", "0", "--no-web"]) == 2
    assert "--record" in capsys.readouterr().err
    assert not same.exists()
    folder = cell.parent / "records.jsonl"
    folder.mkdir()  # (refused at commit, once it served: a hostile try)
    assert main(["run", "--config", str(cell), "--record", str(folder), "--port", "0",
                 "--no-web"]) == 2
    assert "--record" in (err := capsys.readouterr().err) and "is a folder" in err, err


LAGS = """
[nc]
processes = 1
main = "O1"
time_scale = 20.0
[nc.storage]
MP0 = "."
[plant]
scan_ms = 1
[[plant.model]]
name = "oil"
kind = "lag"
target = "SYVAR1"
actual = "SYVAR2"
time_constant_ms = 40
[[plant.model]]
name = "air"
kind = "lag"
target = "SYVAR3"
actual = "SYVAR4"
time_constant_ms = 60
"""


async def test_the_plants_budget_in_the_session_is_the_replays(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """On the wall clock a busy loop cuts the plant's tick short and stretches its period,
    which the record did not keep: the replay ticked every scan, and wrote the moving values
    at other times and counts than the session (94 writes of a speed live, 143 replayed: a
    hostile try) -- a threshold crossed a scan apart, a divergence of a faithful session.
    Here the budget is nil: every tick is cut after one model and the period stretches."""
    import ncgate.gateway.plant.plant as plant_module

    monkeypatch.setattr(plant_module, "TICK_S", 0.0)
    monkeypatch.setattr(plant_module, "BUDGET", 0.0)
    (tmp_path / "O1.nc").write_text("N10 (WAI,SYVAR2>989)\nN20 (WAI,SYVAR4>989)\nN30 M30\n")
    (tmp_path / "ncgate.toml").write_text(LAGS)
    record = tmp_path / "session.jsonl"
    overrides = {"modbus.port": 0}
    config = ncgate_test_config(tmp_path / "ncgate.toml", **overrides)
    async with Gateway(config, record=record, overrides=overrides) as gw:
        gw.write("SYVAR1", 1000)
        gw.write("SYVAR3", 1000)
        await gw.start()
        await gw.wait_idle(timeout_s=30)
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    decided = {line["plant"] for line in lines if "plant" in line}
    assert decided == {"cut", "stretch"}, decided  # the budget acted, and was kept

    def plant_writes(events: list[dict[str, object]]) -> list[tuple[float, object, object]]:
        return [(round(float(str(e["t"])), 6), e["var"], e["value"]) for e in events
                if e["event"] == "write" and str(e["who"]).startswith("plant ")]

    result = await asyncio.to_thread(run_replay, record)
    assert result.divergence is None, result.divergence
    live = plant_writes([line for line in lines if "seq" in line])
    assert len(live) > 10
    # (To the session's last: a tick due at the stop's instant the replay runs, and the
    # session, closing, may not have.)  The same writes, one for one, at the same times --
    # to the record's resolution: an input's time is kept to the microsecond, and a model's
    # switch point worked out from it may round the other way (0.760697 and 0.760698); a
    # tick of another grid or a write more or less would be a millisecond off or more.
    replayed = [w for w in plant_writes(result.events) if w[0] <= live[-1][0] + 2e-6]
    assert [w[1:] for w in replayed] == [w[1:] for w in live]
    assert all(abs(a[0] - b[0]) <= 1.5e-6 for a, b in zip(replayed, live, strict=True)), (
        [(a, b) for a, b in zip(replayed, live, strict=True) if abs(a[0] - b[0]) > 1.5e-6])


def test_a_malformed_plant_budget_line_names_its_line(
        cell: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    header = {"ncgate_record": 2, "config": str(cell), "overrides": {}, "files": {}}
    for line, said in (({"plant": "pause", "t": 0.1, "n": 2}, '"plant": expected "cut"'),
                       ({"plant": "stretch", "t": 0.1, "n": 3}, "a power of 2"),
                       ({"plant": "cut", "t": 0.1, "n": 0}, "a number of models"),
                       ({"plant": "cut", "t": -1, "n": 1}, '"t": expected a time')):
        record = tmp_path / "r.jsonl"
        record.write_text("".join(json.dumps(x) + "\n" for x in (header, line,
                                                                 {"stop": 1.0})))
        assert main(["sim", "--replay", str(record)]) == 2
        err = capsys.readouterr().err
        assert f"{record}:2: " in err and said in err, err
