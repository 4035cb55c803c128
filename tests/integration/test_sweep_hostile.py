"""``ncgate sweep``: what a hostile tester found -- a Dask worker in another working folder, a
key given twice in two spellings, a reproducer without its ``--until``, an ``-o`` into no
folder, a scheduler that goes away, a ``--resume`` of another ``--explore`` count.

Real processes as in test_sweep.py: the sweep is its own ``ncgate sweep`` process, a Dask
scheduler and worker are ``dask`` processes on loopback (ports 47400-47499: this file's own).
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from .test_sweep import LOOPS, RACE, ncgate, rows_of, start, wait_for

DASK = str(Path(sys.executable).parent / "dask")


class Cluster:
    """A ``dask scheduler`` and a ``dask worker`` (one thread) as processes, both started in
    ``cwd``: a working folder that is not the sweep's."""

    def __init__(self, port: int, cwd: Path) -> None:
        self.address = f"tcp://127.0.0.1:{port}"
        quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "cwd": cwd}
        self.scheduler = subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port",
                                           str(port), "--no-dashboard"], **quiet)
        self.worker = subprocess.Popen([DASK, "worker", self.address, "--nthreads", "1",
                                        "--no-dashboard"], **quiet)

    def wait_for_worker(self) -> None:
        from distributed import Client

        with Client(self.address, timeout=120, set_as_default=False) as client:
            client.wait_for_workers(1, timeout=120)

    def stop(self) -> None:
        for proc in (self.worker, self.scheduler):
            proc.kill()
            proc.wait()


@pytest.fixture
def elsewhere(tmp_path: Path) -> Path:
    folder = tmp_path / "elsewhere"
    folder.mkdir()
    return folder


@contextlib.contextmanager
def cluster_at(port: int, cwd: Path) -> Iterator[Cluster]:
    cluster = Cluster(port, cwd)
    try:
        cluster.wait_for_worker()
        yield cluster
    finally:
        cluster.stop()


@pytest.fixture
def cluster_elsewhere(elsewhere: Path) -> Iterator[Cluster]:
    with cluster_at(47401, elsewhere) as cluster:
        yield cluster


# -- 1. a Dask worker runs the files the client meant ------------------------------------


def test_a_dask_worker_in_another_folder_runs_a_spec_given_by_relative_paths(
        cluster_elsewhere: Cluster, tmp_path: Path) -> None:
    """The config and script were passed to the worker as the client shows them, relative to
    the client's working folder: every row was `error: ncgate.toml: no such file`."""
    cell = tmp_path / "cell"
    cell.mkdir()
    for name, text in RACE.items():
        (cell / name).write_text(text)
    done = ncgate("sweep", "spec.toml", "-o", "out.csv", "--scheduler",
                  cluster_elsewhere.address, cwd=cell)
    assert done.returncode == 0, done.stdout + done.stderr
    [row] = rows_of(cell / "out.csv")
    assert row["verdict"] == "ok", row
    # The table shows the files as documented: relative to the sweep's working folder.
    assert row["command"] == "ncgate sim A --config ncgate.toml --script plc.toml"


# -- 2, 3. a key or a value given twice ----------------------------------------------------


@pytest.mark.parametrize(("table", "said"), [
    # TOML reads these as two keys, a string and a nested table: the later one won, unsaid.
    ('[grid]\n"nc.lookahead" = [0]\nnc.lookahead = [1]\n',
     "grid.nc.lookahead: the key is given twice"),
    ('[grid]\nnc.lookahead = [1]\n"nc.lookahead" = [0]\n',
     "grid.nc.lookahead: the key is given twice"),
    ('[random]\nsamples = 2\n"nc.feed_override" = [50, 60]\nnc.feed_override = [70, 80]\n',
     "random.nc.feed_override: the key is given twice"),
    ('[explore]\n"nc.feed_override" = [50, 60]\nnc = {feed_override = [70, 80]}\n',
     "explore.nc.feed_override: the key is given twice"),
    # The same number in two spellings ran twice: the duplicate check compared their text.
    ('[grid]\n"sim.input_delay_scale" = [1, 1.0]\n',
     "grid.sim.input_delay_scale: a value is given twice"),
    ('[grid]\n"nc.feed_override" = [100, 50, 100.0]\n',
     "grid.nc.feed_override: a value is given twice"),
], ids=["grid-quoted-then-dotted", "grid-dotted-then-quoted", "random", "explore-inline",
        "grid-1-and-1.0", "grid-100-and-100.0"])
