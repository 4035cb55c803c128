"""``ncgate sweep``: every variant of a spec as an independent sim, into one table.

Real processes throughout: the sweep runs as its own ``ncgate sweep`` process, its local
workers are processes, a Dask cluster is a LocalCluster on loopback started here, and a killed
worker is killed with SIGKILL.  Expected verdicts come from the examples' READMEs and from
``ncgate sim``'s own output, never from the sweep's code.
"""

from __future__ import annotations

import csv
import os
import random
import re
import shlex
import signal
import stat
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from ..conftest import EXAMPLES

SNDS = ["rendezvous", "latched"]
LOOKAHEADS = [0, 4, 16]
EXAMPLES_SPEC = f"""
[sweep]
examples = ["*"]
[grid]
"nc.snd" = {SNDS!r}
"nc.lookahead" = {LOOKAHEADS!r}
""".replace("'", '"')


def ncgate(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ncgate", *args], cwd=cwd, text=True,
                          capture_output=True, timeout=timeout)


def start(*args: str, cwd: Path, env: dict[str, str] | None = None
          ) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "ncgate", *args], cwd=cwd, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)


def terminated_once(sweep: subprocess.Popen[str], ready: Callable[[], bool],
                    what: str) -> tuple[str, str]:
    """SIGTERM to ``sweep`` once ``ready()`` holds (it must still run then); its output."""
    try:
        wait_for(lambda: ready() or sweep.poll() is not None, what)
        assert sweep.poll() is None, "the sweep ended before it could be stopped"
        sweep.send_signal(signal.SIGTERM)
        return sweep.communicate(timeout=60)
    finally:
        sweep.kill()


def rows_of(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as file:
        return list(csv.DictReader(file))


def wait_for(condition: Callable[[], bool], what: str, seconds: float = 120) -> None:
    """Until ``condition()`` holds (an event seen by polling; no fixed sleep decides)."""
    deadline = time.monotonic() + seconds
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def runnable_examples() -> dict[str, list[str]]:
    """Each example folder with a main program beside its config: its scripts (scenarios)."""
    import tomllib

    out = {}
    for folder in sorted(p for p in EXAMPLES.iterdir() if (p / "ncgate.toml").is_file()):
        main = tomllib.loads((folder / "ncgate.toml").read_text())["nc"].get("main")
        if main and (folder / f"{main}.nc").is_file():
            suite = sorted((folder / "scenarios").glob("*.toml"))
            script = folder / "script.toml"
            out[folder.name] = [str(s) for s in suite] or (
                [str(script)] if script.is_file() else [""])
    return out


@pytest.fixture(scope="module")
def examples_sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The examples x both SND policies x 3 look-ahead depths, swept once (2 workers)."""
    folder = tmp_path_factory.mktemp("sweep")
    (folder / "spec.toml").write_text(EXAMPLES_SPEC)
    done = ncgate("sweep", "spec.toml", "-o", "first.csv", "--workers", "2", cwd=folder)
    assert done.returncode == 1, done.stderr  # the hazard example is not ok at depth 16
    assert not (folder / "first.csv.parts").exists()
    return folder


def test_the_table_has_one_row_per_variant_sorted_by_id(examples_sweep: Path) -> None:
    rows = rows_of(examples_sweep / "first.csv")
    header = next(csv.reader((examples_sweep / "first.csv").open()))
    for name in ("id", "verdict", "program", "nc.snd", "nc.lookahead", "cycle_s", "alarms",
                 "hazards", "report", "command"):
        assert name in header
    expected = {(name, script, snd, str(depth))
                for name, scripts in runnable_examples().items() for script in scripts
                for snd in SNDS for depth in LOOKAHEADS}
    seen = {(Path(r["program"]).parent.name, r["script"], r["nc.snd"], r["nc.lookahead"])
            for r in rows}
    assert len(rows) == len(expected) == len(seen)
    assert seen == expected
    ids = [r["id"] for r in rows]
    assert ids == sorted(ids) and len(set(ids)) == len(ids)


def test_the_examples_readmes_verdicts(examples_sweep: Path) -> None:
    rows = rows_of(examples_sweep / "first.csv")

    def verdicts(example: str, depth: int | None = None, snd: str = "") -> set[str]:
        return {r["verdict"] for r in rows if Path(r["program"]).parent.name == example
                and (depth is None or r["nc.lookahead"] == str(depth))
                and r["nc.snd"].startswith(snd)}

    # hazard/README.md: the control's default look-ahead makes N3's plain SND act early,
    # one hazard; with lookahead = 0 (and the default rendezvous SND) it is gone.
    assert verdicts("hazard", 16) == {"hazard"}
    assert verdicts("hazard", 0, "rendezvous") == {"ok"}
    # isg_no_flush/README.md: without #FLUSH the #WAIT deadlocks, naming the WAIT.
    no_flush = [r for r in rows if "isg_no_flush" in r["program"] and r["nc.lookahead"] != "0"]
    assert no_flush and {r["verdict"] for r in no_flush} == {"deadlock"}
    assert all("AL140" in r["alarms"] and "#WAIT" in r["signature"] for r in no_flush)
    # machine/: every scenario of the suite passes (each expects its own alarm).
    assert verdicts("machine") == {"ok"}
    assert verdicts("mutual", 0) == {"ok"}


def test_a_second_run_gives_the_same_bytes(examples_sweep: Path) -> None:
    again = ncgate("sweep", "spec.toml", "-o", "second.csv", "--workers", "1",
                   cwd=examples_sweep)
    assert again.returncode == 1, again.stderr
    assert (examples_sweep / "second.csv").read_bytes() == \
        (examples_sweep / "first.csv").read_bytes()


def sim_verdict(out: str, status: int) -> tuple[str, str]:
    """The verdict and cycle time ``ncgate sim``'s own report gives, read from its text."""
    cycle = re.findall(r"^simulated (\d+\.\d{3}) s", out, re.M)
    assert len(cycle) == 1, out
    if re.search(r"^(PASS|FAIL) ", out, re.M):
        return ("expect_failed" if re.search(r"^FAIL ", out, re.M) else "ok"), cycle[0]
    if re.search(r"^\[[\d.]+\] deadlock: ", out, re.M):
        return "deadlock", cycle[0]
    if re.search(r"^\[[\d.]+\] stall: ", out, re.M):
        return "stall", cycle[0]
    if re.search(r"^\[[\d.]+\] (P\d+|PLC) alarm AL\d+", out, re.M):
        return "alarm", cycle[0]
    # "[t] P2 hazard PROG92.nc:10 N85: ..." or, with no block, "[t] P0 hazard: script ..."
    if re.search(r"^\[[\d.]+\] P\d+ hazard[ :]", out, re.M):
        return "hazard", cycle[0]
    assert status == 0, out
    return "ok", cycle[0]


@pytest.mark.timeout(300)  # twenty `ncgate sim` processes one after another: 60-100 s under
# load (2 cores, xdist, CPU hogs), and with the examples' sweep set up first, past 120 s
def test_twenty_rows_rerun_by_their_command_agree(examples_sweep: Path) -> None:
    rows = rows_of(examples_sweep / "first.csv")
    chosen = random.Random(20).sample(rows, 20)
    kinds = set()
    for row in chosen:
        words = shlex.split(row["command"])
        assert words[:2] == ["ncgate", "sim"]
        done = ncgate(*words[1:], cwd=examples_sweep, timeout=120)
        assert done.returncode in (0, 1), done.stderr
        verdict, cycle = sim_verdict(done.stdout, done.returncode)
        assert (verdict, cycle) == (row["verdict"], f"{float(row['cycle_s']):.3f}"), row
        kinds.add(verdict)
    assert len(kinds) >= 2  # the sample is not all of one kind: it compares something


# -- robustness: budgets, timeouts, crashes, a bad spec --------------------------------------


LOOPS = {
    # Loops forever in no time: only the wall timeout stops it (no runaway limit here).
    "SPIN": 'E1=0\n"L"\n(BLT,E1,1,L)\nM30\n',
    # Moves forever: the virtual-time budget stops it.
    "LOOP": 'E1=0\n"L"\nG1X10F6000\nG1X0\n(BLT,E1,1,L)\nM30\n',
    "OK": "G1X10F600\nM30\n",  # 1 s at 600 mm/min over 10 mm
    "BAD": "N1G1X10F600\nN2(WAI,SA10=1\nM30\n",  # the ')' missing: sim refuses it, exit 2
}


def test_a_hang_is_a_timeout_row_and_the_sweep_goes_on(tmp_path: Path) -> None:
    (tmp_path / "progs").mkdir()
    for name, text in LOOPS.items():
        (tmp_path / "progs" / f"{name}.nc").write_text(text)
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["progs/*.nc"]\nbudget_s = 30\n'
                                        '[grid]\n"nc.runaway_blocks" = [0]\n')
    done = ncgate("sweep", "spec.toml", "--timeout", "2", "--workers", "2", cwd=tmp_path)
    assert done.returncode == 1, done.stderr
    rows = {Path(r["program"]).stem: r for r in rows_of(tmp_path / "spec.csv")}
    assert rows["OK"]["verdict"] == "ok" and float(rows["OK"]["cycle_s"]) == 1.0
    assert rows["SPIN"]["verdict"] == "timeout"
    assert "wall timeout of 2 s" in rows["SPIN"]["report"]
    assert rows["LOOP"]["verdict"] == "timeout"
    assert float(rows["LOOP"]["cycle_s"]) == 30.0
    assert "budget" in rows["LOOP"]["report"]
    # The budget's row reproduces with --until at the budget: sim stops there.
    assert rows["LOOP"]["command"].endswith("--until 30.0")
    assert rows["BAD"]["verdict"] == "error"
    assert rows["BAD"]["report"].startswith("BAD.nc:2:14: error NC012")
    alone = ncgate(*shlex.split(rows["BAD"]["command"])[1:], cwd=tmp_path)
    assert alone.returncode == 2 and rows["BAD"]["report"] in alone.stderr
    assert "4 variants: 1 ok, 2 timeout, 1 error" in done.stdout


