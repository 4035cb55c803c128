"""Every ISG example (seeds 001, 002, 004) under ``ncgate sim``, checked on the trace against
what the seed says happens and what its README row states -- and the engine's other dialect
beside it: the NC-110 scenarios run unchanged in ``test_scenarios.py``."""

from __future__ import annotations

import io
import json
from typing import Any

import pytest

from ncgate.gateway.cli.main import main
from ncgate.interpreter.codes import AlarmCode

from .test_scenarios import index, sim

Event = dict[str, Any]


def only(events: list[Event], **match: Any) -> list[Event]:
    return [e for e in events if all(e.get(k) == v for k, v in match.items())]


def position(result: Any, channel: int) -> tuple[float, float]:
    p = result.runtime.engine.processes[channel]
    return (round(p.actual[0], 6), round(p.actual[1], 6))


def test_parameters_from_two_channels() -> None:
    """Seed 001: channel 3's WAIT takes P[0] from channel 1 and P[1] from channel 2."""
    result = sim("isg_params", "PARAMS")
    assert result.exit_status == 0 and result.outcome == "idle"
    ev = result.events
    s1 = ev[index(ev, event="signal", proc=1)]
    s2 = ev[index(ev, event="signal", proc=2)]
    assert (s1["id"], s1["to"], s1["params"], s1["level"]) == (110014, [3], {"0": 1234}, "dec")
    assert (s2["id"], s2["to"], s2["params"]) == (110014, [3], {"1": 200})
    # A signal never blocks its sender: both end at t = 0.
    assert [e["t"] for e in only(ev, event="end") if e["proc"] in (1, 2)] == [0.0, 0.0]
    p3 = result.runtime.engine.processes[3]
    assert p3.E[1] == 1234 and p3.E[2] == 200
    assert position(result, 3) == (1234.0, 200.0)
    assert p3.stats.snd_received == 2


def test_three_kinds_of_wait() -> None:
    """Seed 001's first example: broadcast, interpolator-level from two channels, and
    parameters into V.P.SIGNAL and P200."""
    result = sim("isg_waits", "WAITS")
    assert result.exit_status == 0
    ev = result.events
    broadcast_wait = ev[index(ev, event="wait", proc=1, n=200)]
    assert broadcast_wait["on"] == {"signal": 4711, "from": "all", "level": "dec"}
    assert broadcast_wait["t"] == 0.0
    resume = ev[index(ev, event="resume", proc=1, n=200)]
    assert (resume["t"], resume["by"]) == (2.0, "all")
    syn_wait = ev[index(ev, event="wait", proc=1, n=100)]
    # Channel 3 signalled 815 at 2.0 s: at 2.5 s the wait is for channel 2's only.
    assert syn_wait["on"] == {"signal": 815, "from": [2], "level": "syn"}
    assert syn_wait["t"] == 2.5
    syn_resume = ev[index(ev, event="resume", proc=1, n=100)]
    assert (syn_resume["t"], syn_resume["by"]) == (3.0, 2)
    assert index(ev, event="signal", proc=2, id=815) < index(ev, event="resume", proc=1, n=100)
    p1 = result.runtime.engine.processes[1]
    assert p1.E[200] == 12 and p1.E[20] == 120 and p1.vars["SIGNAL"] == 7
    assert position(result, 1) == (120.0, 7.0)


def test_decoder_waits_for_decoder_which_runs_on() -> None:
    """Seed 002 (1): decoder 3 waits for decoder 1, which works on without interruption."""
    result = sim("isg_decoders", "DECODERS")
    assert result.exit_status == 0
    ev = result.events
    wait = ev[index(ev, event="wait", proc=3)]
    assert wait["on"] == {"signal": 814, "from": [1], "level": "dec"} and wait["t"] == 0.0
    resume = ev[index(ev, event="resume", proc=3)]
    assert (resume["t"], resume["by"]) == (1.0, 1)
    signal = ev[index(ev, event="signal", proc=1)]
    assert signal["params"] == {"0": 1000} and signal["t"] == 1.0
    # Decoder 1 never waits for a signal (its only wait is its own #FLUSH).
    assert [e["on"] for e in only(ev, event="wait", proc=1)] == [{"flush": True}]
    assert position(result, 3) == (1000.0, 0.0)


def test_interpolators_wait_for_each_other_and_decoder_3() -> None:
    """Seed 002 (2): interpolators 1 and 2 wait for each other and for decoder 3."""
    result = sim("isg_dec_interp", "DECINT")
    assert result.exit_status == 0
    ev = result.events
    from_3 = ev[index(ev, event="signal", proc=3)]
    assert (from_3["to"], from_3["level"], from_3["t"]) == ([1, 2], "dec", 0.5)
    wait = ev[index(ev, event="wait", proc=1)]
    # Decoder 3's signal came at 0.5 s: at 1.0 s the wait is for channel 2's only.
    assert wait["on"] == {"signal": 968, "from": [2], "level": "syn"} and wait["t"] == 1.0
    resume = ev[index(ev, event="resume", proc=1)]
    assert (resume["t"], resume["by"]) == (3.0, 2)
    # Both paths go on together from t = 3 (1 s of motion each, then the end).
    assert [e["t"] for e in only(ev, event="end") if e["proc"] in (1, 2)] == [4.0, 4.0]


