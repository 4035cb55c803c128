"""The timeline marks each write by who wrote it: the PLC, the plant, anyone else -- a new
user found the plant's writes and the faults' drawn as "PLC write"."""

from __future__ import annotations

import io
import re

from ncgate.gateway.timeline import WRITERS, write_gantt


def _write(t: float, var: str, who: str) -> dict[str, object]:
    return {"seq": 0, "t": t, "event": "write", "proc": 0, "var": var, "value": 1, "who": who}


def test_each_writer_has_its_mark_and_its_legend_entry() -> None:
    events = [{"seq": 0, "t": 0.0, "event": "start", "proc": 1, "prog": "A", "by": "api"},
              _write(0.1, "SA20", "plc"), _write(0.2, "SA40", "plant clamp"),
              _write(0.3, "SA10", "modbus 127.0.0.1:5000"),
              {"seq": 0, "t": 1.0, "event": "end", "proc": 1, "how": "M30"}]
    out = io.StringIO()
    write_gantt(events, 1, out)
    svg = out.getvalue()
    marks = re.findall(r'<path d="[^"]*" fill="(#[0-9a-f]{6})"><title>[^<]*?: (SA\d+)=', svg)
    assert {var: fill for fill, var in marks} == {
        "SA20": WRITERS["plc"][0], "SA40": WRITERS["plant"][0], "SA10": WRITERS["other"][0]}
    for _, label in WRITERS.values():
        assert f"\u25bc {label} write" in svg


def test_a_trace_with_plc_writes_only_shows_the_plc_entry() -> None:
    events = [_write(0.1, "SA20", "plc")]
    out = io.StringIO()
    write_gantt(events, 1, out)
    assert "\u25bc PLC write" in out.getvalue()
    assert "\u25bc plant write" not in out.getvalue()
