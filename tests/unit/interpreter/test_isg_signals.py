"""Signals and waits of the ISG dialect (spec 5.3, 5.4): storing, consuming, broadcast and
COUNT, REMOVE, parameters, the store limit, resets, deadlocks across channels, and how a
signal counts on the fieldbus."""

from __future__ import annotations

from pathlib import Path

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.isg.frontend import IsgFrontEnd

from .isg_harness import events, isg_sim


def board(result):  # type: ignore[no-untyped-def]
    front_end = result.runtime.engine.front_end
    assert isinstance(front_end, IsgFrontEnd) and front_end.board is not None
    return front_end.board


def test_broadcast_without_count_is_never_used_up(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
#SIGNAL [ID5]
M30
%channel2
#WAIT [ID5]
#WAIT [ID5]
M30
%channel3
#WAIT [ID5]
M30
""")
    assert result.outcome == "idle"
    assert [e["to"] for e in events(result, "signal")] == ["all"]
    (stored,) = board(result).stored()
    assert (stored.id, stored.to, stored.left) == (5, 0, None)
    assert [result.runtime.engine.processes[k].stats.snd_received for k in (2, 3)] == [2, 1]


def test_broadcast_with_count_reaches_every_waiting_lane_then_is_used_up(
        tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
G01 X100 F6000
#FLUSH
#SIGNAL [ID5 COUNT2]
M30
%channel2
#WAIT [ID5]
#WAIT [ID5]
M30
%channel3
#WAIT [ID5]
M30
""")
    # Channels 2 and 3 wait from t = 0; the one signal at t = 1 resumes both ("all"),
    # which uses its COUNT up: channel 2's second WAIT has nothing left to take.
    assert sorted((e["proc"], e["t"], e["by"]) for e in events(result, "resume")
                  if e["by"] == "all") == [(2, 1.0, "all"), (3, 1.0, "all")]
    assert result.outcome == "stall"
    assert not board(result).stored()
    (wait,) = [e for e in events(result, "wait", proc=2) if e["t"] == 1.0]
    assert wait["line"] == 8


def test_a_directed_signal_is_used_up_by_one_wait(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
#SIGNAL [ID7 CH2]
M30
%channel2
#WAIT [ID7 CH1]
#WAIT [ID7 CH1]
M30
""", processes=2)
    # The second WAIT needs another signal from channel 1, whose program has ended: in a
    # closed simulation nothing can start it again.
    (alarm,) = events(result, "alarm", proc=2)
    assert alarm["code"] == AlarmCode.ORPHAN_WAIT.label and alarm["line"] == 6


def test_count_lets_a_directed_signal_serve_several_waits(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
#SIGNAL [ID7 COUNT 2 CH2]
M30
%channel2
#WAIT [ID7 CH1]
#WAIT [ID7 CH1]
M30
""", processes=2)
    assert result.outcome == "idle" and not board(result).stored()


def test_remove_clears_broadcasts_in_a_range(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
#SIGNAL [ID5]
#SIGNAL [ID6]
#SIGNAL [ID9]
#SIGNAL [ID6 CH2]
#SIGNAL REMOVE [IDMIN5 IDMAX6]
M30
%channel2
G01 X100 F6000
#FLUSH
#WAIT [ID9]
#WAIT [ID6 CH1]
#WAIT [ID5]
M30
""", processes=2)
    (remove,) = events(result, "remove")
    assert remove["removed"] == 2 and remove["line"] == 6
    # 9 (out of the range) and the directed 6 (REMOVE without CH clears broadcasts) are
    # still there; broadcast 5 is gone.
    assert result.outcome == "stall"
    *_, last = events(result, "wait", proc=2)
    assert last["on"] == {"signal": 5, "from": "all", "level": "dec"}


def test_remove_with_ch_clears_the_signals_to_that_channel(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
#SIGNAL [ID4 CH2]
#SIGNAL [ID4 CH3]
#SIGNAL REMOVE [ID4 CH2]
M30
%channel2
M30
%channel3
M30
""")
    assert events(result, "remove")[0]["removed"] == 1
    assert [(s.id, s.to) for s in board(result).stored()] == [(4, 3)]


