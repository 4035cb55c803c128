"""The manual's narrations hold under every interleaving the timing allows (spec 2.2).

Hypothesis rewrites the example programs with random motion (axis values, feeds), random PLC
delays in the script, random lookahead and either SND policy, runs them, and checks the
invariants of the narration on each trace.
"""

from __future__ import annotations

import random
import re
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway.sim import run_sim

from ..conftest import EXAMPLES

Event = dict[str, Any]
_AXIS = re.compile(r"(?<=[XYZ])-?\d+(\.\d+)?")
_FEED = re.compile(r"(?<=F)\d+")
_ARC = re.compile(r"G0?[23](?!\d)")
_ARC_WORD = re.compile(r"[IJK]-?\d+(\.\d+)?")


def randomise(text: str, rng: random.Random) -> str:
    out = []
    for line in text.splitlines():
        if not line.startswith(";") and "(" not in line:
            # Random end points do not lie on an arc's circle: arcs become straight moves.
            line = _ARC_WORD.sub("", _ARC.sub("G1", line))
            line = _AXIS.sub(lambda m: f"{rng.uniform(-200, 200):.3f}", line)
            line = _FEED.sub(lambda m: str(rng.randint(20, 20000)), line)
        out.append(line)
    return "\n".join(out) + "\n"


def prepare(tmp: Path, folder: str, seed: int, lookahead: int, latched: bool,
            delay: float) -> tuple[Path, Path | None]:
    rng = random.Random(seed)
    for program in (EXAMPLES / folder).glob("*.nc"):
        (tmp / program.name).write_text(randomise(program.read_text(), rng))
    snd = "latched" if latched else "rendezvous"
    (tmp / "ncgate.toml").write_text(
        f'[nc]\nlookahead = {lookahead}\nsnd = "{snd}"\n[nc.storage]\nMP0 = "."\n')
    script = EXAMPLES / folder / "script.toml"
    if not script.exists():
        return tmp / "ncgate.toml", None
    text = re.sub(r"after = [\d.]+", f"after = {delay}", script.read_text())
    text = re.sub(r"at = [\d.]+", f"at = {delay * 4}", text)
    (tmp / "script.toml").write_text(text)
    return tmp / "ncgate.toml", tmp / "script.toml"


def run(tmp: Path, folder: str, main: str, seed: int, lookahead: int, latched: bool,
        delay: float) -> list[Event]:
    config_path, script_path = prepare(tmp, folder, seed, lookahead, latched, delay)
    result = run_sim(load_config(config_path), main, load_script(script_path))
    assert result.outcome == "idle", result.events[-5:]
    assert not [e for e in result.events if e["event"] == "alarm"]
    return result.events


def runs_of(ev: list[Event], proc: int) -> list[tuple[int, int]]:
    """(first, last) event index of each program run of a process."""
    starts = [i for i, e in enumerate(ev) if e["event"] == "start" and e["proc"] == proc]
    ends = [i for i, e in enumerate(ev) if e["event"] == "end" and e["proc"] == proc]
    return list(zip(starts, ends, strict=True))


def passed(ev: list[Event], proc: int, line: int, run: tuple[int, int]) -> list[int]:
    """Events of a process, within one run, at blocks after a source line."""
    first, last = run
    return [i for i in range(first + 1, last + 1) if ev[i]["proc"] == proc
            and ev[i].get("line", 0) > line]


def nth(ev: list[Event], k: int, **match: Any) -> int:
    found = [i for i, e in enumerate(ev) if all(e.get(a) == b for a, b in match.items())]
    return found[k]


SETTINGS = settings(max_examples=40, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])
params = dict(seed=st.integers(0, 10**6), lookahead=st.sampled_from([0, 1, 2, 16]),
              latched=st.booleans(), delay=st.floats(0, 5).map(lambda d: round(d, 3)))


