"""The sim script loader (spec 4.3): entries, and errors naming the file and dotted key."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import ConfigError, load_config
from ncgate.config.script import load_script
from ncgate.gateway.door import Door
from ncgate.gateway.sim import ScriptPlayer
from ncgate.gateway.wiring import build_runtime


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "script.toml"
    path.write_text(text)
    return path


def test_entries_of_every_form(tmp_path: Path) -> None:
    script = load_script(write(tmp_path, """
[[write]]
at = 2.5
set = "SA10=1"
[[write]]
when = "SYVAR1=10"
after = 0.1
set = "SK250=8"
[[snd]]
when = "P3 WAIT_PROC"
from = 4
to = 3
"""))
    at, cond, snd = script.entries
    assert (at.key, at.at, at.when, at.set) == ("write[0]", 2.5, None, "SA10=1")
    assert (cond.when, cond.after, cond.set) == ("SYVAR1=10", 0.1, "SK250=8")
    assert (snd.key, snd.when, snd.sender, snd.target) == ("snd[0]", "P3 WAIT_PROC", 4, 3)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[[write]]\nset = \"SA1=1\"", "write[0]: give exactly one of 'at' and 'when'"),
        ("[[write]]\nat = -1\nset = \"SA1=1\"", "write[0].at: expected a time in seconds, 0 .."),
        ("[[write]]\nat = nan\nset = \"SA1=1\"", "write[0].at: expected a time in seconds"),
        ("[[write]]\nwhen = \"SA1=1\"\nafter = inf\nset = \"SA2=1\"",
         "write[0].after: expected a delay in seconds, 0 .. 86400 (a day)"),
        ("[[expect]]\ncond = \"SA1=1\"\nby = 1e9", "expect[0].by: expected a time in seconds"),
        ("[[expect]]\ncond = \"SA1=1\"\nwithin = [0, nan]",
         "expect[0].within: expected [from, to] in seconds, 0 <= from <= to <= 86400"),
        ("[[expect]]\nname = \"a\"\ncond = \"SA1=1\"\nby = 1\n"
         "[[expect]]\nname = \"a\"\ncond = \"SA2=1\"\nby = 2",
         'expect[1].name: "a" is expect[0]\'s name too'),
        ("[[fault]]\ntarget = \"SA1\"\nkind = \"stuck\"\nvalue = 1\nat = 10\n"
         "for_s = 100000", "fault[0].for_s: ends at 100010 s, past 86400 s"),
        ("[[write]]\nat = 1\nset = \"SA1\"", "write[0].set: expected an assignment"),
        ("[[write]]\nat = 1\nafter = 2\nset = \"SA1=1\"", "write[0].after: only with 'when'"),
        ("[[write]]\nat = 1\nset = \"SA1=1\"\ncolour = 3", "write[0].colour: unknown key"),
        ("[[snd]]\nat = 1\nfrom = 0\nto = 1", "snd[0].from: expected a process number"),
        ("[[plc]]\nat = 1", "plc: unknown key"),
    ],
)
def test_bad_entries_name_file_and_key(tmp_path: Path, text: str, message: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as caught:
        load_script(path)
    assert str(caught.value).startswith(f"{path}: ") and message in str(caught.value)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[[write]]\nat = 1\nset = \"SA10=2\"", "write[0].set: SA10 holds 0..1, not 2"),
        ("[[write]]\nat = 1\nset = \"SK9999=1\"", "write[0].set: SK9999 is outside the image"),
        ("[[write]]\nat = 1\nset = \"E1=1\"", "write[0].set: E parameters belong to a process"),
        ("[[write]]\nwhen = \"P9 IDLE\"\nset = \"SA1=1\"", "write[0].when: process 9 is not"),
        ("[[write]]\nwhen = \"P1 NAPPING\"\nset = \"SA1=1\"", "write[0].when: unknown state"),
        ("[[write]]\nwhen = \"SA10>1\"\nset = \"SA1=1\"", "write[0].when: SA10 is a bit"),
        ("[[snd]]\nat = 1\nfrom = 2\nto = 1", "snd[0].from: process 2 is not external"),
    ],
)
def test_entries_are_validated_against_the_config(tmp_path: Path, text: str,
                                                  message: str) -> None:
    path = write(tmp_path, text)
    runtime = build_runtime(load_config(None), closed=True)
    with pytest.raises(ConfigError) as caught:
        ScriptPlayer(runtime, load_script(path), Door(runtime))
    assert message in str(caught.value)
