"""Every scenario of examples/ under `ncgate sim`, checked on the trace against what its
README row says (order of events, who resumed whom, simulated times the spec fixes)."""

from __future__ import annotations

import io
import json
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway.cli.main import main
from ncgate.gateway.sim import SimResult, run_sim, write_trace

from ..conftest import EXAMPLES

Event = dict[str, Any]


def sim(folder: str, main_program: str, overrides: dict[str, Any] | None = None) -> SimResult:
    config = load_config(EXAMPLES / folder / "ncgate.toml", overrides=overrides)
    script_path = EXAMPLES / folder / "script.toml"
    script = load_script(script_path if script_path.exists() else None)
    return run_sim(config, main_program, script)


def index(events: list[Event], **match: Any) -> int:
    for i, e in enumerate(events):
        if all(e.get(k) == v for k, v in match.items()):
            return i
    raise AssertionError(f"no event {match}")


def after_block(events: list[Event], proc: int, line: int) -> list[int]:
    """Indexes of the events of a process at blocks after a source line."""
    return [i for i, e in enumerate(events) if e["proc"] == proc and e.get("line", 0) > line
            and e["event"] != "start"]


def test_conditional_waits() -> None:
    result = sim("conditional", "COND1")
    assert result.exit_status == 0 and result.outcome == "idle"
    ev = result.events
    # P2 ends N106 (line 3) only after P1's N21 SND.
    snd = index(ev, event="snd", proc=1, n=21, to=2)
    assert all(i > snd for i in after_block(ev, 2, 3))
    # P1 ends N131 only when SA12 = 1 (the script writes it at 3.0 s).
    write_sa12 = index(ev, event="write", var="SA12", value=1)
    resume_131 = index(ev, event="resume", proc=1, n=131)
    assert write_sa12 < resume_131 and ev[resume_131]["t"] == 3.0
    assert ev[resume_131]["by"] == "cond"
    # ... N147 only when K byte 250 = 8.
    write_sk = index(ev, event="write", var="SK250", value=8)
    assert all(i > write_sk for i in after_block(ev, 1, 10))
    # P2 ends N121 only after P1's N153 stored SYVAR2 = 31.
    write_sy = index(ev, event="write", var="SYVAR2", value=31, n=153, proc=1)
    resume_121 = index(ev, event="resume", proc=2, n=121)
    assert write_sy < resume_121 and ev[resume_121]["by"] == "cond"


@pytest.mark.parametrize("lookahead", [16, 0])
def test_mutual_wait(lookahead: int) -> None:
    result = sim("mutual", "MUT1", {"nc.lookahead": lookahead})
    assert result.exit_status == 0
    ev = result.events
    # Each waits for the others: P1 resumed by 2 and 3, P2 and P3 resumed by 1 (or passed
    # at once because P1's SND was already waiting for them).
    assert index(ev, event="snd", proc=2, n=231, to=1) < index(ev, event="snd", proc=1, n=110)
    assert index(ev, event="snd", proc=3, n=331, to=1) < index(ev, event="snd", proc=1, n=111)
    # N112, N233 and N333 start at the same simulated instant: P1 passes N111 at the moment
    # it releases P2 (N110) and P3 (N111).
    t_release = {ev[index(ev, event="snd", proc=1, n=n)]["t"] for n in (110, 111)}
    assert len(t_release) == 1
    (t,) = t_release
    # The decoders reach them together; with no lookahead the machines move together too,
    # after the longest motion before the syncs (P3: 10 mm at 200 mm/min = 3 s).
    assert t == (3.0 if lookahead == 0 else 0.0)
    ends = {e["proc"]: e["t"] for e in ev if e["event"] == "end"}
    moves = {1: 0.6, 2: 1.2, 3: 3.0}  # N112 X10->0 at F1000; N233 Y10->0 at F500; N333 at F200
    if lookahead == 0:
        assert ends == pytest.approx({k: t + v for k, v in moves.items()})


