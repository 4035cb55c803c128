"""The trace file's and the console's line of an event (``events.as_line``, made without the
JSON encoder for speed) is byte for byte the line of spec 4.4 that ``to_jsonl(as_dict(e))``
makes with it: on every event of every example cell, and on the values a line can meet."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway.sim import run_sim
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.states import WaitKind, Where
from ncgate.interpreter.engine.trace import to_jsonl

from ..conftest import EXAMPLES

# The example cells that run (examples/errors holds programs that must not check).
CELLS = sorted(p.parent for p in EXAMPLES.glob("*/ncgate.toml") if p.parent.name != "errors")


def reference(event: ev.Event) -> str:
    return to_jsonl(ev.as_dict(event))


@pytest.mark.parametrize("cell", CELLS, ids=[c.name for c in CELLS])
def test_every_event_of_an_example_cell(cell: Path) -> None:
    config = load_config(cell / "ncgate.toml")
    script_path = cell / "script.toml"
    result = run_sim(config, config.nc.main, load_script(
        script_path if script_path.exists() else None), until=600.0)
    events = list(result.runtime.trace._all)
    assert events
    for event in events:
        assert ev.as_line(event) == reference(event)


def test_every_kind_of_event_the_examples_make_is_covered() -> None:
    kinds: set[str] = set()
    for cell in CELLS:
        config = load_config(cell / "ncgate.toml")
        script_path = cell / "script.toml"
        result = run_sim(config, config.nc.main, load_script(
            script_path if script_path.exists() else None), until=600.0)
        kinds |= {e.kind for e in result.runtime.trace._all}
    assert {"start", "wait", "resume", "snd", "end", "write", "alarm"} <= kinds, kinds


WHERE: Where = ("P\u00e9\"1", 3, None)
VALUES = ["plain", 'quote " and \\ backslash', "line\nbreak\ttab\x01", "\u00e9\u4e2d\U0001f600",
          "", 0, -1, 2**40, 1.5, -0.0, 1e20, 1e-7, 0.1 + 0.2, math.nan, math.inf, -math.inf,
          True, False, None]


@pytest.mark.parametrize("value", VALUES, ids=[repr(v) for v in VALUES])
def test_the_values_a_line_can_meet(value: object) -> None:
    for where in (None, WHERE, ("A", 1, 20)):
        for t in (0.0, 1.0000005, 123456.1234565, 1e-9):
            write = ev.Write(7, t, 0, where, "SA10", value, value)  # type: ignore[arg-type]
            assert ev.as_line(write) == reference(write)
            hazard = ev.Hazard(8, t, 2, where, value)  # type: ignore[arg-type]
            assert ev.as_line(hazard) == reference(hazard)


def test_events_with_structured_fields() -> None:
    for on in (ev.WaitOn(WaitKind.COND, 0, "SA10=1", 1.0, "door"),
               ev.WaitOn(WaitKind.COND, 0, "SYVAR3>2.5", 2.5, None),
               ev.WaitOn(WaitKind.SND, 2, None, None, None)):
        wait = ev.Wait(1, 0.5, 1, ("A", 2, 10), on)
        assert ev.as_line(wait) == reference(wait)
    alarm = ev.Alarm(2, 0.5, 1, None, AlarmCode.DIVISION_BY_ZERO, "a message with \"quotes\"")
    assert ev.as_line(alarm) == reference(alarm)
    for writer in (None, "modbus 127.0.0.1:40312"):
        resume = ev.Resume(3, 0.75, 2, None, "plc", writer)
        assert ev.as_line(resume) == reference(resume)


def test_the_kinds_the_examples_do_not_make() -> None:
    blocked = (ev.Blocked(1, "A", 3, 30, "waits for SA10=1"), ev.Blocked(2, "B", 1, None, "x"))
    events: list[ev.Event] = [
        ev.Stall(1, 1.0, 0, None, blocked),
        ev.Deadlock(2, 1.0, 0, None, blocked, "1 -> 2 -> 1"),
        ev.Remove(3, 1.0, 1, None, 4),
        ev.Display(4, 1.0, 1, ("A", 5, 50), "TOOL \"T1\" \u00e9"),
        ev.PlcReload(5, 1.0, 0, None, True, "web 127.0.0.1", ["/tmp/a.st"], 3, ["n"], [],
                     ["a.st:1:1: warning"]),
        ev.Force(6, 1.0, 0, None, "SA10", 1, "api"),
        ev.Force(7, 1.0, 0, None, None, None, "web 127.0.0.1"),
        ev.Forced(8, 1.0, 0, None, "main.n", -5, "api"),
        ev.Aux(9, 1.0, 1, ("A", 2, 20), "M08", "before_motion", "8", None),
        ev.AuxAck(10, 1.0, 1, None, "M08", "plc scan.st:4"),
        ev.Signal(11, 1.0, 1, None, 3, (2, 3), None, {1: 2.0, 2: 0.5}, "high"),
        ev.Signal(12, 1.0, 1, None, 3, "all", 2, {}, "low"),
    ]
    for event in events:
        assert ev.as_line(event) == reference(event)
