"""Issue 25, items 10-15: what the commands do at their edges -- `sim`'s verdict with PLC
logic, its end with `--until`, its options and signals; `run`'s refusal of programs it cannot
run; the wording of errors; the built-in cell's first run."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from ncgate.gateway.cli.main import main

from ..conftest import EXAMPLES
from ..helpers import write_cell

FAULTY = """PROGRAM main
VAR q : INT; END_VAR
q := 100 / SYVAR[1];
SYVAR[2] := q;
END_PROGRAM
"""

# Presses NC.START for the next part whenever process 1 is idle, two more parts after the
# first, as a cell's PLC does (a rising edge is a cycle start: docs/plc.md).
NEXT_PART = """PROGRAM cell
VAR parts : INT; pressed : BOOL; END_VAR
IF pressed THEN
  NC.START := FALSE;
  pressed := FALSE;
ELSIF NC.P[1].IDLE AND parts < 2 THEN
  NC.START := TRUE;
  pressed := TRUE;
  parts := parts + 1;
END_IF
END_PROGRAM
"""


def events_of(path: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


# -- item 10: any alarm is exit 1 ------------------------------------------------------------


def test_sim_exits_1_when_the_plc_logic_faults(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "logic.st").write_text(FAULTY)
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'
                         '[plc]\nlogic = "logic.st"\n', {"A": "N1G1X10F600\nN2M30\n"})
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"),
                 "--trace", str(tmp_path / "t.jsonl")]) == 1
    out = capsys.readouterr().out
    assert "PLC alarm AL160" in out
    assert out.rstrip().endswith(": every program ended, 1 alarm")
    alarms = [e for e in events_of(tmp_path / "t.jsonl") if e["event"] == "alarm"]
    assert [(e["proc"], e["code"]) for e in alarms] == [(0, "AL160")]


# -- item 11: PLC logic keeps the simulation going to --until ---------------------------------


def test_sim_with_plc_logic_runs_to_until_so_the_plc_starts_the_next_parts(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "cell.st").write_text(NEXT_PART)
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'
                         '[plc]\nlogic = "cell.st"\n', {"A": "N1G1X10F700\nN2G0X0\nN3M30\n"})
    config = str(tmp_path / "ncgate.toml")
    assert main(["sim", "--config", config, "--until", "30",
                 "--trace", str(tmp_path / "t.jsonl")]) == 0
    out = capsys.readouterr().out
    assert out.rstrip().endswith("simulated 30.000 s: stopped at --until")
    starts = [e["by"] for e in events_of(tmp_path / "t.jsonl") if e["event"] == "start"]
    assert starts == ["script", "plc cell.st:7", "plc cell.st:7"]
    # Without --until the run still ends when every process is idle.
    assert main(["sim", "--config", config, "--trace", str(tmp_path / "t.jsonl")]) == 0
    assert "every program ended" in capsys.readouterr().out
    assert [e["event"] for e in events_of(tmp_path / "t.jsonl")].count("start") == 1


def test_sim_with_a_script_entry_still_to_come_runs_to_until(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n',
               {"A": "N1G1X10F600\nN2M30\n"})
    (tmp_path / "script.toml").write_text('[[write]]\nat = 20.0\nset = "SYVAR3=7"\n')
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"), "--script",
                 str(tmp_path / "script.toml"), "--until", "30",
                 "--trace", str(tmp_path / "t.jsonl")]) == 0
    # The program ends at 1 s; the script's last input comes at 20 s, and nothing after it.
    assert capsys.readouterr().out.rstrip().endswith("simulated 20.000 s: every program ended")
    writes = [(e["t"], e["var"]) for e in events_of(tmp_path / "t.jsonl")
              if e["event"] == "write"]
    assert writes == [(20.0, "SYVAR3")]


# -- item 12: sim --set, --dialect, SIGTERM ----------------------------------------------------


def test_sim_sets_config_keys_like_run(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n',
               {"A": "N1M30\n", "B": "N1G1X10F600\nN2M30\n"})
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"), "--set", "nc.main=B",
                 "--set", "nc.rapid_mm_min=5000", "--trace", str(tmp_path / "t.jsonl")]) == 0
    assert [e["prog"] for e in events_of(tmp_path / "t.jsonl") if e["event"] == "start"] == ["B"]
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"),
                 "--set", "nc.lookahead=-1"]) == 2
    assert "nc.lookahead: expected an integer" in capsys.readouterr().err


def test_sim_runs_an_isg_file_with_dialect_and_suggests_it_without(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "PATHS.nc").write_text((EXAMPLES / "isg_paths" / "PATHS.nc").read_text())
    (tmp_path / "ncgate.toml").write_text('[nc]\nprocesses = 3\n[nc.storage]\nMP0 = "."\n')
    config = str(tmp_path / "ncgate.toml")
    assert main(["sim", "PATHS", "--config", config]) == 2
    err = capsys.readouterr().err
    assert "error NC002" in err
    assert "PATHS.nc reads without error as isg: give --dialect isg" in err
    assert main(["sim", "PATHS", "--config", config, "--dialect", "isg"]) == 0
    assert "every program ended" in capsys.readouterr().out
    assert main(["check", str(tmp_path / "PATHS.nc"), "--config", config]) == 1
    assert "give --dialect isg" in capsys.readouterr().err


def test_sigterm_ends_sim_with_its_summary_and_trace(tmp_path: Path) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\nblock_time_ms = 250\n[nc.storage]\nMP0 = "."\n',
               {"A": '"L"\nN1(DIS,"tick")\nN2(BNC,L)\n'})
    trace = tmp_path / "t.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "ncgate", "sim", "--config",
                             str(tmp_path / "ncgate.toml"), "--trace", str(trace)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # Nothing to wait on but the other process's state: poll until it catches SIGTERM
        # (the SigCgt mask in /proc), which it does only once the simulation is running.
        deadline = time.monotonic() + 30
        while not catches_sigterm(proc.pid):
            assert time.monotonic() < deadline and proc.poll() is None, proc.communicate()
            time.sleep(0.01)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 1, err
    assert out.rstrip().endswith("interrupted (SIGTERM)"), out
    assert "Traceback" not in err
    assert any(e["event"] == "display" for e in events_of(trace))


def catches_sigterm(pid: int) -> bool:
    status = Path(f"/proc/{pid}/status").read_text()
    mask = next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:"))
    return bool(int(mask, 16) >> (signal.SIGTERM - 1) & 1)


# -- item 14: the wording of errors ------------------------------------------------------------


def test_a_taken_hub_port_names_canopen_hub_port(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(
            [sys.executable, "-m", "ncgate", "run", "--no-web", "--port", "0",
             "--set", "canopen.hub=true", "--set", f"canopen.hub_port={port}",
             "--set", f"canopen.channel=hub-{tmp_path.name}"],
            capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert f"canopen.hub_port: cannot listen on 127.0.0.1:{port}" in done.stderr


@pytest.mark.parametrize(("args", "said"), [
    (["sim", "--set", "nc.lookahead=-1"], "ncgate sim: --set: nc.lookahead: expected an integer"),
    (["sim", "--set", "nc.main.x=1"], "ncgate sim: --set: nc.main.x: nc.main is a value, not"),
    (["run", "--port", "70000"], "ncgate run: --port: modbus.port: expected an integer"),
    (["run", "--web", "0.0.0.0:18080"], "ncgate run: --web: web.token: the console listens on"),
    # (a key no option set, refused for its section's: those options, not every one given)
    (["run", "--no-web", "--opcua", "0", "--port", "0", "--set", "opcua.host=0.0.0.0"],
     "ncgate run: --opcua --set: opcua.security: "),
    (["sim", "--set", "nc.lookahed=0"], "--set: nc.lookahed: unknown key (did you mean "
                                        "lookahead?)"),
])
def test_an_override_that_fails_is_blamed_on_its_option(
        capsys: pytest.CaptureFixture[str], args: list[str], said: str) -> None:
    assert main(args) == 2
    err = capsys.readouterr().err
    assert said in err
    assert "built-in default" not in err and "Traceback" not in err


def test_a_mistyped_key_in_a_file_suggests_the_nearest(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "ncgate.toml").write_text('[nc]\nlookahed = 0\n[modbus]\nprot = 502\n')
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 2
    assert "nc.lookahed: unknown key (did you mean lookahead?)" in capsys.readouterr().err
    (tmp_path / "ncgate.toml").write_text('[modbus]\nprot = 502\n')
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 2
    assert "modbus.prot: unknown key (did you mean port?)" in capsys.readouterr().err


def test_a_folder_given_as_config_is_said_in_a_sentence(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("sim", "check", "run", "map"):
        assert main([command, "--config", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert f"{tmp_path}: is a folder, not a config file" in err, err
        assert "Errno" not in err


def test_check_and_sim_do_not_refuse_a_console_bind_they_never_open(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'
                         '[web]\nhost = "0.0.0.0"\n', {"A": "N1M30\n"})
    config = str(tmp_path / "ncgate.toml")
    assert main(["sim", "--config", config]) == 0
    assert main(["check", "--config", config]) == 0
    assert main(["map", "--config", config]) == 0
    capsys.readouterr()
    assert main(["run", "--config", config]) == 2  # run serves it: a token is needed
    assert "web.token: the console listens on 0.0.0.0" in capsys.readouterr().err


def test_version_answers_without_importing_the_gateway() -> None:
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "ncgate", "--version"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stdout.startswith("ncgate "), done
    imported = {line.split("|")[-1].strip() for line in done.stderr.splitlines()
                if line.startswith("import time:")}
    assert "ncgate.gateway.cli.main" in imported  # the measure sees the command's imports
    assert not imported & {"ncgate.gateway.app", "pymodbus", "canopen", "can", "aiohttp",
                           "lark", "ncgate.interpreter.engine"}


# -- item 13: run refuses programs it cannot run; a missing MP0 is said ------------------------


@pytest.mark.parametrize(("programs", "said"), [
    ({}, "nc.main: program A is not on MP0"),
    ({"A": "N1G1X10F600\nN2(WAI,SA1=)\nN3M30\n"}, "A.nc:2:"),
    ({"A": "N1(EXE,2,B)\nN2M30\n"}, "error NC050: program B not found"),
])
def test_run_refuses_a_main_program_it_cannot_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], programs: dict[str, str],
        said: str) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n', programs)
    assert main(["run", "--config", str(tmp_path / "ncgate.toml"), "--no-web"]) == 2
    err = capsys.readouterr().err
    assert said in err
    assert "not started" in err and "--allow-missing" in err


def test_run_refuses_a_missing_storage_folder(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\nMP2 = "later"\n',
               {"A": "N1M30\n"})
    assert main(["run", "--config", str(tmp_path / "ncgate.toml"), "--no-web"]) == 2
    assert f"nc.storage.MP2: no such folder: {tmp_path / 'later'}" in capsys.readouterr().err


async def test_run_with_allow_missing_starts_a_cell_whose_programs_arrive_later(
        tmp_path: Path) -> None:
    from .test_cli_run import start_run, stop_run

    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n[modbus]\nport = 0\n'
                         '[canopen]\nenabled = false\n', {})
    proc, _, lines = await start_run(tmp_path / "ncgate.toml", "--no-web", "--allow-missing")
    code, log = await stop_run(proc, lines)
    assert code == 0, log


@pytest.mark.parametrize("command", [["sim"], ["check"]])
def test_check_and_sim_say_when_mp0_does_not_exist(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], command: list[str]) -> None:
    write_cell(tmp_path, '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "gone"\n', {"A": "N1M30\n"})
    assert main([*command, "--config", str(tmp_path / "ncgate.toml")]) == 2
    assert f"nc.storage.MP0: no such folder: {tmp_path / 'gone'}" in capsys.readouterr().err



@pytest.mark.parametrize(("extra", "code", "said"), [
    ('[plant]\nlogic = "plant.st"\n', 1, "plant.st:3:6: error ST010: unknown variable y"),
    ('[[plant.model]]\nname = "a"\nkind = "delay"\ninput = "SA1"\noutput = "SA40"\n'
     '[[plant.model]]\nname = "b"\nkind = "delay"\ninput = "SA2"\noutput = "SA40"\n', 2,
     "ncgate.toml: plant.model[1].output: SA40 is driven by a.output already"),
])
def test_check_of_a_config_refuses_what_run_and_sim_refuse_of_its_plant(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: str, code: int,
        said: str) -> None:
    """A new user's `check --config` said 0 errors where `run` then refused the plant's
    logic (ST010) or two models driving one input."""
    write_cell(tmp_path, f'[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n{extra}',
               {"A": "N1M30\n"})
    (tmp_path / "plant.st").write_text("PROGRAM Plant\nVAR x : INT; END_VAR\nx := y + 1;\n"
                                       "END_PROGRAM\n")
    assert main(["check", "--config", str(tmp_path / "ncgate.toml")]) == code
    out, err = capsys.readouterr()
    assert said in out + err
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 2  # as sim refuses it


def logic_cell(folder: Path, section: str, logic: str, programs: str = "") -> None:
    """A cell whose [plc] or [plant] ``logic`` (TOML) is lib.st (a function block, no
    PROGRAM) or main.st (PROGRAM Main), beside its config."""
    write_cell(folder, f'[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'
                       f'[{section}]\nlogic = {logic}\n{programs}', {"A": "N1M30\n"})
    (folder / "lib.st").write_text("FUNCTION_BLOCK Lib\nVAR x : INT; END_VAR\nx := 1;\n"
                                   "END_FUNCTION_BLOCK\n")
    (folder / "main.st").write_text("PROGRAM Main\nVAR x : INT; END_VAR\nx := 1;\n"
                                    "END_PROGRAM\n")


@pytest.mark.parametrize("section", ["plc", "plant"])
@pytest.mark.parametrize(("logic", "programs", "said"), [
    ("lib.st", "", "{section}.logic: the files hold no PROGRAM to run"),
    ("main.st", 'programs = ["nosuch"]\n',
     "{section}.programs[0]: no PROGRAM nosuch in {section}.logic (PROGRAMs: Main)"),
    ("main.st", 'programs = ["Main", "main"]\n',  # (it ran twice a scan)
     "{section}.programs[1]: main is listed twice (also {section}.programs[0]): a PROGRAM "
     "runs once a scan"),
])
def test_check_of_a_config_refuses_the_programs_sim_would_not_find_in_its_logic(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], section: str, logic: str,
        programs: str, said: str) -> None:
    """`check --config` said 0 errors of logic that holds no PROGRAM, or of a `programs`
    entry naming none, which sim and run refuse: check now chooses the PROGRAMs as they do."""
    logic_cell(tmp_path, section, f'"{logic}"', programs)
    config = str(tmp_path / "ncgate.toml")
    message = f"{config}: {said.format(section=section)}"
    for command in ("sim", "check"):
        assert main([command, "--config", config]) == 2
        assert message in capsys.readouterr().err, command
    # The config's own logic, named as a file beside --config, is still the cell's (a hostile
    # try: `check --config C noprog.st` said 0 errors); another ST file named is checked
    # alone, as a library's may hold no PROGRAM.
    assert main(["check", "--config", config, str(tmp_path / logic)]) == 2
    assert message in capsys.readouterr().err
    (tmp_path / "other.st").write_text((tmp_path / "lib.st").read_text().replace("Lib", "Other"))
    fine = tmp_path / "fine.toml"
    fine.write_text(f'[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n[{section}]\n'
                    'logic = "main.st"\n')
    assert main(["check", "--config", str(fine), str(tmp_path / "other.st")]) == 0
    # Without --config, the config beside a logic file named is the one check takes: its own
    # logic is the cell's there too (`check main.st` beside it said 0 errors, sim refused).
    assert main(["check", str(tmp_path / logic)]) == 2
    assert f"{tmp_path.resolve() / 'ncgate.toml'}: {said.format(section=section)}" in \
        capsys.readouterr().err
    # A library beside it is checked alone -- under that config, which a PROGRAM listed twice
    # makes a config error of its own.
    assert main(["check", str(tmp_path / "other.st")]) == (2 if "twice" in said else 0)


@pytest.mark.parametrize(("extra", "said"), [
    ('[plc]\nlogic = "sub"\n', "plc.logic: is a folder, not a file: {tmp}/sub"),
    ('[plant]\nlogic = ["main.st", "sub"]\n', "plant.logic[1]: is a folder, not a file: "
     "{tmp}/sub"),
    ('[plc]\nlogic = "/dev/null"\n', "plc.logic: is not a regular file: /dev/null"),
    ('[plc]\nlogic = ""\n', "plc.logic: empty: give a file name"),
    ('[plc]\nlogic = ["main.st", ""]\n', "plc.logic[1]: empty: give a file name"),
    ('[plc]\nlogic = "gone.st"\n', "plc.logic: no such file: {tmp}/gone.st"),
    ('[plc]\nlogic = ["main.st", "./main.st"]\n',
     "plc.logic[1]: {tmp}/main.st is listed twice (also plc.logic[0]): list each file once"),
    ('[web.tls]\ncert = "/dev/null"\nkey = "main.st"\n',
     "web.tls.cert: is not a regular file: /dev/null"),
])
def test_a_config_file_name_that_is_no_file_says_what_it_is(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: str, said: str) -> None:
    """A folder, /dev/null or "" given as plc.logic all said "no such file" (of the config's
    own folder, for ""); a file listed twice was ST032 "Main is already defined at" its own
    line, in check, and sim ran it once."""
    write_cell(tmp_path, f'[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n{extra}',
               {"A": "N1M30\n"})
    (tmp_path / "sub").mkdir()
    (tmp_path / "main.st").write_text("PROGRAM Main\nVAR x : INT; END_VAR\nx := 1;\n"
                                      "END_PROGRAM\n")
    config = str(tmp_path / "ncgate.toml")
    for command in ("check", "sim"):
        assert main([command, "--config", config]) == 2
        err = capsys.readouterr().err
        assert f"ncgate {command}: {config}: {said.format(tmp=tmp_path.resolve())}\n" == err


SECURE_UA = '[opcua]\nsecurity = "sign"\ncertificate = "A.nc"\nprivate_key = "A.nc"\n'


@pytest.mark.parametrize(("extra", "said"), [
    ('[nc.storage]\nMP0 = "A.nc"\n', "nc.storage.MP0: is a file, not a folder: {tmp}/A.nc"),
    ('[nc.storage]\nMP0 = "."\nMP1 = "A.nc"\n',
     "nc.storage.MP1: is a file, not a folder: {tmp}/A.nc"),
    ('[nc.storage]\nMP0 = "/dev/null"\n', "nc.storage.MP0: is not a folder: /dev/null"),
    ('[nc.storage]\nMP0 = ""\n', "nc.storage.MP0: empty: give a folder"),
    (SECURE_UA + 'trusted = "/dev/null"\n',
     "opcua.trusted: is neither a regular file nor a folder: /dev/null"),
    (SECURE_UA + 'trusted = ["sub", ""]\n',
     "opcua.trusted[1]: empty: give a certificate file or a folder of them"),
    ('[plc]\nretain_file = ""\n', "plc.retain_file: empty: give a file name"),
    ('[trace]\nfile = ""\n', "trace.file: empty: give a file name"),
    ('[modbus.tls]\ncert = "A.nc"\nkey = "A.nc"\nca = ""\n', "modbus.tls.ca: empty: give a "
     "file name"),
    ('symbols_file = ""\n', "symbols_file: empty: give a file name"),
])
def test_a_config_folder_or_optional_file_name_that_is_none_says_what_it_is(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: str, said: str) -> None:
    """A file as a storage folder said "no such folder" (and as MP1, nothing: check and sim
    went on); "" as opcua.trusted trusted the config's own folder, and /dev/null passed (the
    server would fail at start reading it as a folder); "" as an optional file said "expected
    a non-empty string", where plc.logic says "empty: give a file name"."""
    write_cell(tmp_path, f'{extra}[nc]\nmain = "A"\n', {"A": "N1M30\n"})
    (tmp_path / "sub").mkdir()
    config = str(tmp_path / "ncgate.toml")
    for command in ("check", "sim"):
        assert main([command, "--config", config]) == 2
        err = capsys.readouterr().err
        assert f"ncgate {command}: {config}: {said.format(tmp=tmp_path.resolve())}\n" == err