def test_a_key_or_value_given_twice_is_the_specs_error(tmp_path: Path, table: str,
                                                       said: str) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "bad.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n' + table)
    explore = ("--explore", "2") if table.startswith("[explore]") else ()
    done = ncgate("sweep", "bad.toml", *explore, cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"bad.toml: {said}" in done.stderr, done.stderr
    assert not list(tmp_path.glob("bad*.csv*"))


def test_a_boolean_and_a_number_are_not_one_value(tmp_path: Path) -> None:
    from ncgate.gateway.sweep.spec import _same

    assert _same(True) != _same(1) and _same(False) != _same(0)
    assert _same(1) == _same(1.0) and _same("1") != _same(1)


# -- 5. -o into no folder ------------------------------------------------------------------


@pytest.mark.parametrize("output", ["no/such/out.csv", "OK.nc/out.csv", "gone/out.csv"])
def test_an_output_in_no_folder_is_refused_before_anything_is_made(tmp_path: Path,
                                                                   output: str) -> None:
    """The table's atomic writing made the missing folders: a typo made a tree, unsaid."""
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n')
    (tmp_path / "gone").symlink_to(tmp_path / "missing")  # a link to no folder
    before = sorted(tmp_path.rglob("*"))
    done = ncgate("sweep", "spec.toml", "-o", output, cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.startswith(f"ncgate sweep: -o {output}: "), done.stderr
    assert ("not a folder" if output.startswith("OK.nc") else "no such folder") in done.stderr
    assert len(done.stderr.splitlines()) == 1, done.stderr
    assert sorted(tmp_path.rglob("*")) == before


# -- 7. --resume says what changed ----------------------------------------------------------


@pytest.mark.parametrize(("then", "now", "said"), [
    (3, ("--explore", "4"), "was run with --explore 3, this one has --explore 4"),
    (None, ("--explore", "4"), "was run without --explore, this one has --explore 4"),
])
def test_resume_of_another_explore_count_says_so(tmp_path: Path, then: int | None,
                                                 now: tuple[str, ...], said: str) -> None:
    """The refusal said "the spec or a file it names changed": neither had."""
    from ncgate.gateway.sweep.spec import load_spec
    from ncgate.gateway.sweep.table import Parts

    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [50, 100]\n')
    # The parts of a sweep stopped before its first row, as that sweep left them.
    Parts(tmp_path / "out.csv", load_spec(tmp_path / "spec.toml", then)).start(False)
    done = ncgate("sweep", "spec.toml", "-o", "out.csv", "--resume", *now, cwd=tmp_path)
    assert done.returncode == 2, done.stdout + done.stderr
    assert said in done.stderr and "changed" not in done.stderr, done.stderr
    assert len(done.stderr.splitlines()) == 1, done.stderr
    # The same count goes on from them.
    again = ncgate("sweep", "spec.toml", "-o", "out.csv", "--resume",
                   *(("--explore", str(then)) if then else ()), cwd=tmp_path)
    assert again.returncode == 0, again.stdout + again.stderr


# -- 6. a scheduler that goes away: one line -----------------------------------------------


def test_a_dask_scheduler_that_goes_away_is_one_line_on_stderr(elsewhere: Path,
                                                              tmp_path: Path) -> None:
    """The FutureCancelledError's text has a newline, so "went away" spanned two lines, and
    distributed's client logged its own traceback after it (distributed.client - ERROR)."""
    import os

    for i in range(3):  # about a second each on the worker
        (tmp_path / f"LONG{i}.nc").write_text("N1 (RPT,20000)\nN2 G1 X1 F100000\nN3 G1 X0\n"
                                              "N4 (ERP)\nN5 M30\n")
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["LONG*.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [50, 100]\n')
    with cluster_at(47402, elsewhere) as cluster:
        env = {**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "3s"}
        sweep = start("sweep", "spec.toml", "-o", "out.csv", "-q", "--scheduler",
                      cluster.address, cwd=tmp_path, env=env)
        try:
            parts = tmp_path / "out.csv.parts"
            wait_for(lambda: any(parts.glob("part-*.jsonl")) or sweep.poll() is not None,
                     "a first part")
            assert sweep.poll() is None, "the sweep ended before its scheduler went away"
            cluster.scheduler.kill()
            cluster.scheduler.wait()
            out, err = sweep.communicate(timeout=300)
        finally:
            sweep.kill()
    assert sweep.returncode == 1, out + err
    assert len(err.splitlines()) == 1, err
    [line] = err.splitlines()
    assert line.startswith(f"ncgate sweep: stopped: the Dask scheduler at {cluster.address} "
                           "went away ("), line
    assert line.endswith("run again with --resume once it serves again"), line


# -- 8. what the sweep says ------------------------------------------------------------------


def test_one_variant_is_said_as_one(tmp_path: Path) -> None:
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n')
    done = ncgate("sweep", "spec.toml", "-q", cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.splitlines()[0] == "1 variant: 1 ok", done.stdout


def test_resume_with_no_parts_says_it_runs_everything(tmp_path: Path) -> None:
    """It ran every variant again unsaid, as a sweep without --resume does."""
    (tmp_path / "OK.nc").write_text(LOOPS["OK"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["OK.nc"]\n[grid]\n'
                                        '"nc.feed_override" = [50, 100]\n')
    done = ncgate("sweep", "spec.toml", "-q", "--resume", cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    parts = (tmp_path / "spec.csv.parts").resolve()
    assert done.stdout.splitlines()[0] == (f"resuming: no rows kept in {parts}: all 2 "
                                           "variants to run"), done.stdout
    assert len(rows_of(tmp_path / "spec.csv")) == 2


# -- 4. the pytest kit's reproducer is the row's command ----------------------------------


def test_the_pytest_kits_reproducer_of_a_budget_timeout_has_its_until(tmp_path: Path) -> None:
    """The kit's `reproduce:` line left out --until BUDGET: the command it printed ran on for
    ever, where the table's `command` stops at the budget."""
    (tmp_path / "LOOP.nc").write_text(LOOPS["LOOP"])
    (tmp_path / "spec.toml").write_text('[sweep]\nprograms = ["LOOP.nc"]\nbudget_s = 5\n')
    (tmp_path / "test_library.py").write_text(
        "from ncgate.gateway.testing import ncgate_sweep\n\n"
        'test_library = ncgate_sweep("spec.toml")\n')
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-q",
                           "test_library.py"], cwd=tmp_path, text=True, capture_output=True,
                          timeout=300)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "timeout: still running at the virtual-time budget of 5 s" in done.stdout
    swept = ncgate("sweep", "spec.toml", "-q", cwd=tmp_path)
    [row] = rows_of(tmp_path / "spec.csv")
    assert swept.returncode == 1 and row["command"].endswith("--until 5.0"), row
    assert f"reproduce: {row['command']}\n" in done.stdout, done.stdout
