"""A scenario's t = 0 is the same instant in `ncgate run --script` as in `ncgate sim
--script`: its expectations watch from the start itself, before the program's first blocks
run, and its entries due at 0 act one after the other, each followed by what it made
runnable -- as sim runs them, and as a replay of the session applies the recorded inputs.
The same file gives the same verdicts in both."""

from __future__ import annotations

import asyncio
import re
import signal
from pathlib import Path

import pytest

from ncgate.gateway.cli.main import main

from .test_cli_run import start_run, stop_run

CELL = """[nc]
processes = 2
main = "O1"
[[nc.process]]
number = 2
external = true
[nc.storage]
MP0 = "."
[modbus]
port = 0
[canopen]
enabled = false
[web]
enabled = false
"""


async def _run_script(folder: Path, *more: str) -> tuple[int, str]:
    """`ncgate run --script scenario.toml` on the cell in ``folder``: it ends by itself at
    the scenario's end; its exit status and its whole output."""
    proc, _, lines = await start_run(folder / "ncgate.toml", "--script",
                                     str(folder / "scenario.toml"), *more)
    assert proc.stdout is not None
    async with asyncio.timeout(30):
        rest = (await proc.stdout.read()).decode()
        code = await proc.wait()
    return code, "".join(lines) + rest


def _verdicts(text: str) -> list[str]:
    return re.findall(r"^(?:PASS|FAIL) .*$", text, re.MULTILINE)


async def _both(folder: Path, program: str, scenario: str,
                capsys: pytest.CaptureFixture[str]) -> tuple[list[str], str]:
    (folder / "ncgate.toml").write_text(CELL)
    (folder / "O1.nc").write_text(program)
    (folder / "scenario.toml").write_text(scenario)
    capsys.readouterr()
    sim_code = main(["sim", "--config", str(folder / "ncgate.toml"), "--script",
                     str(folder / "scenario.toml")])
    sim = _verdicts(capsys.readouterr().out)
    code, log = await _run_script(folder)
    assert (code, _verdicts(log)) == (sim_code, sim), log
    return sim, log