def test_a_storage_folder_set_on_the_command_line_that_is_none_names_the_option(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """`--set nc.storage.MP0=A.nc` said "<built-in default>: ... no such folder"."""
    (tmp_path / "A.nc").write_text("N1M30\n")
    monkeypatch.chdir(tmp_path)
    for value, said in (("A.nc", f"is a file, not a folder: {tmp_path.resolve()}/A.nc"),
                        ("", "empty: give a folder")):
        assert main(["sim", "A.nc", "--set", f"nc.storage.MP0={value}"]) == 2
        assert capsys.readouterr().err == f"ncgate sim: --set: nc.storage.MP0: {said}\n"


def test_check_checks_a_file_given_twice_once_and_says_so(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`ncgate check plc.st plc.st` said ST032 "Main is already defined at plc.st:1:1" of
    plc.st:1:1 (twice, 2 errors); a program given by name and by its folder was counted and
    said twice."""
    write_cell(tmp_path, '[nc]\nmain = "A"\n', {"A": "N1G1X10F600\nN2(WAI,SA1=)\nN3M30\n"})
    (tmp_path / "main.st").write_text("PROGRAM Main\nVAR x : INT; END_VAR\nx := 1;\n"
                                      "END_PROGRAM\n")
    st = str(tmp_path / "main.st")
    assert main(["check", st, str(tmp_path / "." / "main.st")]) == 0
    assert capsys.readouterr().err == (f"ncgate check: {st} is given twice: checked once\n"
                                       "1 file(s) checked: 0 error(s), 0 warning(s)\n")
    assert main(["check", str(tmp_path / "A.nc"), str(tmp_path)]) == 1
    out, err = capsys.readouterr()
    assert out.count("A.nc:2:") == 1, out
    assert "2 file(s) checked: 1 error(s)" in err  # A.nc and main.st
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'
                                          'MP1 = "."\n')  # two devices, one folder
    assert main(["check", "--config", str(tmp_path / "ncgate.toml")]) == 1
    out, err = capsys.readouterr()
    assert out.count("A.nc:2:") == 1 and "1 file(s) checked: 1 error(s)" in err, out + err


def test_check_takes_a_hard_link_for_the_file_and_refuses_an_empty_or_slashed_argument(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A hostile try: a hard link was checked beside its file (ST032 "already defined" at its
    own line); `check ""` checked the current folder (`check "$UNSET"` passed); `check
    plc.st/` took the file."""
    st = tmp_path / "main.st"
    st.write_text("PROGRAM Main\nVAR x : INT; END_VAR\nx := 1;\nEND_PROGRAM\n")
    os.link(st, tmp_path / "hard.st")
    assert main(["check", str(st), str(tmp_path / "hard.st")]) == 0
    assert capsys.readouterr().err == (f"ncgate check: {tmp_path / 'hard.st'} is given twice: "
                                       "checked once\n1 file(s) checked: 0 error(s), "
                                       "0 warning(s)\n")
    for arg, said in (("", "an empty argument: give a file, a folder or a glob"),
                      (f"{st}/", f"not a folder: {st}/")):
        assert main(["check", arg]) == 2
        assert capsys.readouterr().err == f"ncgate check: {said}\n"


# -- item 15: the built-in cell runs its own programs without a hazard --------------------------


def test_the_built_in_cell_runs_its_programs_without_a_hazard(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "PROG91"]) == 0
    out = capsys.readouterr().out
    assert " hazard " not in out
    assert out.rstrip().endswith("every program ended")
    assert main(["check"]) == 0  # the built-in storage: PROG91/92/93, no diagnostic
    assert "3 file(s) checked: 0 error(s), 0 warning(s)" in capsys.readouterr().err


def test_the_hazard_example_shows_one_hazard_on_purpose(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    trace = tmp_path / "t.jsonl"
    assert main(["sim", "--example", "hazard", "--trace", str(trace)]) == 0
    out = capsys.readouterr().out
    assert [line for line in out.splitlines() if " hazard " in line] == [
        "[0.000] P1 hazard HAZ1.nc:4 N3: (SND,2) acted at decode time while motion programmed "
        "above it (N2) was still queued; mark the block # to act in motion order, or set "
        "nc.lookahead = 0"]
    snds = [(e["t"], e["n"]) for e in events_of(trace) if e["event"] == "snd"]
    assert snds == [(0.0, 3), (1.0, 4)]  # the plain N3 at decode time, the # N4 in motion
    assert main(["sim", "--example", "hazard", "--set", "nc.lookahead=0"]) == 0
    assert " hazard " not in capsys.readouterr().out


def test_map_into_a_reader_that_stops_early_ends_quietly() -> None:
    """`ncgate map | head -3`: the reader goes after a few lines; map said "[Errno 32] Broken
    pipe" (a new user's find).  The pipe is made smaller than the map, so that map is still
    writing when the reader closes."""
    import fcntl

    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)  # (Linux) the map is 17 KB
    proc = subprocess.Popen([sys.executable, "-m", "ncgate", "map"], stdout=write_end,
                            stderr=subprocess.PIPE, text=True)
    os.close(write_end)
    head = os.read(read_end, 64)
    os.close(read_end)
    _, err = proc.communicate(timeout=60)
    assert head.startswith(b"# Modbus map")
    assert proc.returncode == 0 and err == "", err


@pytest.mark.parametrize(("section", "key"), [("plc", "plc.logic"),
                                              ("plant", "plant.logic[1]")])
def test_a_logic_file_that_cannot_be_read_is_its_key(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
        section: str, key: str) -> None:
    """A logic file the config found, whose reading fails (its permissions: a fault injected
    here, since root reads any file), said only "[Errno 13] Permission denied: 'main.st'":
    it is the config error of its key, as a missing file is."""
    logic_cell(tmp_path, section,
               '"main.st"' if section == "plc" else '["lib.st", "main.st"]')
    unreadable = tmp_path / "main.st"
    open_ = os.open

    def refuse(path: Any, flags: int, *args: Any, **kwargs: Any) -> int:
        if Path(path).resolve() == unreadable.resolve():
            raise PermissionError(13, "Permission denied", str(path))
        return open_(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", refuse)
    config = tmp_path / "ncgate.toml"
    assert main(["sim", "--config", str(config)]) == 2
    assert f"ncgate sim: {config}: {key}: cannot read {unreadable}: Permission denied" in \
        capsys.readouterr().err


def test_a_logic_file_whose_read_fails_is_named_by_check_and_a_fifo_is_refused_at_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`check` said "[Errno 5] Input/output error" of a logic file whose read fails (a link
    to /proc/self/mem: found, then EIO), naming neither the file nor the key; and a FIFO put
    where a logic file was (run --watch reloads what appears there) held the reload's read
    for ever, waiting for a writer, and every reload after it (a hostile try)."""
    import threading

    from ncgate.plc.st.plcopen import read_logic_text

    (tmp_path / "ncgate.toml").write_text('[plc]\nlogic = "plc.st"\n')
    (tmp_path / "plc.st").symlink_to("/proc/self/mem")
    config = tmp_path / "ncgate.toml"
    for args, said in ((["check", str(tmp_path / "plc.st")], str(tmp_path / "plc.st")),
                       (["check", "--config", str(config)], "/proc/")):
        assert main(args) == 2
        err = capsys.readouterr().err  # (a file named: as named)
        assert f"plc.logic: cannot read {said}" in err and "Input/output error" in err, err
    fifo = tmp_path / "swapped.st"
    os.mkfifo(fifo)
    said: list[BaseException] = []

    def read() -> None:
        try:
            read_logic_text(fifo)
        except OSError as exc:
            said.append(exc)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(30)
    assert not reader.is_alive(), "the read of a FIFO waits for a writer"
    assert said and "not a regular file" in str(said[0]) and str(fifo) in str(said[0])
    assert main(["check", str(fifo)]) == 2
    assert f"not a regular file: {fifo}" in capsys.readouterr().err


def test_check_takes_a_cells_logic_by_its_path_whatever_its_name_or_how_often_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A cell's logic named plc.txt was checked as an NC program (4 errors) by `check
    plc.txt`, `check .` and `check --config`; one file that is the logic of two cells (a
    link) was the second cell's only when named first (a hostile try)."""
    (tmp_path / "a").mkdir()
    write_cell(tmp_path / "a", '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'
               '[plc]\nlogic = "plc.txt"\n', {"A": "N1M30\n"})
    (tmp_path / "a" / "plc.txt").write_text("PROGRAM Main\nVAR x : INT; END_VAR\nx := 1;\n"
                                            "END_PROGRAM\n")
    for args in (["plc.txt"], ["."], ["--config", "ncgate.toml"]):
        with contextlib.chdir(tmp_path / "a"):
            assert main(["check", *args]) == 0, args
        assert "NC0" not in capsys.readouterr().out
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "ncgate.toml").write_text('[plc]\nlogic = "../a/plc.txt"\n'
                                                'programs = ["Nope"]\n')
    (tmp_path / "b" / "plc.txt").symlink_to("../a/plc.txt")
    for order in (["b", "a"], ["a", "b"]):
        args = [str(tmp_path / folder / "plc.txt") for folder in order]
        assert main(["check", *args]) == 2, order
        assert "plc.programs[0]: no PROGRAM Nope" in capsys.readouterr().err


def st_cell(folder: Path, sections: tuple[str, ...], name: str, text: str) -> None:
    """A cell whose ``sections`` ([plc], [plant]) run the ST file ``name``: ``text``."""
    write_cell(folder, '[nc]\nmain = "O1"\n[nc.storage]\nMP0 = "."\n' + "".join(
        f'[{section}]\nlogic = "{name}"\n' for section in sections),
        {"O1": "N10 (DLY,1)\nN20 M30\n"})
    (folder / name).write_text(text)


def test_check_says_a_file_that_is_plc_and_plant_logic_once_and_as_it_was_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """One ST file as both [plc] and [plant] logic, with one error: `check O1.nc l.st` said it
    twice, as /abs/l.st, and counted "3 file(s) checked: 2 error(s)"."""
    st_cell(tmp_path, ("plc", "plant"), "l.st", "PROGRAM main\nVAR x : INT; END_VAR\n"
               "x := x + ;\nEND_PROGRAM\n")
    with contextlib.chdir(tmp_path):
        assert main(["check", "O1.nc", "l.st"]) == 1
        out, err = capsys.readouterr()
        assert out.count("error ST002") == 1 and out.startswith("l.st:3:10: error ST002"), out
        assert "2 file(s) checked: 1 error(s)" in err
        assert main(["check", "--config", "ncgate.toml"]) == 1
        out, err = capsys.readouterr()
        assert out.count("error ST002") == 1 and "2 file(s) checked: 1 error(s)" in err


def test_retain_in_the_plant_logic_is_a_warning_where_it_was_accepted_in_silence(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
        ) -> None:
    st_cell(tmp_path, ("plant",), "p.st", "PROGRAM tank\nVAR RETAIN level : INT; END_VAR\n"
               "level := level + 1;\nEND_PROGRAM\n")
    with contextlib.chdir(tmp_path):
        assert main(["check", "--config", "ncgate.toml"]) == 0
        out = capsys.readouterr().out
        assert "p.st:2:12: warning SW005: level is RETAIN: the plant's logic keeps nothing" \
            in out, out
        assert main(["sim", "--config", "ncgate.toml"]) == 0
    assert "warning SW005" in caplog.text


def test_check_process_is_one_of_the_config_beside_the_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`check A.nc --process 7` beside a config of 8 processes said "expected 1..5" (the
    built-in config's count), though A.nc is checked under the config beside it."""
    write_cell(tmp_path, "[nc]\nprocesses = 8\n", {"A": "N1 G1 X1 F100\nN2 M30\n"})
    assert main(["check", str(tmp_path / "A.nc"), "--process", "7"]) == 0
    assert main(["check", str(tmp_path / "A.nc"), "--process", "9"]) == 2
    assert "--process 9: expected 1..8" in capsys.readouterr().err


def test_examples_into_a_reader_gone_still_says_where_they_are() -> None:
    """`ncgate examples | head -0`: the reader gone before the list, the line on stderr that
    says where the examples are installed was lost with it (unbuffered output, as
    PYTHONUNBUFFERED makes it, met the closed pipe at the first line)."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader went before the first line
    proc = subprocess.Popen([sys.executable, "-m", "ncgate", "examples"], stdout=write_end,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    os.close(write_end)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0 and err.startswith("installed in "), err


@pytest.mark.parametrize(("program", "status"), [("N{n}(WAI,SA1=)\n", 1), ("N{n}G999\n", 0)])
def test_check_into_a_reader_that_stops_early_ends_quietly_with_the_status_it_found(
        tmp_path: Path, program: str, status: int) -> None:
    """`ncgate check | head -1` exited 0 whatever it found (main's BrokenPipe answer, right
    for map, which only prints).  The pipe is made smaller than the diagnostics, so that
    check is still writing when the reader closes; 0 when the diagnostics are warnings."""
    import fcntl

    (tmp_path / "A.nc").write_text("".join(program.format(n=n) for n in range(1, 301)) + "M30\n")
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)  # (Linux) the diagnostics are ~30 KB
    proc = subprocess.Popen([sys.executable, "-m", "ncgate", "check", str(tmp_path / "A.nc")],
                            stdout=write_end, stderr=subprocess.PIPE, text=True)
    os.close(write_end)
    head = os.read(read_end, 1024)
    os.close(read_end)
    _, err = proc.communicate(timeout=60)
    assert head.startswith(f"{tmp_path / 'A.nc'}:1:".encode()), head
    assert proc.returncode == status, err
    assert err.splitlines()[-1].startswith("1 file(s) checked: ") and "Traceback" not in err, err


@pytest.mark.parametrize(("program", "status"), [("N1(WAI,SA1=)\nM30\n", 1), ("N1G999\nM30\n", 0)])
def test_check_with_both_streams_into_a_reader_gone_keeps_the_status_it_found(
        tmp_path: Path, program: str, status: int) -> None:
    """`ncgate check ... 2>&1 | head -0` (or `| true`): the summary on stderr met the closed
    pipe, and main's BrokenPipe answer (map's) made it exit 0 -- a CI step with pipefail went
    green with errors (a hostile try)."""
    (tmp_path / "A.nc").write_text(program)
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before check writes a line
    proc = subprocess.run([sys.executable, "-m", "ncgate", "check", str(tmp_path / "A.nc")],
                          stdout=write_end, stderr=write_end, timeout=60)
    os.close(write_end)
    assert proc.returncode == status


@pytest.mark.parametrize("command", [["check", "A.nc"], ["sim", "A.nc"]])
def test_a_command_with_its_standard_output_closed_says_its_status_not_a_traceback(
        tmp_path: Path, command: list[str]) -> None:
    """`ncgate check A.nc >&-`: Python's sys.stdout is None, and check's flush of it was
    'this is a bug in ncgate' (exit 70); sim's too.  What it would print goes nowhere."""
    (tmp_path / "A.nc").write_text("N1(WAI,SA1=)\nM30\n" if command[0] == "check"
                                   else "N1(DLY,0.1)\nM30\n")
    proc = subprocess.run(["sh", "-c", 'exec "$@" >&-', "sh", sys.executable, "-m", "ncgate",
                           *command], cwd=tmp_path, capture_output=True, text=True,
                          timeout=60)
    assert "Traceback" not in proc.stderr and "a bug in ncgate" not in proc.stderr, proc.stderr
    assert proc.returncode == (1 if command[0] == "check" else 0), proc.stderr


def _output_of(buffered: bool) -> dict[str, str]:
    """The environment of a command whose standard output is a pipe: block-buffered as a
    shell gives it, or written through at each write (PYTHONUNBUFFERED, as in CI)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    return env if buffered else {**env, "PYTHONUNBUFFERED": "1"}


@pytest.mark.parametrize("buffered", [True, False], ids=["buffered", "unbuffered"])
@pytest.mark.parametrize(("cond", "status"), [("SA10=1", 1), ("SA10=0", 0)])
def test_sim_into_a_reader_that_stops_early_ends_quietly_with_the_status_it_found(
        tmp_path: Path, cond: str, status: int, buffered: bool) -> None:
    """`ncgate sim | head -1` exited 0 whatever the scenarios found: the reader's going was a
    BrokenPipeError out of the report, answered by main as map's, and the JUnit file was not
    written.  Each scenario's expectation FAILs (SA10 is never set) or passes; the pipe is
    made smaller than the report, so that sim is still writing when the reader closes."""
    import fcntl
    import xml.etree.ElementTree as ET

    (tmp_path / "A.nc").write_text("G1X10F600\nM30\n")
    scripts = []
    for i in range(24):  # ~0.8 KB of report each
        (tmp_path / f"s{i}.toml").write_text(
            f'[[expect]]\nname = "SA10"\ncond = "{cond}"\nwithin = [0.0, 0.5]\n')
        scripts += ["--script", f"s{i}.toml"]
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)  # (Linux)
    proc = subprocess.Popen([sys.executable, "-m", "ncgate", "sim", "A.nc", *scripts,
                             "--junit", "v.xml"], cwd=tmp_path, stdout=write_end,
                            stderr=subprocess.PIPE, text=True, env=_output_of(buffered))
    os.close(write_end)
    head = os.read(read_end, 1024)
    os.close(read_end)
    _, err = proc.communicate(timeout=120)
    assert head.startswith(b"== s0.toml"), head
    assert proc.returncode == status and err == "", err
    junit = ET.parse(tmp_path / "v.xml").getroot()
    assert (junit.get("tests"), junit.get("failures")) == ("24", str(24 * status))


@pytest.mark.parametrize("fmt", ["md", "csv"])
def test_map_into_a_reader_gone_before_it_starts_exits_0_quietly(fmt: str) -> None:
    """`ncgate map --format csv | head -0`: the 3 KB waited in a block-buffered stdout for
    the interpreter's last flush, which met the closed pipe: "Exception ignored ...
    BrokenPipeError", exit 120.  map only prints: 0."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    proc = subprocess.run([sys.executable, "-m", "ncgate", "map", "--format", fmt],
                          stdout=write_end, stderr=subprocess.PIPE, text=True,
                          env=_output_of(buffered=True), timeout=60)
    os.close(write_end)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


def test_check_of_a_glob_takes_the_programs_not_the_readme_beside_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`ncgate check 'examples/*'` read README.md and __init__.py as part programs (47
    errors, a new user's find); a glob gives what a folder gives, a file named is checked."""
    write_cell(tmp_path, '[nc]\nmain = "A"\n', {"A": "N1M30\n"})
    (tmp_path / "README.md").write_text("# A cell\n\nIt ends at once.\n")
    (tmp_path / "__init__.py").write_text("")
    assert main(["check", str(tmp_path / "*")]) == 0
    assert "1 file(s) checked: 0 error(s)" in capsys.readouterr().err
    assert main(["check", str(tmp_path / "README.md")]) == 1  # named: read as asked


@pytest.mark.parametrize("command", ["check", "sim", "map"])
def test_an_unknown_option_is_said_by_its_commands_usage(
        capsys: pytest.CaptureFixture[str], command: str) -> None:
    """`ncgate check --set x=y` printed the top level's usage (a new user's find): the
    command's own usage and name say what it takes."""
    assert main([command, "--bogus"]) == 2
    err = capsys.readouterr().err
    assert f"usage: ncgate {command} " in err
    assert f"ncgate {command}: error: unrecognized arguments: --bogus" in err