def test_scheme3_two_cycles() -> None:
    result = sim("scheme3", "PROG91")
    assert result.exit_status == 0 and result.outcome == "idle"
    ev = result.events
    starts = [(e["proc"], e["prog"]) for e in ev if e["event"] == "start"]
    assert starts == [(1, "PROG91"), (2, "PROG92"), (3, "PROG93"), (2, "PROG92"),
                      (3, "PROG93")]
    # P2 waits at N40 for SA10 = 1 from the PLC (script: 0.5 s after P2 starts waiting).
    wait_40 = index(ev, event="wait", proc=2, n=40)
    assert ev[wait_40]["on"] == {"cond": "SA10=1", "value": 0}
    write_sa10 = index(ev, event="write", var="SA10", value=1, who="script write[0]")
    assert ev[write_sa10]["t"] == pytest.approx(ev[wait_40]["t"] + 0.5)
    resume_40 = index(ev, event="resume", proc=2, n=40)
    assert write_sa10 < resume_40 and ev[resume_40]["by"] == "cond"
    # P3 at N20 for SYVAR1 = 10 from P1's N60, in both cycles.
    writes = [i for i, e in enumerate(ev) if e["event"] == "write" and e["var"] == "SYVAR1"
              and e["value"] == 10]
    assert [ev[i]["n"] for i in writes] == [60, 60]
    p3_starts = [i for i, e in enumerate(ev) if e["event"] == "start" and e["proc"] == 3]
    for cycle, (write, begin) in enumerate(zip(writes, p3_starts, strict=True)):
        later = [i for i in after_block(ev, 3, 5) if i > begin
                 and (cycle + 1 == len(p3_starts) or i < p3_starts[cycle + 1])]
        assert later and all(i > write for i in later)
    # P2 never passes N16 before P1 executed N24; P3 not N1 before P1's N35.
    for proc, wai_line, sender_n in ((2, 6, 24), (3, 2, 35)):  # PROG92 N16, PROG93 N1
        snds = [i for i, e in enumerate(ev) if e["event"] == "snd" and e["proc"] == 1
                and e["n"] == sender_n]
        assert len(snds) == 2
        p_starts = [i for i, e in enumerate(ev) if e["event"] == "start" and e["proc"] == proc]
        for snd, begin in zip(snds, p_starts, strict=True):
            passed = [i for i in after_block(ev, proc, wai_line) if i > begin]
            assert passed and min(passed) > snd
    # Per cycle P1 sends N24 to P2 and N35 to P3, and takes N85, N99 from P2 and N80, N94
    # from P3 at N66/N77 and N67/N78 (the order is checked by test_interleavings).
    delivered = sorted((e["proc"], e["to"], e["n"]) for e in ev if e["event"] == "snd")
    assert delivered == sorted(2 * [(1, 2, 24), (1, 3, 35), (2, 1, 85), (2, 1, 99),
                                    (3, 1, 80), (3, 1, 94)])
    # The second cycle's EXE re-issues on processes finishing with REL: P1 waits for them.
    exe_wait = index(ev, event="wait", proc=1, n=1)
    assert ev[exe_wait]["on"] == {"exe": 2}


def test_section4() -> None:
    result = sim("section4", "PR90")
    assert result.exit_status == 0
    ev = result.events
    starts = [(e["proc"], e["prog"], e["by"]) for e in ev if e["event"] == "start"]
    assert starts == [(1, "PR90", "script"), (2, "PR98", 1), (3, "PR99", 1), (2, "PR100", 1),
                      (3, "PR101", 1)]
    # PR99 does not pass N1 before PR90's N7 SND.
    snd7 = index(ev, event="snd", proc=1, n=7, to=3)
    first_p3 = index(ev, event="start", proc=3)
    assert all(i > snd7 for i in after_block(ev, 3, 2) if i > first_p3)
    # P1 passes N60/N61 only with the SNDs of PR98 N72 and PR99 N69.
    assert index(ev, event="snd", proc=2, n=72, to=1) < index(ev, event="exe", proc=1, n=62)
    assert index(ev, event="snd", proc=3, n=69, to=1) < index(ev, event="exe", proc=1, n=63)
    # PR100/PR101 start when P2/P3 are free: each start follows that process's end.
    for proc in (2, 3):
        end = index(ev, event="end", proc=proc)
        second = [i for i, e in enumerate(ev) if e["event"] == "start" and e["proc"] == proc][1]
        assert end < second and ev[end]["t"] == ev[second]["t"]


@pytest.mark.parametrize(("folder", "main_program"), [
    ("conditional", "COND1"), ("mutual", "MUT1"), ("scheme3", "PROG91"), ("section4", "PR90")])
def test_runs_are_deterministic(folder: str, main_program: str) -> None:
    outputs = []
    for _ in range(2):
        out = io.StringIO()
        write_trace(sim(folder, main_program), out)
        outputs.append(out.getvalue())
    assert outputs[0] == outputs[1] and outputs[0]


