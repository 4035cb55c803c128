"""A `run --script` session recorded (`--record`) replays and matches (`sim --replay`) when a
script's entry falls on the PLC's scan grid and a scan reads it: the entry acts after the scan
of its instant, live as in the replay, which applies it after every timer of its time
(docs/decisions.md, "Script entries act after the timers of their instant")."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from ncgate.gateway.record import read_record
from ncgate.inputs import Writes

# Scans every 125 ms, a time a binary float holds exactly: an entry 0.25 s after a scan's
# write is on the grid to the bit, in the session, its record (to the microsecond) and the
# replay.  A scan apart is 125 ms, beyond the replay's tolerance (10 ms).
CONFIG = """[nc]
processes = 1
main = "O1"
[nc.storage]
MP0 = "."
[plc]
logic = "cell.st"
scan_ms = 125
[modbus]
port = 0
[canopen]
enabled = false
[web]
enabled = false
"""

# SA21 follows the script's first write at the next scan (on the grid); the script's second
# write, 0.25 s after that (on the grid again), is what the program waits for, through the PLC.
LOGIC = """PROGRAM cell
SA[21] := SA[20];
SA[30] := SA[22];
END_PROGRAM
"""

SCRIPT = """[[write]]
at = 0.1
set = "SA20=1"

[[write]]
when = "SA21=1"
after = 0.25
set = "SA22=1"

[[expect]]
name = "the program ends"
cond = "P1 IDLE"
within = [1.0, 1.5]
"""


def ncgate(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ncgate", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=90, check=False)


def test_a_script_entry_on_the_scan_grid_replays_as_the_session_ran_it(
        tmp_path: Path) -> None:
    (tmp_path / "O1.nc").write_text("N10 (WAI,SA30=1)\nN20 M30\n")
    (tmp_path / "cell.st").write_text(LOGIC)
    (tmp_path / "ncgate.toml").write_text(CONFIG)
    (tmp_path / "s.toml").write_text(SCRIPT)
    record = tmp_path / "session.jsonl"
    done = ncgate("run", "--config", "ncgate.toml", "--script", "s.toml", "--record",
                  str(record), "-q", cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    recording = read_record(record)
    # The second write is on the grid: k scans of 125 ms from the PLC's start, to the bit.
    writes = [r.t for r in recording.inputs if isinstance(r.input, Writes)]
    assert len(writes) == 2 and (writes[1] / 0.125).is_integer(), writes
    done = ncgate("sim", "--replay", str(record), cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "the replay matches" in done.stdout, done.stdout
    # The scan of its instant did not see it, the next did: the program resumed a scan on.
    resume = next(e for e in recording.events if e["event"] == "resume")
    assert resume["t"] == writes[1] + 0.125, (resume, writes)