async def test_a_state_the_program_leaves_at_once_holds_at_t0_in_run_as_in_sim(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # P1 is RUNNING from its start until its first dwell begins, at the same instant: sim
    # saw that state at t = 0, run (which watched only after the first blocks) did not.
    verdicts, _ = await _both(
        tmp_path, "N10 (DLY,0.2)\nN20 M30\n",
        '[[expect]]\nname = "runs at once"\ncond = "P1 RUNNING"\nwithin = [0.0, 0.1]\n'
        '[[expect]]\nname = "ends"\ncond = "P1 IDLE"\nby = 1.0\n', capsys)
    assert verdicts == ["PASS runs at once: P1 RUNNING at 0.000 s",
                        "PASS ends: P1 IDLE at 0.200 s"]


async def test_entries_at_t0_act_one_after_the_other_in_run_as_in_sim(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Two SNDs at 0 to a program that waits for two: with P1 run between them, each finds
    # P1 waiting for it.  Applied back to back, the second came while P1 had not yet
    # passed its first WAI, and was latched with a hazard that sim never raised.
    verdicts, log = await _both(
        tmp_path, "N10 (WAI,2)\nN20 (WAI,2)\nN30 M30\n",
        '[[snd]]\nat = 0\nfrom = 2\nto = 1\n[[snd]]\nat = 0\nfrom = 2\nto = 1\n'
        '[[expect]]\nname = "both heard"\ncond = "P1 IDLE"\nby = 0.5\n', capsys)
    assert verdicts == ["PASS both heard: P1 IDLE at 0.000 s"]
    assert "hazard" not in log, log


PLC_CELL = """[nc]
processes = 1
main = "O1"
[nc.storage]
MP0 = "."
[plc]
logic = "plc.st"
scan_ms = 10
[plant]
scan_ms = 10
[[plant.model]]
name = "clamp"
kind = "cylinder"
extend = "SA20"
extended = "SA30"
retracted = "SA31"
travel_ms = 300
[modbus]
port = 0
[canopen]
enabled = false
[web]
enabled = false
"""


async def test_a_plc_reaction_lands_on_the_scan_it_lands_on_in_sim(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The program's first block asks for the clamp and waits for it; the PLC's scan at the
    # program's start opens the valve (sim's t = 0 is a scan's instant, the start before its
    # scan); the clamp is closed exactly 300 ms on, and the program goes on then.  `run
    # --script` started the program between two scans, so every PLC reaction came 0..10 ms
    # later than in sim, and these edges failed.
    (tmp_path / "ncgate.toml").write_text(PLC_CELL)
    (tmp_path / "O1.nc").write_text("N10 SYVAR1=1\nN20 (WAI,SA30=1)\nN30 (DLY,0.5)\nN40 M30\n")
    (tmp_path / "plc.st").write_text("PROGRAM main\nSA[20] := SYVAR[1] = 1;\nEND_PROGRAM\n")
    (tmp_path / "scenario.toml").write_text(
        '[[expect]]\nname = "open a hair before"\ncond = "SA30=0"\nwithin = [0.299, 0.299]\n'
        '[[expect]]\nname = "closed on the dot"\ncond = "SA30=1"\nwithin = [0.3, 0.3]\n'
        '[[expect]]\nname = "ends"\ncond = "P1 IDLE"\nby = 1.5\n')
    capsys.readouterr()
    sim_code = main(["sim", "--config", str(tmp_path / "ncgate.toml"), "--script",
                     str(tmp_path / "scenario.toml")])
    sim = _verdicts(capsys.readouterr().out)
    assert sim_code == 0 and sim == ["PASS open a hair before: SA30=0 at 0.299 s",
                                     "PASS closed on the dot: SA30=1 at 0.300 s",
                                     "PASS ends: P1 IDLE at 0.800 s"], sim
    for _ in range(3):  # (a start between two scans passes by chance about once in ten)
        code, log = await _run_script(tmp_path, "--record", str(tmp_path / "r.jsonl"))
        assert (code, _verdicts(log)) == (0, sim), log
        # The record says the start came first at its instant, and the replay puts it there:
        # the same events at the very same times (applied after that instant's scan, as other
        # inputs are, the PLC's reactions came a scan later).
        assert main(["sim", "--replay", str(tmp_path / "r.jsonl"), "--tolerance-ms",
                     "0"]) == 0, capsys.readouterr().out


async def test_the_start_comes_after_the_plants_tick_of_its_instant_in_run_and_replay(
        tmp_path: Path) -> None:
    # The scans share an instant every 20 ms (PLC 5 ms, plant 4 ms); the start at one comes
    # after the plant's tick of it (the sample first at its instant) and before the scan, in
    # the session and in its replay alike.  Armed before the tick, the start came first live
    # and after the tick in the replay: the program's first WAI read another ramp value and
    # the replay diverged, 6 runs of 6.
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 1\nmain = "O1"\nlookahead = 0\n[nc.storage]\nMP0 = "."\n'
        '[plc]\nlogic = "plc.st"\nscan_ms = 5\n[plant]\nscan_ms = 4\n[[plant.model]]\n'
        'name = "ramp"\nkind = "generator"\nshape = "ramp"\noutput = "SYVAR2"\n'
        'period_ms = 20\nlow = 0\nhigh = 1000\n'
        '[modbus]\nport = 0\n[canopen]\nenabled = false\n[web]\nenabled = false\n')
    (tmp_path / "plc.st").write_text("PROGRAM main\nSA[1] := TRUE;\nEND_PROGRAM\n")
    (tmp_path / "O1.nc").write_text("N10 (WAI,SYVAR2<100)\nN20 (DLY,0.05)\nN30 M30\n")
    (tmp_path / "scenario.toml").write_text(
        '[[expect]]\nname = "ends"\ncond = "P1 IDLE"\nwithin = [0, 0.5]\n')
    for i in range(3):
        record = tmp_path / f"r{i}.jsonl"
        code, log = await _run_script(tmp_path, "--record", str(record))
        assert code == 0, log
        assert main(["sim", "--replay", str(record), "--tolerance-ms", "0"]) == 0


async def test_a_stop_while_the_scenario_waits_for_its_instant_starts_nothing(
        tmp_path: Path) -> None:
    # At a time scale of 0.0002 the next scan's instant is up to 50 s of the wall clock away;
    # Ctrl-C meanwhile stops the gateway at once, and the program never starts (it waited,
    # deaf to the signal, and then started the part program on a stopping gateway).
    (tmp_path / "ncgate.toml").write_text(PLC_CELL.replace(
        '[nc]\n', '[nc]\ntime_scale = 0.0002\n'))
    (tmp_path / "O1.nc").write_text("N10 (DLY,0.1)\nN20 M30\n")
    (tmp_path / "plc.st").write_text("PROGRAM main\nSA[20] := FALSE;\nEND_PROGRAM\n")
    (tmp_path / "scenario.toml").write_text(
        '[[expect]]\nname = "ends"\ncond = "P1 IDLE"\nwithin = [0.1, 0.2]\n')
    proc, _, lines = await start_run(tmp_path / "ncgate.toml", "--script",
                                     str(tmp_path / "scenario.toml"))
    assert proc.stdout is not None
    async with asyncio.timeout(20):
        while "the next instant its scans share" not in lines[-1]:
            line = (await proc.stdout.readline()).decode()
            assert line, "".join(lines)
            lines.append(line)
    code, log = await stop_run(proc, lines, signal.SIGINT, timeout_s=10.0)
    assert "stopped before its start" in log, log
    assert "starts O1" not in log, log
    assert code == 1 and "FAIL ends: not reached" in log, log


def test_an_until_finer_than_a_millisecond_is_printed_as_given(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # `--until 0.15999` printed as 0.160: "the run ended at 0.160 s, before the window
    # [0.1, 0.2] s closed" read as if the run had gone past 0.16.
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "O1"\n[nc.storage]\nMP0 = "."\n')
    (tmp_path / "O1.nc").write_text("N10 (DLY,0.5)\nN20 M30\n")
    (tmp_path / "s.toml").write_text(
        '[[expect]]\nname = "w"\ncond = "P1 IDLE"\nwithin = [0.1, 0.2]\n')
    args = ["sim", "--config", str(tmp_path / "ncgate.toml"), "--script",
            str(tmp_path / "s.toml"), "--until"]
    capsys.readouterr()
    assert main([*args, "0.15999"]) == 1
    out = capsys.readouterr().out
    assert "simulated 0.15999 s: stopped at --until" in out, out
    assert "the run ended at 0.15999 s, before the window [0.1, 0.2] s closed" in out, out
    assert "P1 DWELL, not IDLE, at 0.15999 s" in out, out
    assert main([*args, "0.15"]) == 1  # a millisecond's time as ever
    assert "the run ended at 0.150 s" in capsys.readouterr().out