def test_paths_1_and_3_wait_for_path_2() -> None:
    """Seed 002 (3): one #SIGNAL SYN with two CH is two directed signals."""
    result = sim("isg_paths", "PATHS")
    assert result.exit_status == 0
    ev = result.events
    waits = {e["proc"]: e for e in only(ev, event="wait")}
    assert (waits[3]["t"], waits[1]["t"]) == (0.5, 1.0)
    assert all(w["on"] == {"signal": 100, "from": [2], "level": "syn"} for w in waits.values())
    signal = ev[index(ev, event="signal", proc=2)]
    assert (signal["to"], signal["level"], signal["t"]) == ([1, 3], "syn", 2.0)
    resumes = only(ev, event="resume")
    assert sorted((e["proc"], e["t"], e["by"]) for e in resumes) == [(1, 2.0, 2), (3, 2.0, 2)]
    assert result.runtime.engine.processes[2].stats.snd_sent == 2


def test_decoder_waits_for_its_own_interpolator_with_flush() -> None:
    """Seed 002 (4): with #FLUSH the decoder waits for its interpolator, which signals at
    X250; the program runs to its end."""
    result = sim("isg_flush", "FLUSH")
    assert result.exit_status == 0
    ev = result.events
    flush = ev[index(ev, event="wait", proc=1)]
    assert flush["on"] == {"flush": True} and flush["line"] == 14
    signal = ev[index(ev, event="signal", proc=1)]
    # G00 to X100 Y500 at the rapid rate, then 150 mm at F300: X250 is reached at 33.059 s.
    rapid = (100 ** 2 + 500 ** 2) ** 0.5 / 10000 * 60
    assert signal["t"] == pytest.approx(rapid + 30.0, abs=1e-6) and signal["level"] == "syn"
    resume = ev[index(ev, event="resume", proc=1)]
    assert resume["by"] == "flush"
    assert resume["t"] == pytest.approx(rapid + 30 + (120 ** 2 + 200 ** 2) ** 0.5 / 80 * 60)
    assert index(ev, event="signal") < index(ev, event="resume")
    assert not only(ev, event="wait", proc=1, line=15)  # the WAIT finds 88 stored
    assert position(result, 1) == (900.0, 500.0)


def test_without_flush_the_buffer_effect_deadlocks_and_names_the_fix() -> None:
    result = sim("isg_no_flush", "NOFLUSH")
    assert result.exit_status == 1
    ev = result.events
    deadlock = ev[index(ev, event="deadlock")]
    assert deadlock["t"] == 0.0
    assert [(b["proc"], b["line"]) for b in deadlock["cycle"]] == [(1, 14)]
    message = deadlock["message"]
    assert "#WAIT [ID88 CH1]" in message and "NOFLUSH.nc:9" in message
    assert "add #FLUSH before the #WAIT" in message
    alarm = ev[index(ev, event="alarm", proc=1)]
    assert alarm["code"] == AlarmCode.DEADLOCK.label
    assert not only(ev, event="signal")  # the signal never left the buffer


def test_no_flush_check_warns_before_it_runs(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "--example", "isg_no_flush"]) == 0  # a warning, not an error
    out = capsys.readouterr().out
    assert "NOFLUSH.nc:14:1: warning IW001" in out
    assert main(["check", "--example", "isg_flush"]) == 0
    assert "IW001" not in capsys.readouterr().out


def test_synchronous_and_asynchronous_ve_access() -> None:
    """Seed 004: a synchronous read waits for the interpolator (implicit #FLUSH WAIT), an
    asynchronous one reads at decode time; a synchronous write acts in motion order."""
    result = sim("isg_ve", "VE")
    assert result.exit_status == 0
    ev = result.events
    flush = ev[index(ev, event="wait", proc=1, n=30)]
    assert flush["on"] == {"flush": True} and flush["t"] == 0.0
    resume = ev[index(ev, event="resume", proc=1, n=30)]
    assert (resume["t"], resume["by"]) == (1.0, "flush")
    p = result.runtime.engine.processes[1]
    assert p.E[1] == 0  # read at t = 0, before the PLC's write at 0.5
    assert p.E[2] == 7  # read at t = 1, after it
    lamp = ev[index(ev, event="write", var="SYVAR6")]
    lamp_now = ev[index(ev, event="write", var="SYVAR7")]
    assert (lamp["t"], lamp["n"]) == (2.0, 50) and (lamp_now["t"], lamp_now["n"]) == (1.0, 60)
    assert position(result, 1) == (200.0, 7.0)


@pytest.mark.parametrize("folder", ["isg_params", "isg_waits", "isg_decoders", "isg_dec_interp",
                                    "isg_paths", "isg_flush", "isg_ve"])
def test_examples_run_from_the_cli_and_check_clean(
        folder: str, tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    trace = tmp_path / "t.jsonl"
    gantt = tmp_path / "g.svg"
    assert main(["sim", "--example", folder, "--trace", str(trace), "--gantt",
                 str(gantt)]) == 0
    events = [json.loads(line) for line in trace.read_text().splitlines()]
    signals = [e for e in events if e["event"] == "signal"]
    flushes = [e for e in events if e["event"] == "wait" and e["on"] == {"flush": True}]
    assert signals or flushes
    svg = gantt.read_text()
    assert svg.count("#FLUSH") >= len(flushes)  # a flush is a labelled WAIT_COND interval
    # Every signal is drawn: an arrow to each addressee, or to each lane waiting for it.
    assert svg.count("#SIGNAL ID") >= sum(len(s["to"]) if s["to"] != "all" else 1
                                          for s in signals)
    assert main(["check", "--example", folder]) == 0
    assert "0 error(s), 0 warning(s)" in capsys.readouterr().err


def test_trace_file_is_byte_identical_between_runs(tmp_path: Any) -> None:
    out = []
    for _ in range(2):
        buf = io.StringIO()
        from ncgate.gateway.sim import write_trace

        write_trace(sim("isg_waits", "WAITS"), buf)
        out.append(buf.getvalue())
    assert out[0] == out[1]
