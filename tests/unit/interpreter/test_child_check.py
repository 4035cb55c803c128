"""A big NC-110 program is checked in a child process (interpreter/child.py; issue 24, loading
never blocks): the reader's answer is the one a check in this process gives, nothing of the
check's work (the parsed blocks) is left in this process, a cancel ends the child at once, and
a child that cannot do the job leaves it to this process."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest

from ncgate.interpreter import child as child_module
from ncgate.interpreter.child import ChildCancelled, ChildFailed, ChildJobs
from ncgate.interpreter.diagnostics import ProgramSyntaxError
from ncgate.interpreter.dialect import DialectOptions
from ncgate.interpreter.nc110 import dialect as nc110_dialect
from ncgate.interpreter.nc110.checker import check_program
from ncgate.interpreter.nc110.compiler import exe_calls, exe_scan
from ncgate.interpreter.nc110.parser import Program
from ncgate.interpreter.storage import Storage, file_version

BODY = "".join(f"N{n % 9999}G1X{n % 500}Y{(n * 7) % 500}F6000\n" for n in range(30_000))


def reader(folder: Path) -> nc110_dialect._Reader:
    return nc110_dialect._Reader(DialectOptions(), Storage({"MP0": folder}, "MP0"))


def write_big(folder: Path, name: str, head: str = "", tail: str = "M30\n") -> Path:
    path = folder / f"{name}.nc"
    path.write_text(head + BODY + tail)
    assert path.stat().st_size >= nc110_dialect.CHILD_BYTES  # the child's size
    return path


def here(path: Path, process: int) -> list[str]:
    """The errors a check in this process finds (what the thread did before the child)."""
    program = Program.from_path(path, display=path.name)
    context = nc110_dialect.check_context(DialectOptions(), Storage({"MP0": path.parent},
                                                                    "MP0"), {process})
    return [d.render() for d in check_program(program, context) if d.is_error]


def test_a_good_big_program_is_checked_apart_and_parsed_here_as_it_runs(
        tmp_path: Path) -> None:
    (tmp_path / "SUB.nc").write_text("N1M30\n")
    path = write_big(tmp_path, "BIG", head="N1(EXE,2,SUB)\n")
    program = reader(tmp_path).load(path, file_version(path), 1, apart=True)
    # The check ran elsewhere: of its blocks, only the first few were parsed in this process,
    # by the reading thread, so that the loop finds the block parser built (45 ms, once) ...
    warm = nc110_dialect.WARM_BLOCKS
    assert len(program) == 30_002
    assert None not in program._blocks[:warm]
    assert program._blocks[warm:].count(None) == len(program) - warm
    # ... and what the engine asks of the program is what reading it here gives.
    assert program.exe_scan is not None
    fresh = Program.from_path(path, display=path.name)
    assert exe_scan(program) == exe_scan(fresh) == (frozenset({2}), False)
    assert exe_calls(program) == exe_calls(fresh) == frozenset({(2, "SUB")})
    assert list(program.lines) == list(fresh.lines) and program.labels == fresh.labels
    assert program.block(1) == fresh.block(1)  # parsed when it runs


def test_a_bad_big_program_has_the_errors_a_check_here_finds(tmp_path: Path) -> None:
    # 1,200 errors: more than one frame of the child's answer (500 a frame), in order.
    bad = "".join(f"N{n}(WAI,SA99999=1)\n" for n in range(1200))
    path = write_big(tmp_path, "BAD", head=bad, tail="N9(EXE,2,NOWHERE)\nM30\n")
    with pytest.raises(ProgramSyntaxError) as caught:
        reader(tmp_path).load(path, file_version(path), 1, apart=True)
    found = [d.render() for d in caught.value.diagnostics]
    assert found == here(path, 1)
    assert len(found) == 1201 and "SA99999" in found[0] and "NOWHERE" in found[-1]


def test_a_big_file_that_is_not_utf8_names_its_first_bad_byte(tmp_path: Path) -> None:
    path = write_big(tmp_path, "LATIN")
    path.write_bytes(path.read_bytes() + b"N1(MSG,caf\xe9)\n")
    with pytest.raises(ProgramSyntaxError) as caught:
        reader(tmp_path).load(path, file_version(path), 1, apart=True)
    with pytest.raises(ProgramSyntaxError) as direct:
        Program.from_path(path, display=path.name)
    assert [d.render() for d in caught.value.diagnostics] == [
        d.render() for d in direct.value.diagnostics]
    assert "NC015" in str(caught.value)


def test_a_cancel_ends_the_child_and_its_waiting_caller(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "forever.py").write_text(  # a job that runs until it is killed
        "import threading\n"
        "def job(payload):\n"
        "    threading.Event().wait()\n"
        "    yield 'never'\n")
    monkeypatch.syspath_prepend(str(tmp_path))  # the child has the parent's path
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    spawned = threading.Event()
    real_popen = child_module.subprocess.Popen

    def popen(*args: Any, **kwargs: Any) -> Any:
        child = real_popen(*args, **kwargs)
        spawned.set()
        return child

    monkeypatch.setattr(child_module.subprocess, "Popen", popen)
    jobs = ChildJobs()
    outcome: list[BaseException] = []

    def run() -> None:
        try:
            jobs.run("forever:job", (), b"")
        except BaseException as exc:
            outcome.append(exc)

    thread = threading.Thread(target=run)
    thread.start()
    assert spawned.wait(30)
    jobs.cancel()  # (a cancel between the start and the bookkeeping counts too)
    thread.join(30)
    assert not thread.is_alive()
    assert len(outcome) == 1 and isinstance(outcome[0], ChildCancelled), outcome
    assert not jobs._running


def test_a_job_that_raises_in_the_child_is_a_failure_with_its_traceback() -> None:
    with pytest.raises(ChildFailed) as caught:
        ChildJobs().run("ncgate.interpreter.nc110.dialect:check_in_child", (), b"")
    assert "TypeError" in str(caught.value)  # missing arguments, raised in the child


def test_a_reader_whose_child_fails_checks_here(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    def no_child(self: ChildJobs, *args: object) -> list[object]:
        raise ChildFailed("no child process: [Errno 11] Resource temporarily unavailable")

    monkeypatch.setattr(ChildJobs, "run", no_child)
    bad = "N1(WAI,SA99999=1)\n"
    path = write_big(tmp_path, "BAD", head=bad)
    with pytest.raises(ProgramSyntaxError) as caught:
        reader(tmp_path).load(path, file_version(path), 1, apart=True)
    assert [d.render() for d in caught.value.diagnostics] == here(path, 1)
    good = write_big(tmp_path, "GOOD")
    program = reader(tmp_path).load(good, file_version(good), 1, apart=True)
    assert program._blocks.count(None) == 0  # checked here: every block parsed


def test_on_the_loop_a_big_program_is_checked_here(tmp_path: Path) -> None:
    """An EXE whose program was not read ahead loads it on the loop: a child would only be
    waited for (and checks slower than this process), so the check is done here."""
    spawned: list[object] = []

    class Watching(ChildJobs):
        def run(self, *args: object) -> list[object]:  # type: ignore[override]
            spawned.append(args)
            return super().run(*args)  # type: ignore[arg-type]

    path = write_big(tmp_path, "BIG")
    on_the_loop = reader(tmp_path)
    on_the_loop.jobs = Watching()
    program = on_the_loop.load(path, file_version(path), 1)  # apart=False: the loop's call
    assert spawned == [] and program._blocks.count(None) == 0  # every block parsed here