def test_parameters_missing_from_every_received_signal_is_an_alarm(tmp_path: Path) -> None:
    # Stored before the WAIT, and delivered to a WAIT already waiting: both are checked.
    result = isg_sim(tmp_path, """%channel1
#SIGNAL [ID3 P[0]=1 CH2]
G01 X100 F6000
#FLUSH
#SIGNAL [ID4 P[0]=1 CH3]
M30
%channel2
#WAIT [ID3 P[1]=P5 CH1]
M30
%channel3
#WAIT [ID4 P[0]=P5 P[2]=P6 CH1]
M30
""")
    alarms = {e["proc"]: e for e in events(result, "alarm")}
    assert alarms[2]["code"] == AlarmCode.SIGNAL_PARAM_MISSING.label and alarms[2]["t"] == 0
    assert "P[1]" in alarms[2]["message"]
    assert alarms[3]["code"] == AlarmCode.SIGNAL_PARAM_MISSING.label and alarms[3]["t"] == 1.0
    assert alarms[3]["message"].endswith("no received signal carried P[2]")


def test_one_signal_more_than_max_events_is_an_alarm_of_the_sender(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
#SIGNAL [ID1 CH2]
#SIGNAL [ID2 CH2 CH3]
#SIGNAL [ID3 CH2]
M30
%channel2
G01 X100 F6000
M30
%channel3
M30
""", config="[nc.isg]\nmax_events = 3")
    (alarm,) = events(result, "alarm")
    assert (alarm["proc"], alarm["line"]) == (1, 4)
    assert alarm["code"] == AlarmCode.SIGNAL_STORE_FULL.label
    # Nothing of the refused signal was stored or sent.
    assert [e["id"] for e in events(result, "signal")] == [1, 2]
    assert len(board(result).stored()) == 3


def test_a_reset_clears_every_stored_signal(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
#SIGNAL [ID1 CH2]
#SIGNAL [ID2]
M30
%channel2
M30
""", processes=2)
    assert len(board(result).stored()) == 2
    engine = result.runtime.engine
    engine.processes[2].vars["X"] = 1.0
    engine.reset()
    assert not board(result).stored() and board(result).stored_count == 0
    assert engine.processes[2].vars == {}


