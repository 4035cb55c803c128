"""The console in a real browser at field rates (issue 30, "The console at field scale", item 1).

``ncgate run`` in a child process; headless Chromium (Debian's ``chromium`` and
``chromedriver``, through Selenium) shows the console; a Modbus TCP client on loopback writes
one SYVAR (FC6) at a steady rate, each write a new value, for ``--seconds`` at each rate (50,
200, 1,000 and 2,000 writes/s by default).  A MutationObserver in the page stamps the moment
each write's row enters the event log.  Printed, one line per rate:

- the rate reached, and the write -> DOM delay p50 / p99 (send of the request to the row in
  the page; both clocks are this machine's wall clock) and the writes the page never showed;
- long tasks (the browser's Long Tasks API: main-thread tasks over 50 ms) and the longest;
- the renderers' CPU share while the writes come (the page's cost, which a busy machine
  blurs less than the long tasks' wall time);
- renderer memory: the page's JS heap and the renderer processes' resident size, after a
  garbage collection, at the end of the warm-up (``--warm-up``, default a quarter of the
  phase) and at the phase's end.

Target at 2,000 writes/s: p99 <= 250 ms, no long task over 50 ms, memory flat (+-10 % after
the warm-up).  The issue measured the page before the change: 54 writes/s p50 2.4 s, 104/s
p50 30 s, 204/s hung WebDriver for minutes.  There is no baseline in the same run: the targets
are the page's absolute budget (what an operator sees), and the page before the change cannot
be run at these rates at all.

    .venv/bin/python bench/console_browser.py                    # 10 s at each rate
    .venv/bin/python bench/console_browser.py --seconds 30 --rates 2000
    BENCH_PROFILE=1 .venv/bin/python bench/console_browser.py    # and the page's draw times

Measured on the 2-core machine shared with other work (30 s at each rate, a 10 s warm-up,
two runs): p99 104 / 95 / 70 / 114 ms and 57 / 53 / 58 / 119 ms at 50 / 200 / 1,000 / 2,000
writes/s, no long task at any rate, renderer RSS within +1.5 %.  At 2,000 writes/s over 90 s
(45 s warm-up) the RSS rose 2.9 % and the JS heap 2.5 -> 6.5 MB: the heap that grows is this
bench's own record of every row's time (60,000 a phase); the page's own heap, read without
it, stays at 1.6-1.7 MB over 75 s.  Before the log refilled its bottom rows and the timeline
was drawn incrementally (a rebuild from 3,000 events 4 times a second), 2,000 writes/s gave
long tasks of 60..135 ms; before the page read its timeline's width on a resize only, a draw
forced a layout of the whole page: long tasks of 80..160 ms.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

OBSERVE = """
// seen: SYVARn -> [time of value i]; gcs: the bench's own collections (not the page's)
const bench = window.__bench = {seen: {}, long: [], gcs: []};
new PerformanceObserver((list) => {
  for (const e of list.getEntries()) bench.long.push([e.startTime, e.duration]);
}).observe({type: "longtask", buffered: true});
new MutationObserver((records) => {
  const now = performance.timeOrigin + performance.now();
  for (const r of records) for (const row of r.addedNodes) {
    const cells = row.cells;
    if (!cells || cells[3].textContent !== "write") continue;
    const m = /^var (SYVAR\\d+), value (\\d+)/.exec(cells[5].textContent);
    if (!m) continue;
    const times = bench.seen[m[1]] || (bench.seen[m[1]] = []);
    if (times[Number(m[2])] === undefined) times[Number(m[2])] = now;
  }
}).observe(document.querySelector("#log tbody"), {childList: true});
"""


PROFILE = """
window.__prof = {};
for (const name of ["appendLog", "renderTimeline", "render", "renderLanes", "renderImage",
                    "renderPlc", "renderFieldbus"]) {
  const f = window[name];
  window[name] = function (...a) {
    const t = performance.now();
    try { return f.apply(this, a); } finally {
      const d = performance.now() - t, p = window.__prof[name] || (window.__prof[name] = [0, 0, 0]);
      p[0]++; p[1] += d; p[2] = Math.max(p[2], d);
    }
  };
}
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rss_kib(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def renderers(root: int) -> list[int]:
    """The renderer processes under ``root`` (chromedriver): the page's."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [root]
    while todo:
        pid = todo.pop()
        todo += children.get(pid, [])
        try:
            if b"--type=renderer" in Path(f"/proc/{pid}/cmdline").read_bytes():
                found.append(pid)
        except OSError:
            pass
    return found


def cpu_s(driver: Any) -> float:
    """The CPU time (user + system) the page's renderers have used: what the page costs,
    which a busy machine blurs less than the long tasks' wall time."""
    total = 0
    for pid in renderers(driver.service.process.pid):
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += int(fields[11]) + int(fields[12])
    return total / os.sysconf("SC_CLK_TCK")


def memory_mb(driver: Any) -> tuple[float, float]:
    """The page's JS heap and its renderers' resident size, after a full garbage collection
    (what the page keeps, not the garbage it has not collected yet)."""
    heap = driver.execute_script(
        "const t = performance.now(); gc(); window.__bench.gcs.push([t, performance.now()]);"
        "return performance.memory.usedJSHeapSize") / 1e6
    rss = sum(rss_kib(pid) for pid in renderers(driver.service.process.pid)) / 1024
    return heap, rss


BLOCK = 30000  # values per SYVAR (int16): write i is value i % BLOCK of SYVAR first + i // BLOCK
BLOCKS = 8  # SYVARs per phase: 240,000 writes


def variable(phase: int, i: int) -> tuple[int, int]:
    """The SYVAR and the value of a phase's write ``i``: each write a pair of its own."""
    return phase * BLOCKS + i // BLOCK, i % BLOCK


def write_at(port: int, phase: int, rate: float, seconds: float, sent: list[float]) -> None:
    """FC6 writes of SYVARs at ``rate`` a second (``variable``); each send's time."""
    with socket.create_connection(("127.0.0.1", port)) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        count = int(rate * seconds)
        start = time.perf_counter()
        for i in range(count):
            due = start + i / rate
            ahead = due - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
            syvar, value = variable(phase, i)
            sent.append(time.time())
            s.sendall(struct.pack(">HHHBBHH", i & 0xFFFF, 0, 6, 1, 6, 1000 + syvar, value))
            answer = b""
            while len(answer) < 12:
                chunk = s.recv(12 - len(answer))
                if not chunk:
                    raise ConnectionError("the gateway closed the Modbus connection")
                answer += chunk


def pct(values: list[float], q: int) -> float:
    if len(values) < 2:
        return values[0] if values else float("nan")
    return statistics.quantiles(values, n=100)[q - 1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rates", type=int, nargs="+", default=[50, 200, 1000, 2000])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--warm-up", type=float, default=None,
                        help="seconds of each phase before its first memory reading "
                        "(default: a quarter of the phase)")
    args = parser.parse_args()
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    chromedriver = shutil.which("chromedriver")
    if chromium is None or chromedriver is None:
        sys.exit("needs chromium and chromedriver (apt-get install chromium chromium-driver)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.support.ui import WebDriverWait

    modbus, web = free_port(), free_port()
    run = subprocess.Popen([sys.executable, "-m", "ncgate", "run", "-q", "--port", str(modbus),
                            "--web", f"127.0.0.1:{web}", "--set", "canopen.enabled=false"],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    output: list[str] = []
    threading.Thread(target=lambda: output.extend(run.stdout or []), daemon=True).start()
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--window-size=1366,768", "--enable-precise-memory-info",
                "--js-flags=--expose-gc"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service(chromedriver), options=options)
    driver.set_script_timeout(120)
    try:
        deadline = time.monotonic() + 20
        while True:  # the gateway is up when its console answers
            try:
                with socket.create_connection(("127.0.0.1", web), timeout=1):
                    break
            except OSError:
                if time.monotonic() > deadline or run.poll() is not None:
                    sys.exit("ncgate run did not start:\n" + "".join(output))
                time.sleep(0.1)
        driver.get(f"http://127.0.0.1:{web}/")
        WebDriverWait(driver, 20).until(
            lambda d: d.execute_script("return document.querySelector('#conn').textContent")
            == "live")
        driver.execute_script(OBSERVE)
        if os.environ.get("BENCH_PROFILE"):
            driver.execute_script(PROFILE)
        print(f"# {args.seconds:g} s at each rate; ncgate run, headless {Path(chromium).name}, "
              f"{os.cpu_count()} cores")
        for number, rate in enumerate(args.rates):
            sent: list[float] = []
            phase_at = driver.execute_script("return performance.now()")
            writer = threading.Thread(target=write_at,
                                      args=(modbus, number, rate, args.seconds, sent))
            began = time.perf_counter()
            cpu0 = cpu_s(driver)
            writer.start()
            time.sleep(args.seconds / 4 if args.warm_up is None else args.warm_up)
            warm = memory_mb(driver)
            writer.join()
            took = time.perf_counter() - began
            cpu = cpu_s(driver) - cpu0
            # Long tasks count while the writes come (the reads below are the bench's own).
            phase_end = driver.execute_script("return performance.now()")
            # Let the page catch up with what was sent (at most 10 s more).
            deadline = time.monotonic() + 10
            last, _ = variable(number, len(sent) - 1)
            while time.monotonic() < deadline and driver.execute_script(
                    "const s = window.__bench.seen[arguments[0]] || [];"
                    "return s.length < arguments[1] || s.includes(undefined);",
                    f"SYVAR{last}", len(sent) - (last - number * BLOCKS) * BLOCK):
                time.sleep(0.2)
            shown = {syvar: driver.execute_script(
                "return window.__bench.seen[arguments[0]] || []", f"SYVAR{syvar}")
                for syvar in range(number * BLOCKS, last + 1)}
            end = memory_mb(driver)
            long_tasks = driver.execute_script(
                "const b = window.__bench; return b.long.filter((e) => e[0] >= arguments[0]"
                " && e[0] <= arguments[1] && !b.gcs.some((g) => e[0] <= g[1]"
                " && e[0] + e[1] >= g[0])).map((e) => e[1]);", phase_at, phase_end)
            delays = []
            for i, t in enumerate(sent):
                syvar, value = variable(number, i)
                row = shown[syvar]
                if value < len(row) and row[value] is not None:
                    delays.append(row[value] / 1000 - t)
            delays.sort()
            lost = len(sent) - len(delays)
            print(f"{rate:5d} writes/s (reached {len(sent) / took:7.1f}): "
                  f"p50 {pct(delays, 50) * 1000:7.1f} ms  p99 {pct(delays, 99) * 1000:7.1f} ms  "
                  f"not shown {lost}  long tasks {len(long_tasks)} "
                  f"(longest {max(long_tasks, default=0):.0f} ms)  "
                  f"memory: JS heap {warm[0]:.1f} -> {end[0]:.1f} MB, renderer RSS "
                  f"{warm[1]:.0f} -> {end[1]:.0f} MB  renderer CPU {100 * cpu / took:.0f} %",
                  flush=True)
        if os.environ.get("BENCH_PROFILE"):
            print(driver.execute_script("return window.__prof"))
    finally:
        driver.quit()
        run.terminate()
        run.wait(10)
        if re.search(r"Traceback", "".join(output)):
            print("".join(output), file=sys.stderr)


if __name__ == "__main__":
    main()