def test_a_terminal_gets_a_progress_line_with_rate_and_eta(tmp_path: Path) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [50, 100, 150]\n')
    code = ("import sys; from pathlib import Path\n"
            "from ncgate.gateway.sweep.main import Options, run_sweep\n"
            "from ncgate.gateway.sweep.spec import load_spec\n"
            "spec = load_spec('spec.toml')\n"
            "status, rows = run_sweep(spec, Options(Path('out.csv'), workers=1, progress=True))\n"
            "sys.exit(status)\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          timeout=120)  # bytes: text mode would read the \r as a new line
    assert done.returncode == 0, done.stderr
    assert re.search(rb"\r3/3 variants  [\d.]+/s  ETA 0 s", done.stderr), done.stderr
    quiet = ncgate("sweep", "spec.toml", cwd=tmp_path)  # not a terminal: no progress line
    assert quiet.returncode == 0 and "variants/s" not in quiet.stderr + quiet.stdout


def test_an_exception_is_a_crash_row_with_its_last_line(monkeypatch: pytest.MonkeyPatch,
                                                         tmp_path: Path) -> None:
    import ncgate.gateway.sim as sim
    from ncgate.gateway.sweep.run import run_variant
    from ncgate.gateway.sweep.spec import load_spec

    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n')
    variant = load_spec(tmp_path / "spec.toml").variants[0]
    assert run_variant(variant, 10)["verdict"] == "ok"

    def broken(*args: object, **kwargs: object) -> None:
        raise ZeroDivisionError("a bug of ncgate")

    monkeypatch.setattr(sim, "run_sim", broken)
    result = run_variant(variant, 10)
    assert result["verdict"] == "crash"
    assert result["report"] == "ZeroDivisionError: a bug of ncgate"


def misbehaving_spec(folder: Path, programs: tuple[str, ...]) -> Path:
    for name in programs:
        (folder / name).write_text(LOOPS["OK"])
    (folder / "spec.toml").write_text(f'[sweep]\nprograms = {list(programs)!r}\n[grid]\n'
                                      '"nc.feed_override" = [50, 100]\n'.replace("'", '"'))
    return folder / "spec.toml"


def test_the_pool_survives_a_dying_and_a_stuck_worker(monkeypatch: pytest.MonkeyPatch,
                                                      tmp_path: Path) -> None:
    from ncgate.gateway.sweep import pool
    from ncgate.gateway.sweep.pool import run_local
    from ncgate.gateway.sweep.spec import load_spec

    from .sweep_runners import misbehaving

    spec = load_spec(misbehaving_spec(tmp_path, ("DIE.nc", "HANG.nc", "OK.nc", "FINE.nc")))
    # The wall timeout is every variant's: at 1 s a loaded machine (2 cores, xdist, CPU hogs)
    # ran OK past it, a timeout row.  10 s is far beyond OK's run; the grace shortened
    # instead keeps HANG's wait short (timeout + grace, then its worker is killed).
    monkeypatch.setattr(pool, "GRACE_S", 1.0)
    got = list(run_local(spec.variants, 2, 10.0, runner=misbehaving))
    ids = [v.id for v, _ in got]
    assert sorted(ids) == sorted(v.id for v in spec.variants)  # each once, none lost
    by = {(Path(v.program).stem, dict(v.sets)["nc.feed_override"]): r for v, r in got}
    for feed in (50, 100):
        assert by["DIE", feed]["verdict"] == "crash"
        assert "died 2 times (exit status 3)" in by["DIE", feed]["report"]
        assert by["HANG", feed]["verdict"] == "timeout"
        assert "was killed" in by["HANG", feed]["report"]
        # 10 mm at 600 mm/min x the override: 2 s at 50 %, 1 s at 100 %
        assert by["OK", feed]["verdict"] == by["FINE", feed]["verdict"] == "ok"
        assert by["OK", feed]["cycle_s"] == 100 / feed


@pytest.mark.parametrize(("spec", "said"), [
    ('[sweep]\nprograms = ["OK.nc"]\n[grid]\n"nc.lookahead" = [0, -1]\n', "nc.lookahead"),
    ('[sweep]\nprograms = ["OK.nc"]\n[grid]\n"nc.bogus" = [1]\n', "nc.bogus: unknown key"),
    ('[sweep]\nprograms = ["OK.nc"]\nbogus = 1\n', "sweep.bogus: unknown key"),
    ('[sweep]\nprograms = ["nothing/*.nc"]\n', "sweep.programs: nothing/*.nc: no such file"),
    ('[sweep]\nprograms = ["OK.nc"]\n[random]\nsamples = 3\n"nc.feed_override" = [150, 50]\n',
     "random.nc.feed_override"),
    ('[sweep]\nprograms = ["OK.nc"]\n[random]\nsamples = 3\n"nc.feed_override" = [50, 500]\n',
     "nc.feed_override"),
    ('[sweep]\nexamples = ["nope"]\n', "sweep.examples: no runnable example 'nope'"),
    # N is --explore's: samples in [explore] would override it unsaid
    ('[sweep]\nprograms = ["OK.nc"]\n[explore]\nsamples = 3\n"nc.feed_override" = [50, 150]\n',
     "explore.samples: unknown key"),
])
def test_a_bad_spec_is_exit_2_naming_the_file_and_the_key(tmp_path: Path, spec: str,
                                                          said: str) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "bad.toml").write_text(spec)
    done = ncgate("sweep", "bad.toml", cwd=tmp_path)
    assert done.returncode == 2
    assert "bad.toml" in done.stderr and said in done.stderr, done.stderr
    assert not (tmp_path / "bad.csv").exists()


def test_random_samples_are_seeded_and_in_range(tmp_path: Path) -> None:
    from ncgate.gateway.sweep.spec import load_spec

    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    text = ('[sweep]\nprograms = ["OK.nc"]\n[grid]\n"nc.snd" = ["rendezvous", "latched"]\n'
            '[random]\nseed = {}\nsamples = 25\n"nc.feed_override" = [50, 150]\n'
            '"plc.scan_ms" = [1, 20]\n"nc.rapid_mm_min" = [1000.0, 20000.0]\n')
    (tmp_path / "a.toml").write_text(text.format(7))
    (tmp_path / "b.toml").write_text(text.format(8))
    a, again, b = (load_spec(tmp_path / n) for n in ("a.toml", "a.toml", "b.toml"))
    assert len(a.variants) == 2 * 25
    assert [v.sets for v in a.variants] == [v.sets for v in again.variants]
    assert {v.sets for v in a.variants} != {v.sets for v in b.variants}
    for v in a.variants:
        values = dict(v.sets)
        assert type(values["nc.feed_override"]) is int and 50 <= values["nc.feed_override"] <= 150
        assert 1 <= values["plc.scan_ms"] <= 20
        assert 1000.0 <= values["nc.rapid_mm_min"] <= 20000.0


# -- --explore finds a race --------------------------------------------------------------


# P1 moves for 1 s at 100 % feed, then releases P2 with an SND and waits for its answer; P2,
# once released, waits for the PLC's SA10 and answers.  The PLC (the script) raises SA10 at
# 0.5 s and drops it at 1.2 s: when P1's SND comes after 1.2 s (a feed override below about
# 83 %), P2 waits for an SA10 that never comes back while P1 waits for P2 -- a stall that the
# program's own run at 100 % never shows.
RACE = {
    "A.nc": "N1(EXE,2,B)\nN2G1X100F6000\nN3(SND,2)\nN4(WAI,2)\nN5M30\n",
    "B.nc": "N1(WAI,1)\nN2(WAI,SA10=1)\nN3(SND,1)\nN4M30\n",
    "ncgate.toml": '[nc]\nprocesses = 2\nlookahead = 0\nmain = "A"\n[nc.storage]\nMP0 = "."\n',
    "plc.toml": '[[write]]\nat = 0.5\nset = "SA10=1"\n[[write]]\nat = 1.2\nset = "SA10=0"\n',
    "spec.toml": '[sweep]\nprograms = ["A.nc"]\nscript = "plc.toml"\n',
}


@pytest.mark.parametrize(("sets", "expected"), [
    ((), [0.5, 1.2]),
    (("sim.input_delay_scale=2",), [1.0, 2.4]),
    (("sim.input_delay_scale=0.5",), [0.25, 0.6]),
])
def test_sim_scales_the_scripts_input_times(tmp_path: Path, sets: tuple[str, ...],
                                            expected: list[float]) -> None:
    for name, text in RACE.items():
        (tmp_path / name).write_text(text)
    args = [w for item in sets for w in ("--set", item)]
    done = ncgate("sim", "A", "--config", "ncgate.toml", "--script", "plc.toml", "--trace",
                  "t.jsonl", "--until", "3", *args, cwd=tmp_path)
    assert done.returncode in (0, 1), done.stderr
    import json

    writes = [e for e in map(json.loads, (tmp_path / "t.jsonl").read_text().splitlines())
              if e["event"] == "write" and e["var"] == "SA10"]
    assert [w["t"] for w in writes] == pytest.approx(expected, abs=1e-6)