def test_two_channels_waiting_for_each_other_are_a_deadlock(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
N10 #WAIT [ID1 CH2]
N20 #SIGNAL [ID2 CH2]
M30
%channel2
N10 #WAIT [ID2 CH1]
N20 #SIGNAL [ID1 CH1]
M30
""", processes=2)
    (deadlock,) = events(result, "deadlock")
    assert sorted((b["proc"], b["n"]) for b in deadlock["cycle"]) == [(1, 10), (2, 10)]
    assert "#WAIT [ID1 CH2]" in deadlock["message"] and "#FLUSH" not in deadlock["message"]


def test_a_wait_on_two_channels_deadlocks_through_the_second(tmp_path: Path) -> None:
    # Channel 1 needs 1 from channels 2 and 3; channel 2 is busy (it would send), but
    # channel 3 waits for channel 1: a cycle through the WAIT's second channel.
    result = isg_sim(tmp_path, """%channel1
N10 #WAIT [ID1 CH2 CH3]
N20 #SIGNAL [ID2 CH3]
M30
%channel2
N10 G01 X100 F6000
N20 #FLUSH
N30 #SIGNAL [ID1 CH1]
M30
%channel3
N10 #WAIT [ID2 CH1]
N20 #SIGNAL [ID1 CH1]
M30
""")
    (deadlock,) = events(result, "deadlock")
    assert deadlock["t"] == 0.0
    assert sorted(b["proc"] for b in deadlock["cycle"]) == [1, 3]


def test_a_signal_counts_like_an_snd_on_the_fieldbus(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """%channel1
N5 #SIGNAL [ID12 CH2 CH3]
N6 #SIGNAL [ID13]
M30
%channel2
#WAIT [ID12 CH1]
M30
%channel3
#WAIT [ID12 CH1]
#WAIT [ID13]
M30
""")
    engine = result.runtime.engine
    assert engine.processes[1].stats.snd_sent == 3  # two directed signals and a broadcast
    assert [engine.processes[k].stats.snd_received for k in (2, 3)] == [1, 2]
    # The SND log: sender, first addressee (0: a broadcast), N, and the signal's number.
    assert [entry[1:] for entry in engine.snd_log] == [(1, 2, 5, 12), (1, 0, 6, 13)]
    sender, target, n, number = engine.last_snd
    assert (sender, target, n) == (1, 0, 6)
    signal = events(result, "signal", id=13)[0]
    # The last-SND number is the event counter's value at the signal's event.
    counted = [e for e in result.events if e["event"] in
               ("start", "end", "wait", "resume", "snd", "alarm", "signal")]
    assert number == [e["seq"] for e in counted].index(signal["seq"]) + 1


def test_control_flow_and_variables(tmp_path: Path) -> None:
    result = isg_sim(tmp_path, """#VAR
V.P.LIMIT = 5
V.P.STEP
#ENDVAR
V.P.STEP = 2
P1 = 0
$WHILE P1 < V.P.LIMIT
P1 = P1 + 1
$ENDWHILE
$IF P1 == 5 AND NOT [V.P.STEP > 2]
G01 X[P1 * V.P.STEP] Y[ABS[-3] + SQRT[16]] F6000
$ELSE
G01 X-1 F6000
$ENDIF
$IF P1 != 5
G01 Y-1
$ENDIF
M30
""", processes=1)
    assert result.outcome == "idle"
    p = result.runtime.engine.processes[1]
    assert (p.actual[0], p.actual[1]) == (10.0, 7.0)
    assert p.vars == {"LIMIT": 5.0, "STEP": 2.0}


def test_a_stall_on_a_broadcast_in_the_own_buffer_says_to_flush(tmp_path: Path) -> None:
    # Anyone could still send a broadcast, so this is no deadlock -- but when nothing is left
    # to run, the stall report names the #SIGNAL SYN sitting in the buffer, and the fix.
    result = isg_sim(tmp_path, """%channel1
N10 G01 X10 F6000
N20 #SIGNAL SYN [ID3]
N30 #WAIT [ID3]
M30
%channel2
M30
""", processes=2)
    assert result.outcome == "stall"
    (stall,) = events(result, "stall")
    (blocked,) = stall["blocked"]
    assert blocked["n"] == 30 and "waits for a broadcast signal 3" in blocked["reason"]
    assert "PROG.nc:3 N20" in blocked["reason"] and "add #FLUSH" in blocked["reason"]


def test_the_interpolator_starts_on_a_full_buffer_or_the_end(tmp_path: Path) -> None:
    """Spec 5.4: channel 1's move is buffered while its decoder waits (the buffer is not
    full), so it starts only when the signal lets the decoder reach the end; with
    nc.lookahead = 2 the buffer is full at once and the move starts at t = 0."""
    program = """%channel1
N10 G01 X100 F6000
N20 #WAIT [ID1 CH2]
N30 M30
%channel2
N10 G01 X50 F6000
N20 #FLUSH
N30 #SIGNAL [ID1 CH1]
N40 M30
"""
    result = isg_sim(tmp_path, program, processes=2)
    assert [(e["proc"], e["t"]) for e in events(result, "end")] == [(2, 0.5), (1, 1.5)]
    folder = tmp_path / "full"
    folder.mkdir()
    result = isg_sim(folder, program.replace("N10 G01 X100 F6000",
                                             "N10 G01 X100 F6000\nN11 G01 X200"),
                     processes=2, config="lookahead = 2")
    assert [(e["proc"], e["t"]) for e in events(result, "end")] == [(2, 0.5), (1, 2.0)]


def test_a_wait_event_names_only_the_channels_still_awaited(tmp_path: Path) -> None:
    """Channel 2's signal is stored before channel 1 waits: the wait is for channel 3 only,
    and its trace event says so (it listed both)."""
    result = isg_sim(tmp_path, """%channel1
N10 G01 X100 F6000
N20 #FLUSH
N30 #WAIT [ID1 CH2 CH3]
M30
%channel2
N10 #SIGNAL [ID1 CH1]
M30
%channel3
N10 G01 X100 F3000
N20 #FLUSH
N30 #SIGNAL [ID1 CH1]
M30
""")
    wait = next(e for e in events(result, "wait") if e["proc"] == 1 and e["n"] == 30)
    assert wait["on"]["from"] == [3]
    assert not events(result, "alarm")