@SETTINGS
@given(**params)
def test_scheme3_narration_holds(tmp_path_factory: Any, seed: int, lookahead: int,
                                 latched: bool, delay: float) -> None:
    tmp = tmp_path_factory.mktemp("s3")
    ev = run(tmp, "scheme3", "PROG91", seed, lookahead, latched, delay)
    p2_runs, p3_runs = runs_of(ev, 2), runs_of(ev, 3)
    assert len(p2_runs) == len(p3_runs) == 2
    (p1_run,) = runs_of(ev, 1)
    p1_cycles = [i for i in range(p1_run[0], p1_run[1] + 1)
                 if ev[i]["event"] == "exe" and ev[i]["n"] == 1] + [p1_run[1] + 1]
    for k in range(2):
        # P2 never passes N16 (line 6) before P1 executed N24.
        snd24 = nth(ev, k, event="snd", proc=1, n=24)
        assert min(passed(ev, 2, 6, p2_runs[k])) > snd24
        # P3 does not pass N1 (line 2) before P1's N35.
        snd35 = nth(ev, k, event="snd", proc=1, n=35)
        assert min(passed(ev, 3, 2, p3_runs[k])) > snd35
        # P3 does not pass N20 (line 5) before P1's N60 stored SYVAR1 = 10.
        write60 = nth(ev, k, event="write", proc=1, n=60, value=10)
        assert min(passed(ev, 3, 5, p3_runs[k])) > write60
        # P1 does not pass N66 / N67 / N77 / N78 before P2 N85 / P3 N80 / P2 N99 / P3 N94.
        cycle = (p1_cycles[k], p1_cycles[k + 1] - 1)
        for p1_line, sender, sender_n in ((13, 2, 85), (14, 3, 80), (17, 2, 99), (18, 3, 94)):
            snd = nth(ev, k, event="snd", proc=sender, n=sender_n, to=1)
            assert min(passed(ev, 1, p1_line, cycle)) > snd
    # P2 does not pass N40 (line 8) before the PLC set SA10 = 1.
    write_sa10 = nth(ev, 0, event="write", var="SA10", value=1)
    assert min(passed(ev, 2, 8, p2_runs[0])) > write_sa10


@SETTINGS
@given(**params)
def test_mutual_narration_holds(tmp_path_factory: Any, seed: int, lookahead: int,
                                latched: bool, delay: float) -> None:
    tmp = tmp_path_factory.mktemp("mu")
    ev = run(tmp, "mutual", "MUT1", seed, lookahead, latched, delay)
    # N112, N233, N333 begin at one instant: P1 releases P2 and P3 together...
    t110 = ev[nth(ev, 0, event="snd", proc=1, n=110)]["t"]
    t111 = ev[nth(ev, 0, event="snd", proc=1, n=111)]["t"]
    assert t110 == t111
    # ... only after both said they were there.
    assert nth(ev, 0, event="snd", proc=2, n=231) < nth(ev, 0, event="snd", proc=1, n=110)
    assert nth(ev, 0, event="snd", proc=3, n=331) < nth(ev, 0, event="snd", proc=1, n=111)


@SETTINGS
@given(**params)
def test_conditional_narration_holds(tmp_path_factory: Any, seed: int, lookahead: int,
                                     latched: bool, delay: float) -> None:
    tmp = tmp_path_factory.mktemp("co")
    ev = run(tmp, "conditional", "COND1", seed, lookahead, latched, delay)
    (p1,), (p2,) = runs_of(ev, 1), runs_of(ev, 2)
    assert min(passed(ev, 2, 3, p2)) > nth(ev, 0, event="snd", proc=1, n=21)
    assert min(passed(ev, 1, 7, p1)) > nth(ev, 0, event="write", var="SA12", value=1)
    assert min(passed(ev, 1, 10, p1)) > nth(ev, 0, event="write", var="SK250", value=8)
    assert min(passed(ev, 2, 6, p2)) > nth(ev, 0, event="write", var="SYVAR2", value=31)
