"""`ncgate check` on the manual's runnable examples (examples/) and on our corpus."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from ncgate.gateway.cli.check import check_files
from ncgate.gateway.cli.main import main
from ncgate.interpreter.codes import DiagnosticCode as C

from ..conftest import EXAMPLES, PROGRAMS

# The diagnostic each file of errors/ must give: its first line says so in words; the code is
# our table's name for that sentence.
EXPECTED_ERRORS = {
    "bad_process.nc": C.PROCESS_OUT_OF_RANGE,
    "bit_greater.nc": C.COMPARE_BIT_ORDER,
    "missing_paren.nc": C.MISSING_CLOSE_PAREN,
    "no_operator.nc": C.MISSING_COMPARISON,
    "self_wait.nc": C.WAIT_FOR_SELF,
    "unknown_label.nc": C.UNKNOWN_LABEL,
    "word_without_value.nc": C.WORD_WITHOUT_VALUE,
}
_EXPECT = re.compile(r"^; expect(?: \(run in process (\d+)\))?: an error on line (\d+): (.*)$")


def scenario_files() -> list[Path]:
    return sorted(p for p in EXAMPLES.glob("*/*.nc") if p.parent.name != "errors")


# The ISG example that shows the buffer-effect deadlock: check warns of it (and only of it).
EXPECTED_WARNINGS = {"isg_no_flush/NOFLUSH.nc": [(C.ISG_BUFFERED_SELF_SIGNAL, 14)]}


@pytest.mark.parametrize("path", scenario_files(), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_example_program_checks_clean(path: Path) -> None:
    (report,) = check_files([path])
    expected = EXPECTED_WARNINGS.get(f"{path.parent.name}/{path.name}", [])
    assert [(d.code, d.span.line) for d in report.diagnostics] == expected


def test_errors_folder_is_fully_covered() -> None:
    assert {p.name for p in (EXAMPLES / "errors").glob("*.nc")} == set(EXPECTED_ERRORS)


@pytest.mark.parametrize("name", sorted(EXPECTED_ERRORS))
def test_each_error_example_gives_its_diagnostic_on_its_line(name: str) -> None:
    path = EXAMPLES / "errors" / name
    first = path.read_text().splitlines()[0]
    match = _EXPECT.match(first)
    assert match, f"unexpected first line: {first}"
    process = int(match.group(1)) if match.group(1) else None
    line = int(match.group(2))
    (report,) = check_files([path], process=process)
    errors = [d for d in report.diagnostics if d.is_error]
    assert EXPECTED_ERRORS[name] in {d.code for d in errors if d.span.line == line}
    assert {d.span.line for d in errors} == {line}  # nothing reported elsewhere


def test_cli_exit_statuses_and_output(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", str(EXAMPLES / "scheme3")]) == 0
    assert main(["check", str(EXAMPLES / "errors" / "bit_greater.nc")]) == 1
    out = capsys.readouterr().out
    assert "bit_greater.nc:2:9: error NC030: SA10 is a bit, only = and # compare it" in out
    assert "  N40(WAI,SA10>0)\n          ^" in out
    assert main(["check", str(EXAMPLES / "nowhere.nc")]) == 2
    assert main(["check", "--bogus"]) == 2
    assert main(["check", "--process", "9", str(EXAMPLES / "errors" / "self_wait.nc")]) == 2


def test_cli_globs_directories_and_process_option() -> None:
    pattern = str(EXAMPLES / "mutual" / "MUT*.nc")
    assert main(["check", pattern]) == 0
    assert main(["check", "--process", "1", str(EXAMPLES / "errors" / "self_wait.nc")]) == 1


def test_cli_without_files_checks_the_builtin_programs() -> None:
    assert main(["check"]) == 0


def test_module_entry_point_runs() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "ncgate", "check", str(EXAMPLES / "errors" / "missing_paren.nc")],
        capture_output=True, text=True, check=False,
    )
    assert done.returncode == 1
    assert "missing_paren.nc:3:16: error NC012: expected ')' to close (WAI" in done.stdout


def test_process_inferred_from_exe_in_main() -> None:
    # PROG92 is started by the main program in process 2: (WAI,2) in it is a self-wait.
    folder = PROGRAMS / "infer"
    (report,) = check_files([folder / "SUB.nc"])
    assert [(d.code, d.span.line) for d in report.diagnostics] == [(C.WAIT_FOR_SELF, 2)]


@pytest.mark.parametrize("path", sorted((PROGRAMS / "valid").glob("*.nc")), ids=lambda p: p.name)
def test_corpus_valid_programs(path: Path) -> None:
    (report,) = check_files([path])
    assert report.diagnostics == ()


@pytest.mark.parametrize("path", sorted((PROGRAMS / "invalid").glob("*.nc")),
                         ids=lambda p: p.name)
def test_corpus_invalid_programs(path: Path) -> None:
    """Each file's first line: `; expect: CODE line:col [CODE line:col ...]`."""
    first = path.read_text().splitlines()[0]
    assert first.startswith("; expect: ")
    expected = [(c, *map(int, pos.split(":"))) for c, pos in
                zip(first.split()[2::2], first.split()[3::2], strict=True)]
    (report,) = check_files([path])
    assert [(d.code.code, d.span.line, d.span.column) for d in report.diagnostics] == expected
