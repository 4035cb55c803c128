"""``ncgate run``'s start with a big main program and ``nc.autostart``: is the main program
checked once or twice before the gateway serves?

Load: a generated NC-110 main program of ``--mb`` MB (3 by default: G1 moves, a label every
thousand lines, a loop counter and a DIS), ``nc.autostart = true``, no console, no CANopen,
in a temporary folder.  Three commands, each a process of its own, in alternating rounds:

- check: ``ncgate check BIG.nc`` -- one check of the program and the interpreter's start
  (the baseline);
- run: ``ncgate run``, from its start to the log line that it serves ("Modbus TCP on"), then
  SIGTERM;
- run --allow-missing: the same without the start-up check: the program is read once, by the
  autostart.

It prints each command's median and range in seconds, and each run's median against the
check's.  Target: ``run`` takes about one check (a ratio near 1), not two.

    .venv/bin/python bench/startup.py [--mb MB] [--rounds N]
"""

from __future__ import annotations

import argparse
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def generate(size_mb: float) -> str:
    """An NC-110 main program of about ``size_mb`` MB that checks without an error."""
    lines: list[str] = []
    size = 0
    n = 0
    while size < size_mb * 1_000_000:
        if n % 1000 == 0:
            line = f'"L{n // 1000}"\n'
        elif n % 1000 == 500:
            line = f"N{n % 9999}E1=E1+1\nN{(n + 1) % 9999}(DIS,\"block\",E1)\n"
        else:
            line = f"N{n % 9999}G1X{n % 500}Y{(n * 7) % 500}Z{(n * 3) % 90}F6000\n"
        lines.append(line)
        size += len(line)
        n += 1
    lines.append("M30\n")
    return "".join(lines)


def write_cell(folder: Path, size_mb: float) -> Path:
    (folder / "BIG.nc").write_text(generate(size_mb))
    config = folder / "ncgate.toml"
    config.write_text('[nc]\nmain = "BIG"\nautostart = true\n[nc.storage]\nMP0 = "."\n'
                      '[modbus]\nport = 0\n[canopen]\nenabled = false\n')
    return config


def time_check(config: Path) -> float:
    began = time.perf_counter()
    subprocess.run([sys.executable, "-m", "ncgate", "check", "--config", str(config), "-q",
                    str(config.parent / "BIG.nc")], check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - began


def time_run(config: Path, *more: str) -> float:
    """From the process's start to its line that it serves; then SIGTERM."""
    began = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "ncgate", "run", "--config", str(config),
                             "--no-web", *more], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None
    log = []
    try:
        for line in proc.stdout:
            log.append(line)
            if "Modbus TCP on" in line:
                return time.perf_counter() - began
        raise SystemExit("ncgate run ended before it served:\n" + "".join(log))
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--mb", type=float, default=3.0, help="the main program's size")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        config = write_cell(Path(tmp), args.mb)
        size = (Path(tmp) / "BIG.nc").stat().st_size
        print(f"main program: {size / 1e6:.2f} MB, "
              f"{(Path(tmp) / 'BIG.nc').read_text().count(chr(10)):,} lines; "
              f"{args.rounds} rounds")
        times: dict[str, list[float]] = {"check": [], "run": [], "run --allow-missing": []}
        for _ in range(args.rounds):
            times["check"].append(time_check(config))
            times["run"].append(time_run(config))
            times["run --allow-missing"].append(time_run(config, "--allow-missing"))
    base = statistics.median(times["check"])
    for name, found in times.items():
        median = statistics.median(found)
        print(f"{name:<20} median {median:5.2f} s  ({min(found):.2f}-{max(found):.2f})"
              f"  {median / base:4.2f}x check")


if __name__ == "__main__":
    main()