def test_cli_sim_writes_trace_and_gantt(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                         ) -> None:
    trace, gantt = tmp_path / "t.jsonl", tmp_path / "g.svg"
    folder = EXAMPLES / "scheme3"
    status = main(["sim", "PROG91", "--config", str(folder / "ncgate.toml"), "--script",
                   str(folder / "script.toml"), "--trace", str(trace), "--gantt", str(gantt)])
    assert status == 0
    out = capsys.readouterr().out
    assert "every program ended" in out
    assert out.splitlines()[0].split()[:4] == ["proc", "programs", "blocks", "running"]
    p1 = next(line for line in out.splitlines() if line.startswith("P1 "))
    assert p1.split()[1] == "1" and p1.split()[6:9] == ["4", "8", "0"]
    lines = trace.read_text().splitlines()
    events = [json.loads(line) for line in lines]
    assert [e["seq"] for e in events] == list(range(1, len(events) + 1))
    assert all(line.startswith('{"seq": ') and '"t": ' in line for line in lines)
    assert all(len(line.split('"t": ')[1].split(",")[0].split(".")[1]) == 6 for line in lines)
    root = ET.parse(gantt).getroot()
    texts = "".join(root.itertext())
    assert "P1" in texts and "time (s)" in texts and "SA10=1" in texts
    svg = "{http://www.w3.org/2000/svg}"
    arrows = [el for el in root.iter(f"{svg}line") if el.get("marker-end")]
    assert len(arrows) == sum(1 for e in events if e["event"] == "snd")


def test_cli_sim_exit_statuses(tmp_path: Path) -> None:
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n')
    (tmp_path / "A.nc").write_text("N1(WAI,SA10=1)\nN2M30\n")
    (tmp_path / "B.nc").write_text("N1E1=1/0\n")
    (tmp_path / "C.nc").write_text("N1GXY\n")
    (tmp_path / "D.nc").write_text("N1G1X1000F6000\nN2M30\n")
    cfg = ["--config", str(tmp_path / "ncgate.toml")]
    assert main(["sim", *cfg]) == 1  # stall
    assert main(["sim", "B", *cfg]) == 1  # alarm
    assert main(["sim", "C", *cfg]) == 2  # program error
    assert main(["sim", "NOPE", *cfg]) == 2
    assert main(["sim", "D", *cfg]) == 0
    assert main(["sim", "D", "--until", "3", *cfg]) == 0
    # A stall is a stall even before --until: nothing would ever change.
    assert main(["sim", "A", "--until", "3", *cfg]) == 1
    bad = tmp_path / "bad.toml"
    bad.write_text('[[write]]\nat = 1\nset = "SA10=2"\n')
    assert main(["sim", "D", *cfg, "--script", str(bad)]) == 2


def test_stall_report_names_the_blocked(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n')
    (tmp_path / "A.nc").write_text("N7(WAI,SA10=1)\nN8M30\n")
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 1
    out = capsys.readouterr().out
    assert "stall: every process is blocked" in out
    assert "P1 A.nc:1 N7 (WAI,SA10=1) waits for SA10=1 (now 0)" in out


def test_builtin_default_simulates_with_no_files(capsys: pytest.CaptureFixture[str]) -> None:
    # `ncgate sim PROG91` works on a fresh install: the built-in config brings its PLC script.
    assert main(["sim", "PROG91"]) == 0
    assert "every program ended" in capsys.readouterr().out
    # Without a PLC nobody sets SA10: the closed simulation stalls at P2's N40, and says so.
    result = run_sim(load_config(None), "PROG91", load_script(None))
    assert result.outcome == "stall"
    (stall,) = [e for e in result.events if e["event"] == "stall"]
    assert {(b["proc"], b["n"]) for b in stall["blocked"]} >= {(2, 40)}


def test_lazy_parse_starts_a_huge_program_without_parsing_it(tmp_path: Path) -> None:
    # 200,000 blocks, the last one bad: with nc.lazy_parse the decoder starts at once and
    # only the blocks it reaches are parsed; the bad block is an alarm when it is reached.
    body = "".join(f"N{i}G1X{i % 50}F6000\n" for i in range(200_000))
    (tmp_path / "BIG.nc").write_text("N1(WAI,SA1=1)\n" + body + "N9GXY\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "BIG"\nlazy_parse = true\n')
    config = load_config(tmp_path / "ncgate.toml")
    result = run_sim(config, "BIG", load_script(None), until=0.0)
    _, program = next(iter(result.runtime.store._cache.values()))
    parsed = sum(1 for b in program._blocks if b is not None)
    assert parsed <= 2  # N1 and nothing past the wait
    assert result.events[-1]["event"] == "stall"
    # Without lazy parsing the bad block stops the program before it starts.
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "BIG"\n')
    with pytest.raises(Exception, match="G needs a value"):
        run_sim(load_config(tmp_path / "ncgate.toml"), "BIG", load_script(None))


def test_lazy_parse_bad_block_is_an_alarm_where_it_stands(tmp_path: Path) -> None:
    (tmp_path / "A.nc").write_text("N1G1X10F600\nN2GXY\nN3M30\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\nlazy_parse = true\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "A", load_script(None))
    (alarm,) = [e for e in result.events if e["event"] == "alarm"]
    assert (alarm["code"], alarm["line"], alarm["t"]) == ("AL121", 2, 0.0)
    assert "A.nc:2:3: NC003: G needs a value" in alarm["message"]
