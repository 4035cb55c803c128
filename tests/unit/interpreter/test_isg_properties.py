"""Property test of stored signals: random signal/wait programs in 2-3 channels.  Whatever
happens (the end, a stall, a deadlock, an orphan wait), every signal a WAIT consumed was sent,
to that channel, and none is consumed more often than it may be.

Each directed signal carries a serial number in P[0] and each decoder-level WAIT stores the
P[0] it took into a parameter of its own, so consumption is read off the channels' parameters
after the run and checked against the ``signal`` events of the trace."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from tempfile import TemporaryDirectory

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from .isg_harness import isg_sim

SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
SLOT0 = 100  # the WAITs' P[0] land in P100, P101, ...


@st.composite
def programs(draw: st.DrawFn) -> tuple[int, str, int]:
    channels = draw(st.integers(min_value=2, max_value=3))
    ids = st.integers(min_value=1, max_value=2)  # few numbers: signals meet their WAITs
    serial = 0
    lines: list[str] = []
    for me in range(1, channels + 1):
        lines.append(f"%channel{me}")
        slot = SLOT0
        for _ in range(draw(st.integers(min_value=0, max_value=10))):
            kind = draw(st.sampled_from(["signal", "signal", "wait", "wait", "move", "flush",
                                         "syn_signal", "syn_wait", "broadcast"]))
            ident = draw(ids)
            other = draw(st.integers(min_value=1, max_value=channels))
            if kind in ("signal", "syn_signal"):
                serial += 1
                syn = " SYN" if kind == "syn_signal" else ""
                count = draw(st.sampled_from(["", "", " COUNT2"]))
                lines.append(f"#SIGNAL{syn} [ID{ident}{count} P[0]={serial} CH{other}]")
            elif kind == "broadcast":
                serial += 1
                lines.append(f"#SIGNAL [ID{ident} COUNT2 P[0]={serial}]")
            elif kind == "wait":
                source = f"CH{other}" if draw(st.booleans()) else ""
                lines.append(f"#WAIT [ID{ident} P[0]=P{slot} {source}]")
                slot += 1
            elif kind == "syn_wait":
                lines.append(f"#WAIT SYN [ID{ident} CH{other}]")
            elif kind == "move":
                lines.append(f"G01 X{draw(st.integers(min_value=1, max_value=50))} F6000")
            else:
                lines.append("#FLUSH")
        lines.append("M30")
    lookahead = draw(st.sampled_from([0, 1, 2, 16]))
    return channels, "\n".join(lines) + "\n", lookahead


@SETTINGS
@given(programs())
def test_every_consumed_signal_was_sent_and_none_twice(case: tuple[int, str, int]) -> None:
    channels, text, lookahead = case
    with TemporaryDirectory() as folder:
        result = isg_sim(Path(folder), text, processes=channels,
                         config=f"lookahead = {lookahead}", until=3600)
    engine = result.runtime.engine
    sent: dict[int, tuple[int, list[int] | str, int]] = {}  # serial -> sender, to, uses
    for e in result.events:
        if e["event"] == "signal":
            serial = int(e["params"]["0"])
            uses = e["count"] or 1
            sent[serial] = (e["proc"], e["to"], uses)
    taken: Counter[int] = Counter()
    for k in range(1, channels + 1):
        for value in engine.processes[k].E[SLOT0:SLOT0 + 10]:
            if value:
                serial = int(value)
                assert serial in sent, f"P{k} consumed serial {serial}, which was never sent"
                _, to, _ = sent[serial]
                assert to == "all" or k in to, f"P{k} took serial {serial} sent to {to}"
                taken[serial] += 1
    for serial, times in taken.items():
        _, to, uses = sent[serial]
        # A directed signal to n channels is n signals of `uses` each; a broadcast, `uses`.
        allowed = uses * (1 if to == "all" else len(to))
        assert times <= allowed, f"serial {serial} consumed {times} times, allowed {allowed}"
    # Every reception counted on the fieldbus is a consumption; SYN waits take no parameter,
    # so they count but leave no serial behind.
    received = sum(engine.processes[k].stats.snd_received for k in range(1, channels + 1))
    assert received >= sum(taken.values())