def test_sim_jitters_each_input_by_a_draw_of_its_seed(tmp_path: Path) -> None:
    import json

    for name, text in RACE.items():
        (tmp_path / name).write_text(text)
    done = ncgate("sim", "A", "--config", "ncgate.toml", "--script", "plc.toml", "--trace",
                  "t.jsonl", "--until", "3", "--set", "sim.input_jitter_ms=300", "--set",
                  "sim.seed=11", cwd=tmp_path)
    assert done.returncode in (0, 1), done.stderr
    draws = random.Random(11)
    expected = [0.5 + draws.uniform(0, 0.3), 1.2 + draws.uniform(0, 0.3)]
    writes = [e["t"] for e in map(json.loads, (tmp_path / "t.jsonl").read_text().splitlines())
              if e["event"] == "write" and e["var"] == "SA10"]
    assert writes == pytest.approx(expected, abs=1e-6)


def test_explore_finds_the_planted_race_and_prints_its_reproducer(tmp_path: Path) -> None:
    for name, text in RACE.items():
        (tmp_path / name).write_text(text)
    plain = ncgate("sim", "A", "--config", "ncgate.toml", "--script", "plc.toml", cwd=tmp_path)
    assert plain.returncode == 0 and "every program ended" in plain.stdout  # hidden at 100 %
    done = ncgate("sweep", "spec.toml", "--explore", "40", "--workers", "2", cwd=tmp_path)
    assert done.returncode == 1, done.stderr
    rows = rows_of(tmp_path / "spec-explore.csv")
    assert len(rows) == 40
    for row in rows:
        # The PLC drops SA10 at 1.2 s x the delay scale + the second of the seed's draws
        # (docs/config.md: one draw per scripted input, in the script's order); P1's SND comes
        # when its move (1 s at 100 %) and two blocks' processing time are done.
        draws = random.Random(int(row["sim.seed"]))
        jitter = float(row["sim.input_jitter_ms"]) / 1000
        late = [draws.uniform(0.0, jitter) for _ in range(2)][1] if jitter else 0.0
        drop = 1.2 * float(row["sim.input_delay_scale"]) + late
        snd = 100 / int(row["nc.feed_override"]) + 2 * float(row["nc.block_time_ms"]) / 1000
        assert row["verdict"] == ("stall" if snd > drop else "ok"), row
    assert {r["verdict"] for r in rows} == {"ok", "stall"}
    found = re.search(r"^stall in (\d+) of 40 variants: (.*)\n  first in ([\d.]+) s of "
                      r"simulated time: (\w+)\n  smallest reproducer: (.*)$", done.stdout, re.M)
    assert found, done.stdout
    assert int(found[1]) == sum(r["verdict"] == "stall" for r in rows)
    assert "P1 A.nc:4 (WAI,2)" in found[2] and "P2 B.nc:2 (WAI,SA10=1)" in found[2]
    stalls = [r for r in rows if r["verdict"] == "stall"]
    first = min(stalls, key=lambda r: float(r["cycle_s"]))
    assert found[4] == first["id"] and found[3] == f"{float(first['cycle_s']):.3f}"
    reproducer = shlex.split(found[5])
    # The cell has no PLC logic: its scan period cannot matter, and the reduction drops it;
    # what it keeps is a subset of the first stall's own values.
    assert "plc.scan_ms" not in found[5]
    kept = {w for w in reproducer if "=" in w}
    assert kept < {w for w in shlex.split(first["command"]) if "=" in w}
    again = ncgate(*reproducer[1:], cwd=tmp_path)
    assert again.returncode == 1 and "stall: every process is blocked" in again.stdout


def test_the_pytest_kit_makes_one_test_per_variant_under_xdist(tmp_path: Path) -> None:
    cell = tmp_path / "cell"
    cell.mkdir()
    for name, text in RACE.items():
        (cell / name).write_text(text)
    # 100 %: the SND comes at 1 s, in time; 70 %: at 1.43 s, after the PLC dropped SA10.
    (cell / "spec.toml").write_text(RACE["spec.toml"] + '[grid]\n"nc.feed_override" = '
                                    "[100, 70, 90, 80]\n")
    (tmp_path / "test_library.py").write_text(
        "from ncgate.gateway.testing import ncgate_sweep\n\n"
        'test_library = ncgate_sweep("cell/spec.toml")\n')
    done = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "-p", "no:cacheprovider",
                           "-q", "test_library.py"], cwd=tmp_path, text=True,
                          capture_output=True, timeout=300)
    assert done.returncode == 1, done.stdout + done.stderr
    assert re.search(r"^2 failed, 2 passed", done.stdout.splitlines()[-1]), done.stdout
    failed = re.findall(r"^FAILED test_library.py::test_library\[(\w+)-A-nc.feed_override="
                        r"(\d+)\]", done.stdout, re.M)
    assert sorted(f for _, f in failed) == ["70", "80"]
    assert "stall: [1.429] stall: every process is blocked" in done.stdout  # 1 s / 70 %
    assert ("reproduce: ncgate sim A --config cell/ncgate.toml --script cell/plc.toml --set "
            "nc.feed_override=70") in done.stdout


def test_a_dotted_key_quoted_or_not_is_the_same_key(tmp_path: Path) -> None:
    from ncgate.gateway.sweep.spec import load_spec

    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "a.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n[grid]\n'
                                     '"nc.snd" = ["rendezvous", "latched"]\n')
    (tmp_path / "b.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n[grid]\n'
                                     'nc.snd = ["rendezvous", "latched"]\n')
    a, b = load_spec(tmp_path / "a.toml"), load_spec(tmp_path / "b.toml")
    assert a.keys == b.keys == ["nc.snd"]
    assert [v.id for v in a.variants] == [v.id for v in b.variants]
    assert len(a.variants) == 2


# -- resume after kill -9, parquet --------------------------------------------------------


BIG_SPEC = """
[sweep]
examples = ["scheme3", "hazard", "mutual", "section4", "plclogic", "isg_paths"]
[grid]
"nc.snd" = ["rendezvous", "latched"]
"nc.lookahead" = [0, 1, 2, 4, 8, 16]
"nc.feed_override" = [50, 80, 100, 120, 150]
"""


@pytest.fixture(scope="module")
def big_sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("big")
    (folder / "spec.toml").write_text(BIG_SPEC)
    done = ncgate("sweep", "spec.toml", "-o", "whole.csv", "--workers", "2", cwd=folder)
    assert done.returncode == 1, done.stderr
    return folder


def parts_of(folder: Path, output: str) -> list[Path]:
    return sorted((folder / f"{output}.parts").glob("part-*.jsonl"))


def test_kill_9_mid_sweep_then_resume_gives_the_same_table(big_sweep: Path) -> None:
    total = len(rows_of(big_sweep / "whole.csv"))
    sweep = start("sweep", "spec.toml", "-o", "resumed.csv", "--workers", "1", cwd=big_sweep)
    try:
        wait_for(lambda: len(parts_of(big_sweep, "resumed.csv")) >= 1 or sweep.poll() is not None,
                 "the first part")
        assert sweep.poll() is None, "the sweep ended before it could be stopped"
        os.kill(sweep.pid, signal.SIGKILL)
    finally:
        sweep.kill()
        sweep.wait()
    assert not (big_sweep / "resumed.csv").exists()  # never a partial table
    import json

    done = [json.loads(line) for part in parts_of(big_sweep, "resumed.csv")
            for line in part.read_text().splitlines()]
    assert 0 < len(done) < total
    again = ncgate("sweep", "spec.toml", "-o", "resumed.csv", "--resume", "--workers", "2",
                   cwd=big_sweep)
    assert again.returncode == 1, again.stderr
    assert f"resuming: {len(done)} of {total} variants done" in again.stdout
    assert (big_sweep / "resumed.csv").read_bytes() == (big_sweep / "whole.csv").read_bytes()
    assert not (big_sweep / "resumed.csv.parts").exists()


def test_sigterm_keeps_the_rows_done_for_resume(big_sweep: Path) -> None:
    import json

    total = len(rows_of(big_sweep / "whole.csv"))
    sweep = start("sweep", "spec.toml", "-o", "stopped.csv", "--workers", "1", cwd=big_sweep)
    _, err = terminated_once(sweep, lambda: len(parts_of(big_sweep, "stopped.csv")) >= 1,
                             "the first part")
    assert sweep.returncode == 1, err
    kept = [json.loads(line) for part in parts_of(big_sweep, "stopped.csv")
            for line in part.read_text().splitlines()]
    assert f"stopped (SIGTERM): {len(kept)} of {total} variants done" in err
    assert "--resume" in err and not (big_sweep / "stopped.csv").exists()
    again = ncgate("sweep", "spec.toml", "-o", "stopped.csv", "--resume", cwd=big_sweep)
    assert f"resuming: {len(kept)} of {total} variants done" in again.stdout
    assert (big_sweep / "stopped.csv").read_bytes() == (big_sweep / "whole.csv").read_bytes()


