"""The plant's tick (docs/plant.md): what moves continuously is sampled on the grid of
plant.scan_ms, each sample written when its rounded value changes; the tick comes first at
its instant, so a PLC scan of that instant reads what it sampled; and the ticks of a lag's
settling tail that would write nothing are not run -- with every change still written at the
tick a tick of every period would have written it.

The expected values and times are worked out here from the lag's documented law,
``target + (a0 - target) * exp(-t / tau)`` rounded to a unit, not taken from a run."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway.sim import run_sim

SCAN = 0.010  # plant.scan_ms and plc.scan_ms

CELL = """[nc]
processes = 1
main = "O1"
[plc]
logic = "plc.st"
scan_ms = 10
[plant]
scan_ms = 10
[[plant.model]]
name = "pressure"
kind = "lag"
target = "SYVAR1"
actual = "SYVAR2"
time_constant_ms = 300
"""

# The PLC copies "pressure up" (5 bar of 10, as the machine example's coolant_ready) to SA30.
LOGIC = """PROGRAM main
SA[30] := SYVAR[2] >= 500;
END_PROGRAM
"""


def _sim(tmp_path: Path, target: int, until: float) -> list[dict[str, Any]]:
    (tmp_path / "O1.nc").write_text("N10 (DLY,10)\nN20 M30\n")
    (tmp_path / "plc.st").write_text(LOGIC)
    (tmp_path / "ncgate.toml").write_text(CELL)
    (tmp_path / "s.toml").write_text(f'[[write]]\nat = 0.5\nset = "SYVAR1={target}"\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "O1",
                     load_script(tmp_path / "s.toml"), until)
    return result.events


def _writes(events: list[dict[str, Any]], var: str) -> list[tuple[float, int]]:
    return [(e["t"], e["value"]) for e in events if e["event"] == "write" and e["var"] == var]


def _law(target: int, t: float) -> float:
    """The lag's value at ``t``: from 0 towards ``target`` since the step at 0.5 s."""
    return target * (1 - math.exp(-(t - 0.5) / 0.3))


def test_every_change_of_a_lag_is_written_at_the_tick_that_first_samples_it(
        tmp_path: Path) -> None:
    target = 800
    settle = 0.5 + 0.3 * math.log(2 * target)  # within half a unit: the target exactly
    writes = [w for w in _writes(_sim(tmp_path, target, 3.0), "SYVAR2") if w[0] > 0.5]
    assert writes and writes[-1][1] == target
    assert settle <= writes[-1][0] < settle + 1e-6  # the settle is a switch point
    grid = [round(0.5 + k * SCAN, 6) for k in range(1, round((settle - 0.5) / SCAN) + 1)]
    # Sampled on every tick of the grid before the settle, the value written would change at
    # exactly these ticks, to these values: the writes are those, no more, no fewer -- the
    # tail's ticks that were not run would have written nothing.
    expected, last = [], 0
    for t in grid:
        value = round(_law(target, t))
        if value != last and t < settle:
            expected.append((t, value))
            last = value
    assert [(round(t, 6), v) for t, v in writes[:-1]] == expected
    # (The tail is long: the last 80 units take over a second, a tick every 5 or more.)
    assert sum(1 for t, _ in expected if t > 1.5) < sum(1 for t in grid if t > 1.5) / 4


def test_a_scan_at_a_ticks_instant_reads_what_the_tick_sampled(tmp_path: Path) -> None:
    # The lag crosses 499.5 (rounded: 500) between two ticks; the tick after the crossing
    # samples 500 or more, and the PLC scan of that same instant reads it: SA30 rises there,
    # not a scan later.
    target = 600
    crossing = 0.5 + 0.3 * math.log(target / (target - 499.5))
    tick = math.ceil(round(crossing / SCAN, 9)) * SCAN
    events = _sim(tmp_path, target, 2.0)
    rise = [t for t, v in _writes(events, "SA30") if v == 1]
    assert rise and math.isclose(rise[0], tick, abs_tol=1e-9), (rise[:1], tick)
    first = next(t for t, v in _writes(events, "SYVAR2") if v >= 500)
    assert math.isclose(first, tick, abs_tol=1e-9)


def test_the_ticks_go_on_far_out_in_machine_time(tmp_path: Path) -> None:
    # 32,769 s in: 1 ms ticks at t / period ~ 3.3e7, where an epsilon added to it is lost in
    # the float; a tick due at k * period found its next at k again, for ever, and the clock
    # stood still (a shift's run at time_scale 10 gets there in under an hour).
    (tmp_path / "O1.nc").write_text("N10 (DLY,0.1)\nN20 M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nprocesses = 1\nmain = "O1"\n[plant]\nscan_ms = 1\n[[plant.model]]\n'
        'name = "spindle"\nkind = "motor"\nrun = "SA1"\nspeed = "SYVAR2"\nrated_rpm = 6000\n'
        'ramp_rpm_s = 12000\n')
    (tmp_path / "s.toml").write_text('[[write]]\nat = 32769.39\nset = "SA1=1"\n')
    result = run_sim(load_config(tmp_path / "ncgate.toml"), "O1",
                     load_script(tmp_path / "s.toml"), 32769.5)
    speeds = [(t, v) for t, v in _writes(result.events, "SYVAR2") if t > 32769.0]
    # Run up at 12,000 rpm/s from 32,769.39 s, sampled every 1 ms: 12 rpm a tick, each tick
    # once, to 1,320 rpm at 32,769.5 (0.11 s of it).
    assert speeds[:3] == [(32769.391, 12), (32769.392, 24), (32769.393, 36)], speeds[:3]
    assert all(round(b[0] - a[0], 6) == 0.001 for a, b in itertools.pairwise(speeds))
    assert speeds[-1] == (32769.5, 1320)