def test_a_sigterm_while_a_part_is_written_keeps_each_row_once(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The stop lands as a part's file is written (the moment the test above reacts to): its
    rows were written again by the stop's own flush, so the parts held a row twice."""
    import io
    import json
    import threading

    from ncgate.gateway.sweep import main
    from ncgate.gateway.sweep.main import Options, run_sweep
    from ncgate.gateway.sweep.spec import load_spec
    from ncgate.gateway.sweep.table import Parts

    assert threading.current_thread() is threading.main_thread()  # run_sweep's handler
    spec = load_spec(misbehaving_spec(tmp_path, ("OK.nc", "FINE.nc")))
    write = Parts.add
    sent = []

    def add_then_sigterm(parts: Parts, rows: list[dict[str, object]]) -> None:
        write(parts, rows)
        if rows and not sent:  # once: the file is there, pending not yet cleared
            sent.append(True)
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(Parts, "add", add_then_sigterm)
    monkeypatch.setattr(main, "FLUSH_ROWS", 1)  # a part at the first row
    status, _ = run_sweep(spec, Options(tmp_path / "out.csv", workers=1, progress=False),
                          io.StringIO())
    assert status == main.EXIT_FAILED
    ids = [json.loads(line)["id"] for part in parts_of(tmp_path, "out.csv")
           for line in part.read_text().splitlines()]
    assert ids and len(ids) == len(set(ids)), ids
    assert f"stopped (SIGTERM): {len(ids)} of 4 variants done" in capsys.readouterr().err


def test_resume_refuses_parts_of_another_spec(tmp_path: Path) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n')
    parts = tmp_path / "spec.csv.parts"
    parts.mkdir()
    (parts / "manifest.json").write_text('{"format": "ncgate-sweep-parts/1", "fingerprint": '
                                         '"another"}')
    done = ncgate("sweep", "spec.toml", "--resume", cwd=tmp_path)
    assert done.returncode == 2 and "changed since" in done.stderr
    assert ncgate("sweep", "spec.toml", cwd=tmp_path).returncode == 0  # no --resume: anew


def test_parquet_holds_the_same_rows(big_sweep: Path) -> None:
    import pyarrow.parquet as pq

    done = ncgate("sweep", "spec.toml", "--format", "parquet", "-o", "whole.parquet",
                  "--workers", "2", cwd=big_sweep)
    assert done.returncode == 1, done.stderr
    table = pq.read_table(big_sweep / "whole.parquet").to_pylist()
    rows = rows_of(big_sweep / "whole.csv")
    assert [r["id"] for r in table] == [r["id"] for r in rows]
    for got, want in zip(table, rows, strict=True):
        assert got["verdict"] == want["verdict"]
        assert got["cycle_s"] == float(want["cycle_s"])
        assert got["hazards"] == int(want["hazards"])
        assert got["nc.lookahead"] == int(want["nc.lookahead"])
        assert got["command"] == want["command"]


# -- the local pool loses nothing when a worker is killed ----------------------------------


def descendants(pid: int) -> list[int]:
    import psutil

    return [p.pid for p in psutil.Process(pid).children(recursive=True)]


def test_a_killed_local_worker_loses_and_duplicates_nothing(big_sweep: Path) -> None:
    import psutil

    sweep = start("sweep", "spec.toml", "-o", "killed.csv", "--workers", "2", cwd=big_sweep)
    try:
        # The workers are the forkserver's children: the sweep's grandchildren.
        def workers() -> list[psutil.Process]:
            return [p for p in psutil.Process(sweep.pid).children(recursive=True)
                    if p.ppid() != sweep.pid]

        wait_for(lambda: (len(workers()) >= 2 and len(parts_of(big_sweep, "killed.csv")) >= 1)
                 or sweep.poll() is not None, "two workers and a first part")
        assert sweep.poll() is None
        victim = workers()[0]
        victim.send_signal(signal.SIGKILL)
        victim.wait(30)
        _out, err = sweep.communicate(timeout=300)
    finally:
        sweep.kill()
    assert sweep.returncode == 1, err
    assert (big_sweep / "killed.csv").read_bytes() == (big_sweep / "whole.csv").read_bytes()


# -- Dask -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cluster() -> Iterator[object]:
    """Two workers, each under a nanny that starts it again whenever it dies, as under
    ``dask worker``.  A LocalCluster would give a worker up for good (close its nanny) when,
    ``distributed.deploy.lost-worker-timeout`` (15 s) after a death of it, the worker is
    missing again: on a loaded machine a worker that DIE kills every few seconds spends most
    of its time restarting, both nannies were closed, and the sweep waited for a worker until
    the test's timeout.  Here the cluster never gives a worker up."""
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.deploy.lost-worker-timeout": "1 day"}), \
            LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                         dashboard_address=None) as local, Client(local) as client:
        yield client


def test_dask_gives_the_same_table(cluster: object, big_sweep: Path) -> None:
    address = cluster.scheduler.address  # type: ignore[attr-defined]
    done = ncgate("sweep", "spec.toml", "-o", "dask.csv", "--scheduler", address,
                  cwd=big_sweep)
    assert done.returncode == 1, done.stderr
    assert (big_sweep / "dask.csv").read_bytes() == (big_sweep / "whole.csv").read_bytes()


def test_a_variant_that_kills_its_dask_workers_is_a_crash_row_alone(cluster: object,
                                                                    tmp_path: Path) -> None:
    from ncgate.gateway.sweep.cluster import run_dask
    from ncgate.gateway.sweep.spec import load_spec

    from .sweep_runners import misbehaving

    innocent = tuple(f"OK{i}.nc" for i in range(7))  # some beside DIE on a dying worker
    spec = load_spec(misbehaving_spec(tmp_path, ("DIE.nc", *innocent)))
    address = cluster.scheduler.address  # type: ignore[attr-defined]
    got = list(run_dask(spec.variants, address, 10.0, runner=misbehaving))
    assert sorted(v.id for v, _ in got) == sorted(v.id for v in spec.variants)
    for variant, result in got:
        if Path(variant.program).stem == "DIE":
            assert result["verdict"] == "crash" and "KilledWorker" in result["report"]
        else:  # in a chunk with DIE, or not: each runs again alone and is ok
            assert result["verdict"] == "ok", result


def test_kill_9_of_a_dask_worker_loses_and_duplicates_nothing(cluster: object,
                                                               big_sweep: Path) -> None:
    client = cluster
    address = client.scheduler.address  # type: ignore[attr-defined]
    client.wait_for_workers(2, timeout=120)  # type: ignore[attr-defined]
    sweep = start("sweep", "spec.toml", "-o", "dask-killed.csv", "--scheduler", address,
                  cwd=big_sweep)
    try:
        def busy() -> list[str]:
            return [w for w, keys in client.processing().items()  # type: ignore[attr-defined]
                    if any("ncgate-sweep" in str(k) for k in keys)]

        wait_for(lambda: (bool(busy()) and len(parts_of(big_sweep, "dask-killed.csv")) >= 1)
                 or sweep.poll() is not None, "a worker running a chunk after a first part")
        assert sweep.poll() is None
        victim = busy()[0]
        pid = client.run(os.getpid, workers=[victim])[victim]  # type: ignore[attr-defined]
        os.kill(pid, signal.SIGKILL)
        _out, err = sweep.communicate(timeout=300)
    finally:
        sweep.kill()
    assert sweep.returncode == 1, err
    assert (big_sweep / "dask-killed.csv").read_bytes() == \
        (big_sweep / "whole.csv").read_bytes()


@pytest.fixture
def lonely_cluster() -> Iterator[object]:
    """One worker of one thread, the test's own: it takes the worker away (the module's
    ``cluster`` must stay whole for the other tests)."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as local:
        yield local


def without_workers(local: object) -> None:
    """``local`` scaled to no worker, until its scheduler has none left."""
    local.scale(0)  # type: ignore[attr-defined]
    # The scheduler's worker table belongs to the cluster's loop thread and no event says it
    # emptied: read it until it has (ASYNC110's kind of poll, in a thread).
    wait_for(lambda: not local.scheduler.workers,  # type: ignore[attr-defined]
             "the scheduler to have no worker")


def test_a_dask_cluster_with_no_worker_left_is_cluster_lost_after_the_results_before(
        monkeypatch: pytest.MonkeyPatch, lonely_cluster: object, tmp_path: Path) -> None:
    """Every worker retired mid-sweep: the tasks stay pending at the scheduler.  They were
    waited for for ever; now the results that came are yielded, then ClusterLost."""
    from ncgate.gateway.errors import ClusterLost
    from ncgate.gateway.sweep import cluster
    from ncgate.gateway.sweep.spec import load_spec

    from .sweep_runners import slow

    monkeypatch.setattr(cluster, "WORKERLESS_S", 2.0)
    spec = load_spec(misbehaving_spec(tmp_path, tuple(f"OK{i}.nc" for i in range(6))))
    address = lonely_cluster.scheduler_address  # type: ignore[attr-defined]
    sweep = cluster.run_dask(spec.variants, address, 60.0, runner=slow)
    got = [next(sweep)]
    without_workers(lonely_cluster)
    with pytest.raises(ClusterLost) as lost:
        got.extend(sweep)
    ids = [v.id for v, _ in got]
    assert len(ids) == len(set(ids)) and all(r["verdict"] == "ok" for _, r in got), got
    assert lost.value.unfinished == len(spec.variants) - len(got) > 0
    assert lost.value.workerless_s >= 2.0
    assert f"the Dask scheduler at {address} has had no worker for " in str(lost.value)
    assert f"; {lost.value.unfinished} variants not done" in str(lost.value)


def test_a_suspect_run_alone_on_a_cluster_with_no_worker_left_is_cluster_lost(
        monkeypatch: pytest.MonkeyPatch, lonely_cluster: object, tmp_path: Path) -> None:
    """Both variants' tasks err, so each runs again alone at the end; the workers are gone
    before the second's run: it was waited for for ever."""
    from ncgate.gateway.errors import ClusterLost
    from ncgate.gateway.sweep import cluster
    from ncgate.gateway.sweep.spec import load_spec

    from .sweep_runners import misbehaving

    monkeypatch.setattr(cluster, "WORKERLESS_S", 2.0)
    spec = load_spec(misbehaving_spec(tmp_path, ("RAISE.nc",)))  # feed 50 and 100
    address = lonely_cluster.scheduler_address  # type: ignore[attr-defined]
    sweep = cluster.run_dask(spec.variants, address, 60.0, runner=misbehaving)
    _, first = next(sweep)  # the first run alone: its verdict
    assert first["verdict"] == "crash" and "RAISE.nc: out of the runner" in first["report"]
    without_workers(lonely_cluster)
    with pytest.raises(ClusterLost) as lost:
        next(sweep)
    assert lost.value.unfinished == 1, lost.value


def test_a_sweep_whose_dask_cluster_has_no_worker_left_stops_with_1_and_resumes(
        monkeypatch: pytest.MonkeyPatch, lonely_cluster: object, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The rows done are kept as at a stop, the message says why and how to go on, and
    ``--resume`` on a cluster with a worker again gives the table a whole sweep gives."""
    import functools
    import io
    import json

    from distributed import Client

    from ncgate.gateway.sweep import cluster, main
    from ncgate.gateway.sweep.main import Options, run_sweep
    from ncgate.gateway.sweep.spec import load_spec
    from ncgate.gateway.sweep.table import Parts

    from .sweep_runners import slow

    misbehaving_spec(tmp_path, tuple(f"OK{i}.nc" for i in range(6)))
    monkeypatch.chdir(tmp_path)  # `sweep spec.toml`, as the resume below: the rows' paths
    spec = load_spec("spec.toml")
    total = len(spec.variants)
    address = lonely_cluster.scheduler_address  # type: ignore[attr-defined]
    monkeypatch.setattr(cluster, "WORKERLESS_S", 2.0)
    monkeypatch.setattr(cluster, "run_dask", functools.partial(cluster.run_dask, runner=slow))
    monkeypatch.setattr(main, "FLUSH_ROWS", 1)  # a part at the first row
    write = Parts.add

    def add_then_retire_the_workers(parts: Parts, rows: list[dict[str, object]]) -> None:
        write(parts, rows)
        if rows:  # the first row is kept: the workers go
            lonely_cluster.scale(0)  # type: ignore[attr-defined]

    monkeypatch.setattr(Parts, "add", add_then_retire_the_workers)
    status, rows = run_sweep(spec, Options(Path("out.csv"), scheduler=address, progress=False),
                             io.StringIO())
    err = capsys.readouterr().err
    assert (status, rows) == (main.EXIT_FAILED, []), err
    kept = [json.loads(line)["id"] for part in parts_of(tmp_path, "out.csv")
            for line in part.read_text().splitlines()]
    assert 0 < len(kept) == len(set(kept)) < total
    assert err.startswith(f"ncgate sweep: stopped: the Dask scheduler at {address} has had no "
                          "worker for "), err
    assert err.endswith(f"s: {len(kept)} of {total} variants done, kept in "
                        f"{tmp_path.resolve() / 'out.csv.parts'}; run again with --resume "
                        "once the "
                        "cluster has workers\n"), err
    assert "Traceback" not in err and not (tmp_path / "out.csv").exists()

    lonely_cluster.scale(1)  # type: ignore[attr-defined]
    with Client(lonely_cluster, set_as_default=False) as client:
        client.wait_for_workers(1, timeout=120)
    again = ncgate("sweep", "spec.toml", "-o", "out.csv", "--resume", "--scheduler", address,
                   cwd=tmp_path)
    assert again.returncode == 0, again.stderr
    assert f"resuming: {len(kept)} of {total} variants done" in again.stdout
    whole = ncgate("sweep", "spec.toml", "-o", "whole.csv", "--workers", "1", cwd=tmp_path)
    assert whole.returncode == 0, whole.stderr
    assert (tmp_path / "out.csv").read_bytes() == (tmp_path / "whole.csv").read_bytes()
    assert not (tmp_path / "out.csv.parts").exists()


def test_a_plant_models_key_is_swept_by_the_models_name(tmp_path: Path) -> None:
    """`plant.model.clamp.travel_ms`: the machine example's PLC alarms when the clamp takes
    over 1 s to close (plc.st: clamp_slow, PT := T#1s), so a 300 ms stroke passes the good
    scenario and a 2,500 ms one fails it; each row's command says so again alone."""
    import shutil

    shutil.copytree(EXAMPLES / "machine", tmp_path / "machine")
    (tmp_path / "spec.toml").write_text(
        '[sweep]\nprograms = ["machine/PART.nc"]\nconfig = "machine/ncgate.toml"\n'
        'script = "machine/scenarios/good.toml"\n'
        '[grid]\n"plant.model.clamp.travel_ms" = [300, 2500]\n')
    done = ncgate("sweep", "spec.toml", "-q", cwd=tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    rows = {r["plant.model.clamp.travel_ms"]: r for r in rows_of(tmp_path / "spec.csv")}
    assert (rows["300"]["verdict"], rows["2500"]["verdict"]) == ("ok", "expect_failed")
    again = ncgate(*shlex.split(rows["2500"]["command"])[1:], cwd=tmp_path)
    assert again.returncode == 1 and "FAIL" in again.stdout, again.stdout + again.stderr
    assert "--set plant.model.clamp.travel_ms=2500" in rows["2500"]["command"]


def test_a_cell_the_plc_holds_is_one_stall_signature_and_the_hold_is_not_running(
        tmp_path: Path) -> None:
    """The PLC holds P1 in a move for ever (NC.HOLD_LEVEL after 500 ms): each variant ends as
    a stall (`sim` ran for ever), the hold's time (0.504 s on a 7 ms scan, 0.500 s on a 10 ms
    one) stays out of the signature, so the two are one failure; running_s is the move until
    the hold, the hold is waiting_s."""
    (tmp_path / "MAIN.nc").write_text("N10G1X100F600\nN20M30\n")
    (tmp_path / "plc.st").write_text("PROGRAM p VAR t : TON; END_VAR\n"
                                     "t(IN := TRUE, PT := T#500ms);\n"
                                     "NC.HOLD_LEVEL := t.Q;\nEND_PROGRAM\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "MAIN"\nstall_s = 5\n'
                                          '[plc]\nlogic = "plc.st"\n')
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["MAIN.nc"]\n'
                                        '[grid]\n"plc.scan_ms" = [7, 10]\n')
    done = ncgate("sweep", "spec.toml", "-q", "--timeout", "60", cwd=tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    rows = {r["plc.scan_ms"]: r for r in rows_of(tmp_path / "spec.csv")}
    assert [rows[k]["verdict"] for k in ("7", "10")] == ["stall", "stall"]
    assert rows["7"]["signature"] == rows["10"]["signature"] == (
        "stall P1 MAIN.nc:2 held (feed hold by plc plc.st:3): a cycle start goes on")
    assert (rows["7"]["running_s"], rows["10"]["running_s"]) == ("P1=0.504", "P1=0.500")
    for row in rows.values():
        held = float(row["cycle_s"]) - float(row["running_s"].removeprefix("P1="))
        assert float(row["waiting_s"].removeprefix("P1=")) == pytest.approx(held)


# -- the hostile review's findings --------------------------------------------------------


SUB_CELL = {
    # P1 starts SUB in P2 and waits for its SND: SUB is read from the storage (MP0), not
    # named by the spec.  The PLC and plant logic are read by every run too.
    "MAIN.nc": "N1(EXE,2,SUB)\nN2(WAI,2)\nN3M30\n",
    "SUB.nc": "N1G4X1\nN2(SND,1)\nN3M30\n",
    "plc.st": "PROGRAM Main\nVAR\n  n : INT;\nEND_VAR\nn := n + 1;\nEND_PROGRAM\n",
    "plant.st": "PROGRAM Plant\nVAR\n  m : INT;\nEND_VAR\nm := m + 1;\nEND_PROGRAM\n",
    "ncgate.toml": '[nc]\nprocesses = 2\nlookahead = 0\nmain = "MAIN"\n[nc.storage]\nMP0 = "."\n'
                   '[plc]\nlogic = "plc.st"\n[plant]\nlogic = "plant.st"\n',
}


@pytest.mark.parametrize("changed", ["SUB.nc", "plc.st", "plant.st"])
def test_resume_refuses_a_changed_file_the_runs_read(monkeypatch: pytest.MonkeyPatch,
                                                     tmp_path: Path, changed: str) -> None:
    from ncgate.gateway.sweep.spec import load_spec
    from ncgate.gateway.sweep.table import Parts

    (tmp_path / "sub").mkdir()
    for name, text in SUB_CELL.items():
        (tmp_path / "sub" / name).write_text(text)
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["sub/MAIN.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [50, 100]\n')
    monkeypatch.chdir(tmp_path)
    # A sweep stopped before its first part: the parts folder holds its manifest.
    Parts(Path("spec.csv"), load_spec("spec.toml")).start(resume=False)
    same = ncgate("sweep", "spec.toml", "--resume", "--timeout", "30", cwd=tmp_path)
    assert same.returncode == 0, same.stdout + same.stderr  # nothing changed: it goes on
    table = (tmp_path / "spec.csv").read_bytes()
    Parts(Path("spec.csv"), load_spec("spec.toml")).start(resume=False)
    file = tmp_path / "sub" / changed
    file.write_text(file.read_text().replace("G4X1", "G4X2").replace("+ 1", "+ 2"))
    done = ncgate("sweep", "spec.toml", "--resume", cwd=tmp_path)
    # The refusal names the file (it said "the spec or a file it names changed", and a
    # user whose log beside the programs was the change could not tell).
    assert done.returncode == 2 and f"{file.resolve()} (changed)" in done.stderr, \
        done.stdout + done.stderr
    assert (tmp_path / "spec.csv").read_bytes() == table  # no row of the new version in it


def test_resume_names_a_program_file_new_beside_the_programs(tmp_path: Path) -> None:
    """A .txt beside the programs is a program file on MP0 (NC-110 reads it): a log written
    there between the runs changes what the sweep reads, and the refusal names it."""
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [50, 100]\n')
    assert ncgate("sweep", "spec.toml", cwd=tmp_path).returncode == 0
    (tmp_path / "spec.csv").unlink()
    from ncgate.gateway.sweep.spec import load_spec
    from ncgate.gateway.sweep.table import Parts

    Parts(tmp_path / "spec.csv", load_spec(tmp_path / "spec.toml")).start(resume=False)
    (tmp_path / "run.txt").write_text("the sweep's log\n")
    done = ncgate("sweep", "spec.toml", "--resume", cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"{(tmp_path / 'run.txt').resolve()} (new)" in done.stderr, done.stderr


def test_resume_knows_the_spec_by_another_spelling_of_its_path(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from ncgate.gateway.sweep.spec import load_spec
    from ncgate.gateway.sweep.table import Parts

    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "res.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n')
    monkeypatch.chdir(tmp_path)
    Parts(Path("res.csv"), load_spec("res.toml")).start(resume=False)  # `sweep res.toml`
    done = ncgate("sweep", str(tmp_path / "res.toml"), "--resume", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert len(rows_of(tmp_path / "res.csv")) == 1


def test_the_table_is_written_through_a_link_and_with_the_umasks_mode(tmp_path: Path) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n')
    (tmp_path / "results").mkdir()
    (tmp_path / "link.csv").symlink_to("results/real.csv")
    done = subprocess.run([sys.executable, "-m", "ncgate", "sweep", "spec.toml", "-o",
                           "link.csv"], cwd=tmp_path, text=True, capture_output=True,
                          timeout=120, preexec_fn=lambda: os.umask(0o027))
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "link.csv").is_symlink()
    assert len(rows_of(tmp_path / "results" / "real.csv")) == 1
    assert (tmp_path / "results" / "real.csv").stat().st_mode & 0o777 == 0o640


@pytest.mark.parametrize("kind", ["fifo", "folder", "descriptor", "spec", "program"])
def test_an_output_that_is_not_a_table_file_is_refused(tmp_path: Path, kind: str) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    spec = '[sweep]\nprograms = ["OK.nc"]\n'
    (tmp_path / "spec.toml").write_text(spec)
    read_end, write_end = os.pipe()  # a pipe other than stdout, named by its descriptor:
    # its /proc link resolves to "pipe:[NNN]", and it was "No such file ... pipe:[NNN].parts"
    output = {"fifo": "out.csv", "folder": "out.csv", "descriptor": f"/dev/fd/{write_end}",
              "spec": "spec.toml", "program": "OK.nc"}[kind]
    if kind == "fifo":
        os.mkfifo(tmp_path / output)
    elif kind == "folder":
        (tmp_path / output).mkdir()
    try:
        done = subprocess.run([sys.executable, "-m", "ncgate", "sweep", "spec.toml", "-o",
                               output], cwd=tmp_path, text=True, capture_output=True,
                              timeout=120, pass_fds=(write_end,))
    finally:
        os.close(read_end)
        os.close(write_end)
    assert done.returncode == 2, done.stderr
    said = "is one of the sweep's inputs" if kind in ("spec", "program") else \
        "not a regular file"
    assert f"-o {output}: {said}" in done.stderr, done.stderr
    if said == "not a regular file":
        assert "for standard output give -o -" in done.stderr
    assert (tmp_path / "spec.toml").read_text() == spec
    assert (tmp_path / "OK.nc").read_text() == LOOPS["OK"]
    assert not (tmp_path / f"{output}.parts").exists()
    if kind == "fifo":
        assert stat.S_ISFIFO((tmp_path / output).stat().st_mode)


def test_random_draws_that_repeat_run_once(tmp_path: Path) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "r.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n[random]\nseed = 1\n'
                                     'samples = 10\n"nc.lookahead" = [0, 3]\n')
    done = ncgate("sweep", "r.toml", "--workers", "2", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    rows = rows_of(tmp_path / "r.csv")
    assert sorted(r["nc.lookahead"] for r in rows) == ["0", "1", "2", "3"]
    assert "the 10 draws gave 4 distinct samples" in done.stdout
    (tmp_path / "e.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n[explore]\n'
                                     '"plc.scan_ms" = [1, 5]\n')
    explored = ncgate("sweep", "e.toml", "--explore", "20", "--workers", "2", cwd=tmp_path)
    assert explored.returncode == 0, explored.stderr
    assert sorted(r["plc.scan_ms"] for r in rows_of(tmp_path / "e-explore.csv")) == \
        ["1", "2", "3", "4", "5"]
    # A program given twice is still the spec's error: the same run twice.
    (tmp_path / "twice.toml").write_text('[sweep]\nprograms = ["OK.nc", "O*.nc"]\n')
    twice = ncgate("sweep", "twice.toml", cwd=tmp_path)
    assert twice.returncode == 2 and "two variants are the same run" in twice.stderr


@pytest.mark.parametrize("timeout", ["inf", "nan", "1e300"])
def test_a_timeout_that_is_no_number_of_seconds_is_refused(tmp_path: Path,
                                                          timeout: str) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n')
    done = ncgate("sweep", "spec.toml", "--timeout", timeout, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert f"--timeout {float(timeout)}: expected seconds > 0" in done.stderr
    assert "Traceback" not in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["OK.nc", "spec.toml"]


def limited_memory() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))  # a product would pass it


@pytest.mark.parametrize("bad_key", [False, True])
def test_a_huge_grid_is_counted_not_built(tmp_path: Path, bad_key: bool) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    keys = ["nc.lookahead", "nc.feed_override", "plc.scan_ms", "nc.block_time_ms",
            "sim.input_jitter_ms", "sim.input_delay_scale", "sim.seed", "nc.runaway_blocks"]
    if bad_key:
        keys[-1] = "nc.bogus"
    grid = "".join(f'"{k}" = {list(range(1, 21))}\n' for k in keys)
    (tmp_path / "big.toml").write_text(f'[sweep]\nprograms = ["OK.nc"]\n[grid]\n{grid}')
    done = subprocess.run([sys.executable, "-m", "ncgate", "sweep", "big.toml"], cwd=tmp_path,
                          text=True, capture_output=True, timeout=120,
                          preexec_fn=limited_memory)
    assert done.returncode == 2, done.stderr
    assert "big.toml" in done.stderr
    if bad_key:
        assert "nc.bogus: unknown key" in done.stderr, done.stderr
    else:
        assert f"{20 ** 8:,} variants" in done.stderr and "1,000,000" in done.stderr


def test_explores_reproducer_of_a_budget_timeout_has_its_until(tmp_path: Path) -> None:
    (tmp_path / "LOOP.nc").write_text(LOOPS["LOOP"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["LOOP.nc"]\nbudget_s = 5\n'
                                        '[explore]\n"nc.feed_override" = [50, 150]\n')
    done = ncgate("sweep", "spec.toml", "--explore", "2", "--workers", "1", cwd=tmp_path)
    assert done.returncode == 1, done.stderr
    rows = rows_of(tmp_path / "spec-explore.csv")
    assert {r["verdict"] for r in rows} == {"timeout"}
    assert all(r["command"].endswith("--until 5.0") for r in rows)
    found = re.search(r"^  smallest reproducer: (.*)$", done.stdout, re.M)
    assert found and found[1].endswith("--until 5.0"), done.stdout
    again = ncgate(*shlex.split(found[1])[1:], cwd=tmp_path, timeout=120)  # it ends
    assert again.returncode in (0, 1) and "simulated 5.000 s" in again.stdout, again.stdout


def test_ctrl_c_stops_the_sweep_quietly_with_130_and_keeps_its_rows(big_sweep: Path) -> None:
    sweep = subprocess.Popen([sys.executable, "-m", "ncgate", "sweep", "spec.toml", "-o",
                              "ctrl-c.csv", "--workers", "2"], cwd=big_sweep, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             start_new_session=True,  # its own group, as a terminal's job
                             # and SIGINT at its default, as a terminal's job has it: pytest
                             # started by a script's `&` (or nohup) ignores SIGINT, and the
                             # sweep inherited that and ran to its end (exit 1, nothing said)
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        wait_for(lambda: len(parts_of(big_sweep, "ctrl-c.csv")) >= 1 or sweep.poll() is not None,
                 "the first part")
        assert sweep.poll() is None, "the sweep ended before it could be stopped"
        os.killpg(sweep.pid, signal.SIGINT)  # the terminal's Ctrl-C: to every process
        _, err = sweep.communicate(timeout=60)
    finally:
        sweep.kill()
        sweep.wait()
    assert sweep.returncode == 130, err
    assert "stopped (Ctrl-C)" in err and "Traceback" not in err, err
    again = ncgate("sweep", "spec.toml", "-o", "ctrl-c.csv", "--resume", cwd=big_sweep)
    assert again.returncode == 1 and "resuming: " in again.stdout, again.stderr
    assert (big_sweep / "ctrl-c.csv").read_bytes() == (big_sweep / "whole.csv").read_bytes()


@pytest.mark.parametrize("buffered", [True, False], ids=["buffered", "unbuffered"])
@pytest.mark.parametrize(("program", "status"), [("OK", 0), ("BAD", 1)])
def test_a_closed_stdout_stops_neither_the_sweep_nor_its_status(
        tmp_path: Path, program: str, status: int, buffered: bool) -> None:
    """`| head -0`: the reader is gone before the first line.  With stdout block-buffered
    (no PYTHONUNBUFFERED, as a shell runs it), the summary waited in the buffer for the
    interpreter's last flush, which met the closed pipe: "Exception ignored ...
    BrokenPipeError", exit 120, whatever the rows."""
    (tmp_path / f"{program}.nc").write_text(LOOPS[program])
    (tmp_path / "spec.toml").write_text(f'[sweep]\nprograms = ["{program}.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [50, 100]\n')
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    read_end, write_end = os.pipe()
    os.close(read_end)
    sweep = subprocess.run([sys.executable, "-m", "ncgate", "sweep", "spec.toml"],
                           cwd=tmp_path, stdout=write_end, stderr=subprocess.PIPE, timeout=120,
                           env=env if buffered else {**env, "PYTHONUNBUFFERED": "1"})
    os.close(write_end)
    assert sweep.returncode == status and sweep.stderr == b"", sweep.stderr
    assert len(rows_of(tmp_path / "spec.csv")) == 2


# -- the table on standard output: -o -, /dev/stdout ---------------------------------------


def ok_and_bad(folder: Path) -> None:
    """A spec of two rows, one not ok (exit 1): its status is the rows', not 0 by chance."""
    for name in ("OK", "BAD"):
        (folder / f"{name}.nc").write_text(LOOPS[name])
    (folder / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc", "BAD.nc"]\n')


def private_folders(tmp: Path) -> list[Path]:
    return sorted(tmp.glob("ncgate-sweep-*"))


@pytest.fixture
def short_tmp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A TMPDIR for a sweep, whose private folder is looked for there.  Short: the local
    pool's forkserver puts its socket there too, and under a test's own tmp_path that
    socket's path passed AF_UNIX's 107 bytes ("AF_UNIX path too long", exit 2)."""
    return tmp_path_factory.mktemp("t")


@pytest.mark.parametrize("output", ["-", "/dev/stdout", "/dev/fd/1", "/proc/self/fd/1"])
def test_the_table_goes_to_stdout_and_the_summary_to_stderr(tmp_path: Path, short_tmp: Path,
                                                            output: str) -> None:
    """`-o -` wrote a file named "-"; `-o /dev/stdout | cat` was exit 2, "No such file or
    directory: '/proc/NNN/fd/pipe:[4115907].parts'".  stdout is a pipe here, as under `|`."""
    ok_and_bad(tmp_path)
    whole = ncgate("sweep", "spec.toml", "-o", "whole.csv", "--workers", "1", cwd=tmp_path)
    assert whole.returncode == 1, whole.stderr
    done = subprocess.run([sys.executable, "-m", "ncgate", "sweep", "spec.toml", "-o", output,
                           "--workers", "1"], cwd=tmp_path, capture_output=True, timeout=120,
                          env={**os.environ, "TMPDIR": str(short_tmp)})
    assert done.returncode == 1, done.stderr
    assert done.stdout == (tmp_path / "whole.csv").read_bytes()  # the table, and only it
    assert b"2 variants: 1 ok, 1 error" in done.stderr and b"not ok:" in done.stderr
    # Nothing made beside the inputs (no file "-", no parts), and the parts' private folder
    # is gone.
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "BAD.nc", "OK.nc", "spec.toml", "whole.csv"]
    assert private_folders(short_tmp) == []


@pytest.mark.parametrize("reader", ["head -0", "head -1"])
@pytest.mark.parametrize(("program", "status"), [("OK", 0), ("BAD", 1)])
def test_the_table_on_stdout_to_a_reader_that_goes_early_keeps_the_rows_status(
        tmp_path: Path, program: str, status: int, reader: str) -> None:
    """`sweep -o - | head -1`: the rest of the table goes nowhere, and the status is still
    the rows' (gateway/stdout.py); the summary, on stderr, is whole."""
    (tmp_path / f"{program}.nc").write_text(LOOPS[program])
    (tmp_path / "spec.toml").write_text(f'[sweep]\nprograms = ["{program}.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [50, 100]\n')
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # as a shell's
    sweep = subprocess.Popen([sys.executable, "-m", "ncgate", "sweep", "spec.toml", "-o", "-",
                              "--workers", "1"], cwd=tmp_path, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, env=env)
    assert sweep.stdout is not None and sweep.stderr is not None
    first = sweep.stdout.readline() if reader == "head -1" else b""
    sweep.stdout.close()  # the reader goes: head -0 before the table, head -1 after a line
    err = sweep.stderr.read()
    assert sweep.wait(timeout=120) == status, err
    if reader == "head -1":
        assert first.startswith(b"id,verdict,program,")
    assert b"2 variants: 2 " in err and b"Traceback" not in err and b"Exception" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{program}.nc", "spec.toml"]


def test_resume_with_the_table_on_stdout_is_refused(tmp_path: Path) -> None:
    ok_and_bad(tmp_path)
    for output in ("-", "/dev/stdout"):
        done = ncgate("sweep", "spec.toml", "-o", output, "--resume", cwd=tmp_path)
        assert done.returncode == 2, done.stderr
        assert "--resume with -o - (standard output)" in done.stderr
        assert "nothing to resume" in done.stderr or "no parts to resume" in done.stderr
        assert done.stdout == "" and "Traceback" not in done.stderr
        assert sorted(p.name for p in tmp_path.iterdir()) == ["BAD.nc", "OK.nc", "spec.toml"]


def test_parquet_on_stdout_goes_to_a_pipe_not_to_a_terminal(tmp_path: Path) -> None:
    import io
    import pty

    import pyarrow.parquet as pq

    ok_and_bad(tmp_path)
    piped = subprocess.run([sys.executable, "-m", "ncgate", "sweep", "spec.toml", "-o", "-",
                            "--format", "parquet", "--workers", "1"], cwd=tmp_path,
                           capture_output=True, timeout=120)
    assert piped.returncode == 1, piped.stderr
    whole = ncgate("sweep", "spec.toml", "-o", "whole.csv", "--workers", "1", cwd=tmp_path)
    table = pq.read_table(io.BytesIO(piped.stdout)).to_pylist()
    assert [(r["id"], r["verdict"], r["command"]) for r in table] == \
        [(r["id"], r["verdict"], r["command"]) for r in rows_of(tmp_path / "whole.csv")]
    assert whole.returncode == 1
    # Binary on a terminal is garbage (and may upset the terminal): refused before any run.
    terminal, other_end = pty.openpty()
    try:
        done = subprocess.run([sys.executable, "-m", "ncgate", "sweep", "spec.toml", "-o", "-",
                               "--format", "parquet"], cwd=tmp_path, stdout=other_end,
                              stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(other_end)
        os.close(terminal)
    assert done.returncode == 2, done.stderr
    assert "--format parquet -o -: standard output is a terminal" in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "BAD.nc", "OK.nc", "spec.toml", "whole.csv"]


def test_a_stopped_sweep_to_stdout_removes_its_parts_and_writes_no_table(
        big_sweep: Path, short_tmp: Path) -> None:
    total = len(rows_of(big_sweep / "whole.csv"))
    sweep = start("sweep", "spec.toml", "-o", "-", "--workers", "1", cwd=big_sweep,
                  env={**os.environ, "TMPDIR": str(short_tmp)})
    out, err = terminated_once(
        sweep, lambda: any(part for f in private_folders(short_tmp)
                           for part in f.glob("*.parts/part-*.jsonl")),
        "the first part in the private folder")
    assert sweep.returncode == 1, err
    assert re.search(rf"stopped \(SIGTERM\): \d+ of {total} variants done, no table written "
                     r"\(-o -: nothing to resume", err), err
    assert out == "" and private_folders(short_tmp) == []
    assert not (big_sweep / "-").exists() and not (big_sweep / "-.parts").exists()


# -- the rows' paths, from the folder the table is written in --------------------------------


@pytest.mark.parametrize("where", ["parent", "elsewhere"])
def test_a_sweep_resumed_from_another_folder_shows_every_rows_paths_alike(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, where: str) -> None:
    """The kept rows showed their program and command as the stopped sweep's working folder
    saw them (`OK.nc`), the new ones as the resumed sweep's (`x/OK.nc`, or absolute): two
    forms in one table, and the kept rows' commands ran from neither folder.  A resumed table
    is the table a whole sweep from the resumed one's folder gives."""
    from ncgate.gateway.sweep.run import run_variant
    from ncgate.gateway.sweep.spec import load_spec
    from ncgate.gateway.sweep.table import Parts, make_row

    first = tmp_path / "x"
    first.mkdir()
    ok_and_bad(first)
    then = {"parent": tmp_path, "elsewhere": tmp_path / "y"}[where]
    then.mkdir(exist_ok=True)
    monkeypatch.chdir(first)  # `cd x && ncgate sweep spec.toml`, stopped after one row
    spec = load_spec("spec.toml")
    kept = spec.variants[0]
    Parts(Path("spec.csv"), spec).start(resume=False)
    Parts(Path("spec.csv"), spec).add([make_row(kept, run_variant(kept, 30.0), spec.keys)])
    resumed = ncgate("sweep", str(first / "spec.toml"), "-o", str(first / "spec.csv"),
                     "--resume", "--workers", "1", cwd=then)
    assert resumed.returncode == 1, resumed.stderr
    assert "resuming: 1 of 2 variants done, 1 to run" in resumed.stdout
    whole = ncgate("sweep", str(first / "spec.toml"), "-o", "whole.csv", "--workers", "1",
                   cwd=then)
    assert whole.returncode == 1, whole.stderr
    rows = rows_of(first / "spec.csv")
    assert {Path(r["program"]).is_absolute() for r in rows} == {where == "elsewhere"}
    assert (first / "spec.csv").read_bytes() == (then / "whole.csv").read_bytes()


@pytest.mark.parametrize("url", ["bogus", "tcp://", "tcp://10.0.0.5", "tcp://:8786",
                                 "tcp://host:99999", "10.0.0.5:8786"])
def test_a_scheduler_that_is_no_address_is_refused_at_once(tmp_path: Path, url: str) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n')
    done = ncgate("sweep", "spec.toml", "--scheduler", url, cwd=tmp_path, timeout=20)
    assert done.returncode == 2, done.stderr
    assert f"--scheduler {url}: expected a Dask scheduler's address" in done.stderr
    assert "Traceback" not in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["OK.nc", "spec.toml"]


def test_a_spec_with_a_byte_order_mark_is_read(tmp_path: Path) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_bytes(b"\xef\xbb\xbf" + b'[sweep]\nprograms = ["OK.nc"]\n')
    done = ncgate("sweep", "spec.toml", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert len(rows_of(tmp_path / "spec.csv")) == 1


def test_an_examples_variant_has_the_same_id_wherever_the_spec_is(tmp_path: Path) -> None:
    """docs/sweep.md: the same spec gives the same ids wherever it runs -- for an installed
    example too, whose files lie wherever ncgate is (its id hashed their path relative to
    the spec's folder, so a spec moved one folder down gave other ids)."""
    deep = tmp_path / "a" / "b"
    deep.mkdir(parents=True)
    for folder in (tmp_path, deep):
        (folder / "s.toml").write_text('[sweep]\nexamples = ["scheme3"]\n')
        done = ncgate("sweep", "s.toml", "-q", cwd=folder)
        assert done.returncode in (0, 1), done.stderr
    ids = [[row["id"] for row in rows_of(folder / "s.csv")] for folder in (tmp_path, deep)]
    assert ids[0] and ids[0] == ids[1]


def test_a_dask_scheduler_that_goes_away_stops_the_sweep_and_makes_no_row_up(
        tmp_path: Path) -> None:
    """kill -9 of the scheduler mid-sweep: the client cancels every future it holds
    (scheduler-connection-lost), and the sweep took that for its workers' deaths -- the
    variants in flight became `crash` rows, final for --resume, then a traceback (a hostile
    try).  It is ClusterLost now, after the results that came, and no row is made up."""
    import socket

    import dask
    from distributed import Client

    from ncgate.gateway.errors import ClusterLost
    from ncgate.gateway.sweep.cluster import run_dask
    from ncgate.gateway.sweep.spec import load_spec

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    dask_cli = str(Path(sys.executable).parent / "dask")
    scheduler = subprocess.Popen([dask_cli, "scheduler", "--host", "127.0.0.1", "--port",
                                  str(port), "--no-dashboard"], stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL)
    worker = subprocess.Popen([dask_cli, "worker", address, "--nthreads", "1",
                               "--no-dashboard"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    # Programs a worker runs for about a second each (ncgate's own runner: a worker of the
    # command line imports no test module), six of them.
    for i in range(3):
        (tmp_path / f"LONG{i}.nc").write_text("N1 (RPT,20000)\nN2 G1 X1 F100000\nN3 G1 X0\n"
                                              "N4 (ERP)\nN5 M30\n")
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["LONG*.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [50, 100]\n')
    spec = load_spec(tmp_path / "spec.toml")
    got: list[tuple[object, dict[str, object]]] = []
    try:
        with dask.config.set({"distributed.comm.timeouts.connect": "3s"}), \
                Client(address, timeout=60, set_as_default=False) as client:
            client.wait_for_workers(1, timeout=60)
            with pytest.raises(ClusterLost) as lost:
                for variant, result in run_dask(spec.variants, address, 60.0,
                                                client=client):
                    got.append((variant, result))
                    if len(got) == 1:
                        scheduler.kill()
    finally:
        for proc in (scheduler, worker):
            proc.kill()
            proc.wait()
    assert got and all(result["verdict"] == "ok" for _, result in got)
    assert "went away" in str(lost.value) and address in str(lost.value)
    assert lost.value.unfinished == len(spec.variants) - len(got)


def test_two_sweeps_of_one_spec_on_one_dask_cluster_each_get_their_own_runs(
        cluster: object, tmp_path: Path) -> None:
    """A task is known by its key, and the keys were made of the variants alone: a second
    sweep of the same spec at the same time (another --timeout, another runner) shared the
    first's tasks and took its results.  Each sweep's keys are its own now."""
    import threading

    from ncgate.gateway.sweep.cluster import run_dask
    from ncgate.gateway.sweep.spec import load_spec

    from .sweep_runners import slow, slow_tagged

    spec = load_spec(misbehaving_spec(tmp_path, tuple(f"OK{i}.nc" for i in range(4))))
    address = cluster.scheduler.address  # type: ignore[attr-defined]
    got: dict[str, list[str]] = {}

    def sweep(name: str, runner: Any) -> None:
        got[name] = [str(result["report"]) for _, result in
                     run_dask(spec.variants, address, 60.0, runner=runner)]

    threads = [threading.Thread(target=sweep, args=("plain", slow)),
               threading.Thread(target=sweep, args=("tagged", slow_tagged))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(300)
    assert len(got["plain"]) == len(got["tagged"]) == len(spec.variants)
    assert "tagged" not in got["plain"] and set(got["tagged"]) == {"tagged"}


def test_a_sigterm_before_the_first_variant_leaves_no_private_folder(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The stop handlers are in before anything is made: a SIGTERM that came after -o -'s
    private folder was made and before they were left that folder behind (the process died
    by the signal).  The test's own handler stands for that default: it must not be met."""
    import io
    import tempfile

    from ncgate.gateway.sweep import main
    from ncgate.gateway.sweep.main import Options, run_sweep
    from ncgate.gateway.sweep.spec import load_spec
    from ncgate.gateway.sweep.table import Parts

    class Unhandled(Exception):
        pass

    def unhandled(signum: int, frame: object) -> None:
        raise Unhandled("SIGTERM met no handler of the sweep's")

    spec = load_spec(misbehaving_spec(tmp_path, ("OK.nc", "FINE.nc")))
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temporary))
    start = Parts.start

    def sigterm_then_start(parts: Parts, resume: bool) -> dict[str, dict[str, object]]:
        os.kill(os.getpid(), signal.SIGTERM)
        return start(parts, resume)

    monkeypatch.setattr(Parts, "start", sigterm_then_start)
    previous = signal.signal(signal.SIGTERM, unhandled)
    try:
        status, rows = run_sweep(spec, Options(None, workers=1, progress=False), io.StringIO())
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert (status, rows) == (main.EXIT_FAILED, [])
    assert list(temporary.iterdir()) == []
    assert "ncgate sweep: stopped (SIGTERM) before any variant ran" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGTERM) is previous


def test_a_sigterm_while_the_sweep_ends_is_exit_1_not_an_interrupt(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The stop handlers stay in until the sweep has said its summary: a SIGTERM there was
    re-raised as a Ctrl-C (exit 130, "interrupted"; a maintainer's review).  It is exit 1,
    as every SIGTERM of a sweep, and the table written stands."""
    import io

    from ncgate.gateway.sweep import main
    from ncgate.gateway.sweep.main import Options, run_sweep
    from ncgate.gateway.sweep.spec import load_spec

    spec = load_spec(misbehaving_spec(tmp_path, ("OK.nc", "FINE.nc")))
    said = main.summary

    def sigterm_then_summary(*args: object) -> None:
        os.kill(os.getpid(), signal.SIGTERM)
        said(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(main, "summary", sigterm_then_summary)
    status, _ = run_sweep(spec, Options(tmp_path / "out.csv", workers=1, progress=False),
                          io.StringIO())
    assert status == main.EXIT_FAILED
    assert "ncgate sweep: stopped (SIGTERM) while it ended" in capsys.readouterr().err
    assert len(rows_of(tmp_path / "out.csv")) == 4  # written whole before
