"""The console in a real browser: Debian's Chromium driven by Selenium through chromedriver,
against ``ncgate run`` as a user starts it (a real process, real HTTP).

CI installs chromium and chromium-driver (.ci/run); on a developer machine without them these
tests are skipped with that reason -- never in CI, where a missing browser is a failure.
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
if CHROMIUM is None or CHROMEDRIVER is None:
    if os.environ.get("CI"):
        pytest.fail("chromium / chromedriver are not installed: .ci/run must install them",
                    pytrace=False)
    pytestmark = pytest.mark.skip(reason="no chromium or chromedriver (apt-get install "
                                  "chromium chromium-driver); CI runs these tests")
else:
    from selenium import webdriver
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import WebDriverWait

WAIT_S = 20


class RunProcess:
    """``ncgate run`` in a subprocess; its output read all along (a full pipe would stall it)."""

    def __init__(self, *args: str, cwd: Path | None = None) -> None:
        # A record started from the page goes to the folder run was started in: never
        # the checkout's (``cwd``, or a fresh temporary folder).
        self.own_folder = cwd is None
        self.folder = cwd or Path(tempfile.mkdtemp(prefix="ncgate-run-"))
        self.proc = subprocess.Popen([sys.executable, "-m", "ncgate", "run", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, cwd=self.folder)
        self.lines: list[str] = []
        self.changed = threading.Condition()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self.changed:
                self.lines.append(line)
                self.changed.notify_all()
        with self.changed:
            self.lines.append("")  # the end
            self.changed.notify_all()

    def wait_for(self, text: str) -> str:
        """The first line with ``text``, once it is out (the process ending first fails)."""
        def seen() -> str | None:
            return next((line for line in self.lines if text in line), None)

        with self.changed:
            self.changed.wait_for(lambda: seen() is not None or "" in self.lines, WAIT_S)
            line = seen()
            assert line is not None, f"no {text!r} from ncgate run:\n" + "".join(self.lines)
            return line

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        assert self.proc.wait(timeout=WAIT_S) == 0, "".join(self.lines)
        self.reader.join(WAIT_S)
        if self.own_folder:
            shutil.rmtree(self.folder, ignore_errors=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def web_port() -> int:
    return free_port()


def start_run(port: int, channel: str) -> RunProcess:
    run = RunProcess("--port", "0", "--web", f"127.0.0.1:{port}",
                     "--set", "nc.time_scale=10", "--set", f"canopen.channel={channel}")
    run.wait_for(f"web console on http://127.0.0.1:{port}/")
    return run


@pytest.fixture
def browser() -> Iterator[Any]:
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--window-size=1400,1200"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()


def until(driver: Any, what: str, check: Any) -> Any:
    try:
        # The page redraws a lane on every status message: an element read just as it was
        # replaced is read again at the next poll, not taken for the page's answer.
        return WebDriverWait(driver, WAIT_S, ignored_exceptions=(
            StaleElementReferenceException,)).until(lambda d: check(d))
    except Exception as exc:
        page = driver.find_element(By.TAG_NAME, "body").text
        raise AssertionError(f"the page never showed {what}:\n{page}") from exc


def click(driver: Any, css: str) -> None:
    """Click the element ``css`` names in a part the page redraws (the lanes, the lists of
    breakpoints, faults and trends): one replaced between being found and clicked is found
    again (a loaded machine's browser redrew the breakpoint list in between)."""
    until(driver, f"{css} clicked", lambda d: _clicked(d, css))


def _clicked(driver: Any, css: str) -> bool:
    try:
        driver.find_element(By.CSS_SELECTOR, css).click()
    except StaleElementReferenceException:
        return False
    return True


def text(driver: Any, css: str) -> str:
    for _ in range(5):  # an element replaced as it is read (the page redraws): find it again
        try:
            found = driver.find_elements(By.CSS_SELECTOR, css)
            return found[0].text if found else ""
        except StaleElementReferenceException:
            continue
    return ""


def test_cycle_start_a_wait_a_forced_bit_and_a_server_restart(browser: Any,
                                                              web_port: int) -> None:
    run = start_run(web_port, "ncgate-browser-1")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        until(browser, "five lanes", lambda d: len(d.find_elements(By.CSS_SELECTOR,
                                                                   ".lane")) == 5)
        browser.find_element(By.ID, "btn-start").click()
        # P2 waits at N40 with its condition, the value now and the block.
        until(browser, "P2 waiting at N40",
              lambda d: text(d, "#lane-2 .state") == "WAIT_COND"
              and "PROG92:8 N40(WAI,SA10=1)" in text(d, "#lane-2 .block")
              and "(WAI,SA10=1) waits for SA10=1 (now 0)" in text(d, "#lane-2 .wait"))
        segments = len(browser.find_elements(By.CSS_SELECTOR, "#timeline rect.seg"))
        assert segments >= 2
        # Force SA10 in the image grid: P2 resumes, the log says who, the timeline grows.
        browser.find_element(By.ID, "sa-10").click()
        answer_dialog(browser, accept=True)  # a write is asked first
        until(browser, "SA10 on, written by web",
              lambda d: "on" in d.find_element(By.ID, "sa-10").get_attribute("class")
              and "last written by web" in d.find_element(By.ID, "sa-10").get_attribute(
                  "title"))
        until(browser, "P2's resume in the event log",
              lambda d: any("resume" in row.text and "by cond" in row.text
                            and "writer web" in row.text
                            for row in d.find_elements(By.CSS_SELECTOR, "#log tbody tr")))
        until(browser, "a longer timeline",
              lambda d: len(d.find_elements(By.CSS_SELECTOR, "#timeline rect.seg")) > segments)
        assert run.wait_for("P2 resumes at PROG92.nc:8 N40 (by cond, written by web 127.0.0.1)")

        # The server goes away: the page says so, and comes back by itself with the new run.
        run.stop()
        until(browser, "the lost connection", lambda d: text(d, "#conn") == "reconnecting…")
        # It says so in a banner and offers no button that would do nothing.
        until(browser, "the banner and no controls",
              lambda d: d.find_element(By.ID, "offline").is_displayed()
              and not d.find_element(By.ID, "btn-start").is_enabled())
        run = start_run(web_port, "ncgate-browser-2")
        until(browser, "the new run, live",
              lambda d: text(d, "#conn") == "live"
              and text(d, "#lane-2 .state") == "IDLE"
              and not d.find_elements(By.CSS_SELECTOR, "#log tbody tr")
              and not d.find_element(By.ID, "offline").is_displayed()
              and d.find_element(By.ID, "btn-start").is_enabled())
        browser.find_element(By.ID, "btn-start").click()
        until(browser, "P2 waiting again, and the new run's events",
              lambda d: text(d, "#lane-2 .state") == "WAIT_COND"
              and any(row.text.startswith("1 ") and "start" in row.text
                      for row in d.find_elements(By.CSS_SELECTOR, "#log tbody tr")))
    finally:
        if run.proc.poll() is None:
            run.stop()


def test_feed_hold_and_starting_a_program_from_the_form(browser: Any, web_port: int) -> None:
    run = start_run(web_port, "ncgate-browser-3")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        browser.find_element(By.ID, "btn-hold").click()
        until(browser, "the feed hold", lambda d: "(feed hold)" in text(d, "#clock"))
        browser.find_element(By.ID, "btn-start").click()  # cycle start releases the hold
        until(browser, "the hold released", lambda d: "(feed hold)" not in text(d, "#clock"))
        until(browser, "the programs on MP0",
              lambda d: [o.text for o in d.find_elements(By.CSS_SELECTOR,
                                                         "#start-program option")]
              == ["PROG91", "PROG92", "PROG93"])
        browser.find_element(By.CSS_SELECTOR, "#start-program option[value=PROG93]").click()
        browser.find_element(By.CSS_SELECTOR, "#start-process option[value='3']").click()
        browser.find_element(By.CSS_SELECTOR, "#start-form button").click()
        until(browser, "PROG93 in P3 waiting for P1",
              lambda d: text(d, "#lane-3 .state") == "WAIT_PROC"
              and "PROG93:2 N1(WAI,1)" in text(d, "#lane-3 .block"))
        # Starting it again: the process is busy; the page says why.
        browser.find_element(By.CSS_SELECTOR, "#start-form button").click()
        until(browser, "the refusal", lambda d: "process 3 is busy" in text(d, "#message"))
    finally:
        run.stop()


def test_the_page_runs_under_its_csp_and_no_other_site_may_frame_it(browser: Any,
                                                                     web_port: int) -> None:
    run = start_run(web_port, "ncgate-browser-4")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live page", lambda d: text(d, "#conn") == "live"
              and len(d.find_elements(By.CSS_SELECTOR, ".lane")) == 5
              and d.find_elements(By.CSS_SELECTOR, "#start-program option"))
        browser.find_element(By.ID, "btn-start").click()
        until(browser, "P2 waiting, drawn on the timeline",
              lambda d: text(d, "#lane-2 .state") == "WAIT_COND"
              and d.find_elements(By.CSS_SELECTOR, "#timeline rect.seg"))
        logged = [entry["message"] for entry in browser.get_log("browser")]
        assert not [line for line in logged if "Content Security Policy" in line
                    or "Refused" in line], logged
        # Another site frames the console (clickjacking): the browser refuses to show it.
        browser.get(f"data:text/html,<iframe src='http://127.0.0.1:{web_port}/'></iframe>")
        browser.switch_to.frame(0)
        shown = until(browser, "the frame loaded", lambda d: d.execute_script(
            "return document.readyState === 'complete' && document.URL !== 'about:blank'"
            " && document.URL"))
        assert shown.startswith("chrome-error:"), shown  # refused: the browser's error page
        assert not browser.find_elements(By.ID, "conn")
    finally:
        run.stop()


def post_write(port: int, var: str, value: int) -> None:
    """A write through the console's HTTP API (as a script or another tab would)."""
    request = urllib.request.Request(
        f"http://127.0.0.1:{port}/api/write", method="POST",
        data=json.dumps({"var": var, "value": value}).encode(),
        headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=WAIT_S) as answer:
        assert answer.status == 200


def log_rows(driver: Any) -> list[Any]:
    return driver.find_elements(By.CSS_SELECTOR, "#log tbody tr")


def test_the_event_log_takes_new_rows_on_top_and_keeps_those_it_has(browser: Any,
                                                                      web_port: int) -> None:
    """It rebuilt its 300 rows (and the timeline) on every message: minutes behind at 100
    writes a second.  Now a batch's rows go on top and the rows it has stay as they are."""
    run = start_run(web_port, "ncgate-browser-5")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        for value in range(1, 101):
            post_write(web_port, "SYVAR5", value)
        until(browser, "the 100th write on top", lambda d: "SYVAR5, value 100," in
              text(d, "#log tbody tr:first-child"))
        kept = log_rows(browser)[0]
        for value in range(101, 351):
            post_write(web_port, "SYVAR5", value)
        until(browser, "the 350th write on top", lambda d: "SYVAR5, value 350," in
              text(d, "#log tbody tr:first-child"))
        rows = log_rows(browser)
        assert len(rows) == 300  # bounded: the oldest went
        seqs = [int(row.find_element(By.TAG_NAME, "td").text) for row in rows]
        assert seqs == sorted(seqs, reverse=True) and seqs[0] - seqs[-1] == 299
        # The row drawn before is the same element, not a copy drawn again.
        assert "SYVAR5, value 100," in kept.text and kept in rows
    finally:
        run.stop()


def test_the_clock_and_the_timeline_move_on_when_nothing_happens(browser: Any,
                                                                 web_port: int) -> None:
    run = start_run(web_port, "ncgate-browser-6")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live"
              and text(d, "#timeline text:last-child"))
        # No program runs and nobody writes: no event comes, yet time goes on.
        clock, axis = text(browser, "#clock"), text(browser, "#timeline text:last-child")
        until(browser, "the clock moving", lambda d: text(d, "#clock") != clock)
        until(browser, "the timeline's axis moving",
              lambda d: text(d, "#timeline text:last-child") != axis)
        assert not log_rows(browser)
        # A wait says how long it has lasted, and that goes on too.
        browser.find_element(By.ID, "btn-start").click()
        waited = until(browser, "P2 waiting at N40, for some time",
                       lambda d: "SA10=1" in text(d, "#lane-2 .wait")
                       and text(d, "#lane-2 .wait .since"))
        assert waited.startswith("for ")
        until(browser, "the wait's duration moving",
              lambda d: text(d, "#lane-2 .wait .since") not in ("", waited))
    finally:
        run.stop()


def test_another_run_on_the_same_port_starts_the_page_afresh(browser: Any,
                                                            web_port: int) -> None:
    """A restart with another config left the old lanes, programs and filters (twice), and
    the page resumed the new run at the old run's last event, missing its first ones."""
    run = start_run(web_port, "ncgate-browser-7")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "five lanes", lambda d: len(d.find_elements(By.CSS_SELECTOR,
                                                                   ".lane")) == 5)
        for value in range(1, 4):
            post_write(web_port, "SYVAR5", value)
        until(browser, "three writes", lambda d: len(log_rows(d)) == 3)
        run.stop()
        until(browser, "the lost connection", lambda d: text(d, "#conn") == "reconnecting…")
        run = RunProcess("--port", "0", "--web", f"127.0.0.1:{web_port}", "--set",
                         "nc.processes=3", "--set", "canopen.channel=ncgate-browser-8")
        run.wait_for(f"web console on http://127.0.0.1:{web_port}/")
        for value in range(1, 6):  # the new run's events 1..5, as the page reconnects
            post_write(web_port, "SYVAR6", value)
        until(browser, "the new run's five writes, from its first",
              lambda d: [row.find_element(By.TAG_NAME, "td").text for row in log_rows(d)]
              == ["5", "4", "3", "2", "1"])
        assert [lane.get_attribute("id") for lane in browser.find_elements(
            By.CSS_SELECTOR, ".lane")] == ["lane-1", "lane-2", "lane-3"]
        options = [o.text for o in browser.find_elements(By.CSS_SELECTOR,
                                                         "#filter-proc option")]
        assert options == ["every process", "P1", "P2", "P3"]
        assert [o.text for o in browser.find_elements(By.CSS_SELECTOR,
                                                      "#filter-kind option")] == [
            "every kind", "write"]
        assert "SYVAR6" in text(browser, "#log tbody tr:first-child")
    finally:
        run.stop()


def test_an_alarm_shows_in_the_header_and_in_its_lane_with_its_block(
        browser: Any, web_port: int, tmp_path: Path) -> None:
    (tmp_path / "MAIN.nc").write_text("N10 (DLY,0.1)\nN20 (SND,3)\nN30 M30\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "MAIN"\n[nc.storage]\nMP0 = "."\n'
                                          'default = "MP0"\n')
    run = RunProcess("--config", str(tmp_path / "ncgate.toml"), "--port", "0", "--web",
                     f"127.0.0.1:{web_port}", "--set", "canopen.channel=ncgate-browser-9")
    try:
        run.wait_for(f"web console on http://127.0.0.1:{web_port}/")
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        assert text(browser, "#alarms") == ""
        browser.find_element(By.ID, "btn-start").click()
        # (SND,3) to a process that runs no program: AL111 at N20.
        until(browser, "the alarm in the header and the lane",
              lambda d: text(d, "#alarms") == "P1 AL111 at MAIN.nc:2 N20"
              and "N20 (SND,3)" in text(d, "#lane-1 .block")
              and "AL111" in text(d, "#lane-1 .alarm"))
        click(browser, "#lane-1 .alarm button")  # Reset
        answer_dialog(browser, accept=True)
        until(browser, "the alarm cleared", lambda d: text(d, "#alarms") == ""
              and text(d, "#lane-1 .state") == "IDLE")
    finally:
        run.stop()


def test_a_lane_starts_holds_and_resets_its_own_process(browser: Any, web_port: int) -> None:
    """Issue 27: each lane's buttons command its process alone. P1's Start starts nc.main in
    P1; P2's Hold holds P2 only; P1's Reset ends P1's program while P2 stays held."""
    run = start_run(web_port, "ncgate-browser-lanes")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        until(browser, "P1's lane buttons",
              lambda d: d.find_elements(By.CSS_SELECTOR, "#lane-1 .lane-cycle_start"))
        click(browser, "#lane-1 .lane-cycle_start")
        until(browser, "PROG91 in P1 and PROG92 in P2",
              lambda d: text(d, "#lane-1 .state") not in ("", "IDLE")
              and text(d, "#lane-2 .state") not in ("", "IDLE"))
        click(browser, "#lane-2 .lane-feed_hold")
        until(browser, "P2 held", lambda d: "HOLD" in text(d, "#lane-2 .state"))
        assert "HOLD" not in text(browser, "#lane-1 .state")
        click(browser, "#lane-1 .lane-reset")
        answer_dialog(browser, accept=True)
        until(browser, "P1 reset", lambda d: text(d, "#lane-1 .state") == "IDLE")
        assert "HOLD" in text(browser, "#lane-2 .state")
    finally:
        run.stop()


def test_the_commissioning_controls_of_the_page(browser: Any, web_port: int) -> None:
    """Issue 27 from the page: a breakpoint set with the form is listed (and cleared by its
    button), single block is switched for the cell, the feed override is written."""
    run = start_run(web_port, "ncgate-browser-controls")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        browser.find_element(By.ID, "break-at").send_keys("PROG92:8")
        browser.find_element(By.CSS_SELECTOR, "#break-form button").click()
        until(browser, "the breakpoint listed",
              lambda d: "PROG92:8" in text(d, "#breakpoints"))
        browser.find_element(By.ID, "single-block").click()
        feed = browser.find_element(By.ID, "feed-override")
        # Emptied, the field asks for nothing (it wrote 0: the machine's feed stopped); then
        # its text is selected and typed over, the field keeping the focus (a clear() blurs
        # it, and the page may write the status's value back in between).
        feed.clear()
        feed.send_keys(Keys.CONTROL + "a" + Keys.NULL + "50" + Keys.ENTER)
        browser.find_element(By.ID, "break-at").click()  # away from the field: a change
        status_url = f"http://127.0.0.1:{web_port}/api/status"

        def status() -> dict[str, Any]:
            with urllib.request.urlopen(status_url, timeout=5) as r:
                return json.loads(r.read())

        until(browser, "single block and 50 % in the status",
              lambda d: all(p["single_block"] for p in status()["processes"]
                            if not p["external"])
              and status()["processes"][0]["feed_override"] == 50)
        events = api(web_port, "GET", "/api/events?since=0")["events"]
        assert {e["feed"] for e in events if e["event"] == "override"} == {50}, events
        click(browser, "#breakpoints .breakpoint")
        until(browser, "the breakpoint cleared",
              lambda d: status()["controls"]["breakpoints"] == [])
    finally:
        run.stop()


# ---- issue 30, item 4: what engineers look for ------------------------------------------------

CELL_LOGIC = """PROGRAM main
VAR
  n : INT;
  t : TON;
END_VAR
n := n + 1;
t(IN := SA[12], PT := T#1s);
SYVAR[7] := n;
END_PROGRAM
"""
CELL_SYMBOLS = """[symbols]
door_closed = "SA10"
spindle_speed = { var = "SYVAR3", comment = "rpm / 10" }
"""


def named_cell(tmp_path: Path, web_port: int, channel: str) -> RunProcess:
    """A cell of one program waiting for SA10, PLC logic with a counter and a TON, and two
    I/O names."""
    (tmp_path / "A.nc").write_text("N1G1X10Y20Z-5F300\nN2(WAI,SA10=1)\nN3M30\n")
    (tmp_path / "logic.st").write_text(CELL_LOGIC)
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\nlookahead = 0\n[nc.storage]\nMP0 = "."\n'
        f'[plc]\nlogic = "logic.st"\nretain_file = "{tmp_path / "r.sqlite"}"\n'
        + CELL_SYMBOLS)
    run = RunProcess("--config", str(tmp_path / "ncgate.toml"), "--port", "0", "--web",
                     f"127.0.0.1:{web_port}", "--set", f"canopen.channel={channel}",
                     cwd=tmp_path)
    run.wait_for(f"web console on http://127.0.0.1:{web_port}/")
    return run


def api(port: int, method: str, path: str, body: Any = None) -> Any:
    request = urllib.request.Request(
        f"http://127.0.0.1:{port}{path}", method=method,
        data=None if body is None else json.dumps(body).encode(),
        headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=WAIT_S) as answer:
        return json.loads(answer.read())


def answer_dialog(driver: Any, accept: bool) -> str:
    """The confirm() the page asked: its question; accepted or dismissed."""
    alert = WebDriverWait(driver, WAIT_S).until(lambda d: d.switch_to.alert)
    question = str(alert.text)
    if accept:
        alert.accept()
    else:
        alert.dismiss()
    return question


def test_a_lane_shows_where_the_axes_are_the_feed_and_the_override(
        browser: Any, web_port: int, tmp_path: Path) -> None:
    run = named_cell(tmp_path, web_port, "ncgate-browser-lane-pos")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        browser.find_element(By.ID, "btn-start").click()
        until(browser, "P1 at X10 Y20 Z-5, F300, waiting",
              lambda d: text(d, "#lane-1 .pos") == "X 10.000 Y 20.000 Z -5.000"
              and text(d, "#lane-1 .feed") == "F 300 mm/min"
              and "SA10=1" in text(d, "#lane-1 .wait")
              and text(d, "#lane-1 .wait .since").startswith("for "))
        api(web_port, "POST", "/api/write", {"var": "P1.FEED_OVERRIDE", "value": 40})
        until(browser, "the override", lambda d: text(d, "#lane-1 .override")
              .startswith("override 40 %"))
    finally:
        run.stop()


def test_reset_and_a_write_are_asked_first(browser: Any, web_port: int) -> None:
    run = start_run(web_port, "ncgate-browser-confirm")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        browser.find_element(By.ID, "btn-start").click()
        until(browser, "P2 waiting", lambda d: text(d, "#lane-2 .state") == "WAIT_COND")
        # A bit written only once the question is answered yes.
        browser.find_element(By.ID, "sa-12").click()
        assert "SA12 = 1" in answer_dialog(browser, accept=False)
        browser.find_element(By.ID, "sa-10").click()
        assert "SA10 = 1" in answer_dialog(browser, accept=True)
        until(browser, "P2 resumed", lambda d: text(d, "#lane-2 .state") != "WAIT_COND")
        # The page's writes (the cell's programs write SYVARs of their own meanwhile).
        writes = [e["var"] for e in api(web_port, "GET", "/api/events?since=0")["events"]
                  if e["event"] == "write" and e["who"].startswith("web ")]
        assert writes == ["SA10"]  # not SA12: that one was declined
        browser.find_element(By.ID, "btn-reset").click()
        assert "Reset" in answer_dialog(browser, accept=False)
        click(browser, "#lane-1 .lane-reset")
        answer_dialog(browser, accept=False)
        assert text(browser, "#lane-1 .state") != "IDLE"  # declined: still running
        browser.find_element(By.ID, "btn-reset").click()
        answer_dialog(browser, accept=True)
        until(browser, "every process idle",
              lambda d: all(text(d, f"#lane-{k} .state") == "IDLE" for k in range(1, 6)))
    finally:
        run.stop()


def test_the_image_grid_has_fixed_columns_index_labels_names_and_force_marks(
        browser: Any, web_port: int, tmp_path: Path) -> None:
    run = named_cell(tmp_path, web_port, "ncgate-browser-grid")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "the grid", lambda d: d.find_elements(By.ID, "sa-17"))
        # 16 bits a row, each row led by its first index: SA16 sits under SA0, SA17 under SA1.
        left = {k: browser.find_element(By.ID, f"sa-{k}").rect["x"] for k in (0, 1, 16, 17)}
        assert left[0] == left[16] and left[1] == left[17] and left[1] > left[0]
        labels = [e.text for e in browser.find_elements(By.CSS_SELECTOR, "#sa .idx")][:3]
        assert labels == ["SA0", "SA16", "SA32"]
        assert [e.text for e in browser.find_elements(By.CSS_SELECTOR, "#k .idx")][:2] == [
            "SK0", "SK8"]
        # The names of [symbols]: in the cell's title and in the names table.
        until(browser, "SA10's name", lambda d: d.find_element(By.ID, "sa-10")
              .get_attribute("title").startswith("SA10 = 0 (door_closed"))
        assert "spindle_speed" in browser.find_element(By.ID, "syvar-3").get_attribute("title")
        until(browser, "the names table", lambda d: [
            [c.text for c in row.find_elements(By.TAG_NAME, "td")][:2]
            for row in d.find_elements(By.CSS_SELECTOR, "#names tr")] == [
            ["door_closed", "SA10"], ["spindle_speed", "SYVAR3"]])
        # [symbols]' comments: a tooltip on the name, and beside the name in the cell's title.
        names = browser.find_elements(By.CSS_SELECTOR, "#names tr td:first-child")
        assert [n.get_attribute("title") for n in names] == ["", "rpm / 10"]
        assert "spindle_speed: rpm / 10" in browser.find_element(By.ID, "syvar-3") \
            .get_attribute("title")
        # A force by name from the form: listed, and the cell marked F.
        browser.find_element(By.ID, "force-var").send_keys("door_closed")
        browser.find_element(By.ID, "force-value").send_keys("1")
        browser.find_element(By.CSS_SELECTOR, "#force-form button").click()
        assert "door_closed = 1" in answer_dialog(browser, accept=True)
        api(web_port, "POST", "/api/force", {"var": "SYVAR3", "value": 42})
        until(browser, "the force list and the F marks",
              lambda d: "SA10" in text(d, "#forced") and "SYVAR3" in text(d, "#forced")
              and "forced" in d.find_element(By.ID, "sa-10").get_attribute("class")
              and "forced" in d.find_element(By.ID, "syvar-3").get_attribute("class")
              and d.find_element(By.ID, "sa-10").get_attribute("title").startswith("SA10 = 1")
              and d.execute_script("return getComputedStyle(document.getElementById('sa-10'),"
                                   " '::after').content") == '"F"')
        browser.find_element(By.ID, "btn-unforce-all").click()
        answer_dialog(browser, accept=True)
        until(browser, "every force released",
              lambda d: not d.find_elements(By.CSS_SELECTOR, "#forced tr")
              and "forced" not in d.find_element(By.ID, "sa-10").get_attribute("class"))
        assert api(web_port, "GET", "/api/force")["forced"] == []
    finally:
        run.stop()


def test_fb_members_and_a_trend_of_chosen_variables(browser: Any, web_port: int,
                                                    tmp_path: Path) -> None:
    run = named_cell(tmp_path, web_port, "ncgate-browser-trend")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        # A TON's members, one row each.
        # The names read in one call in the page: the table is drawn again on each status
        # message, and on a loaded machine a row read cell by cell was always replaced first.
        until(browser, "main.t.Q and main.t.ET",
              lambda d: set(d.execute_script(
                  "return [...document.querySelectorAll('#plc-vars tr')]"
                  ".map((r) => r.cells.length ? r.cells[0].textContent : '')"))
              >= {"main.n", "main.t.IN", "main.t.PT", "main.t.Q", "main.t.ET"})
        for name in ("main.n", "spindle_speed"):
            browser.find_element(By.ID, "trend-var").send_keys(name)
            browser.find_element(By.CSS_SELECTOR, "#trend-form button").click()
        api(web_port, "POST", "/api/write", {"var": "SYVAR3", "value": 250})
        def chart(d: Any) -> dict[str, Any]:  # read at once: the chart is redrawn each tick
            return dict(d.execute_script("""
                const n = document.querySelector("#trend polyline[data-name='main.n']");
                return {lines: document.querySelectorAll('#trend polyline').length,
                        legend: document.querySelector('#trend-legend').textContent,
                        points: n ? n.getAttribute('points').trim().split(/\\s+/).length : 0};
                """))

        until(browser, "two lines, main.n rising, spindle_speed at 250",
              lambda d: (c := chart(d))["lines"] == 2 and "spindle_speed = 250" in c["legend"]
              and c["points"] > 4)
        # A time axis in machine seconds.
        ticks = browser.execute_script(  # read at once: the chart is redrawn on each tick
            "return [...document.querySelectorAll('#trend text.tick')].map((e) => e.textContent)")
        # Every 10 s of machine time; where the window starts depends on how long the run
        # has been on (a loaded machine took the window past 0 s: ["10 s", "20 s", ...]).
        seconds = [int(tick.removesuffix(" s")) for tick in ticks]
        assert len(seconds) >= 2 and all(t % 10 == 0 for t in seconds), ticks
        assert all(b - a == 10 for a, b in itertools.pairwise(seconds)), ticks
        # Removed with its button.
        click(browser, "#trend-legend .item button")
        until(browser, "one line", lambda d: len(d.find_elements(By.CSS_SELECTOR,
                                                                 "#trend polyline")) == 1)
    finally:
        run.stop()


def test_record_from_the_page_and_the_downloads(browser: Any, web_port: int,
                                                tmp_path: Path) -> None:
    run = named_cell(tmp_path, web_port, "ncgate-browser-record")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        browser.find_element(By.ID, "btn-record").click()
        until(browser, "recording", lambda d: "Stop recording" in text(d, "#btn-record"))
        post_write(web_port, "SYVAR5", 7)
        browser.find_element(By.ID, "btn-record").click()
        until(browser, "stopped", lambda d: text(d, "#btn-record").strip("● ") == "Record")
        # What the links download, fetched by the page itself.
        fetch = ("const done = arguments[arguments.length - 1];"
                 "fetch(arguments[0]).then(async (r) => done([r.status,"
                 " r.headers.get('Content-Disposition'), await r.text()]));")
        code, disposition, body = browser.execute_async_script(
            fetch, browser.find_element(By.ID, "dl-record").get_attribute("href"))
        assert code == 200 and disposition.startswith("attachment")
        record = body
        lines = [json.loads(line) for line in record.splitlines()]
        assert lines[0]["ncgate_record"] == 2 and list(lines[-1]) == ["stop"]
        assert [(i["input"], i["changes"]) for i in lines if "input" in i] == [
            ("write", [["SYVAR", 5, "IN", 7]])]
        code, disposition, body = browser.execute_async_script(
            fetch, browser.find_element(By.ID, "dl-trace").get_attribute("href"))
        assert code == 200 and disposition.startswith("attachment")
        assert any(json.loads(line).get("var") == "SYVAR5" for line in body.splitlines())
        # The file itself is in the folder run was started in.
        assert [p.read_text() for p in tmp_path.glob("ncgate-record-*.jsonl")] == [record]
    finally:
        run.stop()


def test_on_a_phone_the_page_is_one_column(browser: Any, web_port: int) -> None:
    run = start_run(web_port, "ncgate-browser-phone")
    try:
        browser.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
            "width": 390, "height": 844, "deviceScaleFactor": 3, "mobile": True})
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "five lanes", lambda d: len(d.find_elements(By.CSS_SELECTOR,
                                                                   ".lane")) == 5)
        boxes = {box: browser.find_element(By.ID, box).rect
                 for box in ("lanes-box", "image-box", "plc-box", "force-box", "trend-box")}
        assert len({round(r["x"]) for r in boxes.values()}) == 1, boxes  # one column
        assert all(r["width"] <= 390 for r in boxes.values())
        # Nothing wider than the screen; the long lists scroll in their own boxes.
        assert browser.execute_script("return document.documentElement.scrollWidth") <= 390
        assert browser.execute_script("return document.documentElement.scrollHeight") < 6000
    finally:
        run.stop()


def test_dark_mode_follows_the_system_and_the_toggle(browser: Any, web_port: int) -> None:
    run = start_run(web_port, "ncgate-browser-dark")
    try:
        def background(d: Any) -> int:
            rgb = d.execute_script("return getComputedStyle(document.body).backgroundColor")
            return sum(int(v) for v in rgb[rgb.index("(") + 1:-1].split(",")[:3])

        browser.execute_cdp_cmd("Emulation.setEmulatedMedia", {"features": [
            {"name": "prefers-color-scheme", "value": "dark"}]})
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        assert background(browser) < 150  # the system's dark
        toggle = browser.find_element(By.ID, "theme")
        assert "auto" in toggle.text
        toggle.click()  # dark
        toggle.click()  # light, whatever the system says
        assert "light" in toggle.text and background(browser) > 600
        browser.refresh()  # kept for the next visit
        until(browser, "light again", lambda d: "light" in text(d, "#theme")
              and background(d) > 600)
        browser.execute_cdp_cmd("Emulation.setEmulatedMedia", {"features": [
            {"name": "prefers-color-scheme", "value": "light"}]})
        browser.find_element(By.ID, "theme").click()  # auto: the system's light
        browser.find_element(By.ID, "theme").click()  # dark, whatever the system says
        assert background(browser) < 150
    finally:
        run.stop()


def test_the_server_svg_labels_do_not_overlap_and_its_legend_is_inside(
        browser: Any, web_port: int) -> None:
    """The timeline picture smeared its write labels over each other and cut its legend at
    the right edge; measured here by the browser that draws it."""
    run = start_run(web_port, "ncgate-browser-svg")
    try:
        for value in range(1, 41):
            post_write(web_port, "SYVAR5", value)
        browser.get(f"http://127.0.0.1:{web_port}/api/timeline.svg")
        boxes = browser.execute_script("""
            const svg = document.documentElement;
            const box = (e) => { const b = e.getBBox(); return [b.x, b.y, b.width, b.height]; };
            return {size: [svg.width.baseVal.value, svg.height.baseVal.value],
                    labels: [...document.querySelectorAll('text.write-label')].map(box),
                    legend: [...document.querySelectorAll('g.legend')].map(box),
                    text: [...document.querySelectorAll('text')].map(box)};""")
        width, height = boxes["size"]
        assert boxes["labels"] and len(boxes["legend"]) == 9
        for x, y, w, h in boxes["text"] + boxes["legend"]:
            assert x >= 0 and x + w <= width and y >= 0 and y + h <= height, (x, y, w, h)
        labels = sorted(boxes["labels"])
        for (x1, _, w1, _), (x2, _, _, _) in itertools.pairwise(labels):
            assert x1 + w1 <= x2, labels  # side by side, never on top of each other
    finally:
        run.stop()


def test_a_lane_names_an_auxiliary_functions_handshake(browser: Any, web_port: int,
                                                       tmp_path: Path) -> None:
    """Issue 28's handshake in the lane: M08 before its block's motion waits for the PLC's
    acknowledge (no PLC logic here: nobody answers) -- the lane says so and for how long."""
    (tmp_path / "A.nc").write_text("N1M08G1X10F600\nN2M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n[nc.aux]\ncodes = { M8 = '
        '"before_motion" }\n')
    run = RunProcess("--config", str(tmp_path / "ncgate.toml"), "--port", "0", "--web",
                     f"127.0.0.1:{web_port}", "--set", "canopen.channel=ncgate-browser-aux")
    try:
        run.wait_for(f"web console on http://127.0.0.1:{web_port}/")
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        browser.find_element(By.ID, "btn-start").click()
        until(browser, "P1 waiting for the acknowledge of M08",
              lambda d: text(d, "#lane-1 .wait.aux").startswith(
                  "handshake: M08 waits for the PLC to acknowledge it")
              and text(d, "#lane-1 .wait.aux .since").startswith("for "))
    finally:
        run.stop()


def test_the_plant_panel_shows_each_model_and_injects_and_clears_a_fault(
        browser: Any, web_port: int, tmp_path: Path) -> None:
    (tmp_path / "A.nc").write_text("N1(WAI,SA30=1)\nN2M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'
        '[[plant.model]]\nname = "clamp"\nkind = "cylinder"\nextend = "SA20"\n'
        'extended = "SA30"\nretracted = "SA31"\ntravel_ms = 300\n')
    run = RunProcess("--config", str(tmp_path / "ncgate.toml"), "--port", "0", "--web",
                     f"127.0.0.1:{web_port}", "--set", "canopen.channel=ncgate-browser-plant",
                     cwd=tmp_path)
    run.wait_for(f"web console on http://127.0.0.1:{web_port}/")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "the clamp at rest", lambda d: "clamp retracted" in text(d, "#model-clamp"))
        browser.find_element(By.ID, "fault-target").send_keys("clamp")
        browser.find_element(By.CSS_SELECTOR, "#fault-kind option[value=never]").click()
        browser.find_element(By.CSS_SELECTOR, "#fault-form button").click()
        assert "Inject never on clamp" in answer_dialog(browser, accept=True)
        until(browser, "the fault listed and the model marked",
              lambda d: "clamp: never" in text(d, "#faults")
              and "faulted" in d.find_element(By.ID, "model-clamp").get_attribute("class"))
        api(web_port, "POST", "/api/write", {"var": "SA20", "value": 1})
        assert api(web_port, "GET", "/api/status")["plant"]["models"][0]["state"] == "retracted"
        click(browser, "#faults button")
        until(browser, "the clamp closing once cleared",
              lambda d: "clamp extended" in text(d, "#model-clamp")
              and not d.find_elements(By.CSS_SELECTOR, "#faults tr"))
        events = [e for e in api(web_port, "GET", "/api/events")["events"]
                  if e["event"] in ("fault", "fault_clear")]
        assert [(e["event"], e["who"].split(" ")[0]) for e in events] == [
            ("fault", "web"), ("fault_clear", "web")]
    finally:
        run.stop()


def test_the_image_grid_is_operated_from_the_keyboard(browser: Any, web_port: int) -> None:
    """One cell of a grid takes the tab, the arrows move it, Enter writes as a click does;
    each cell has a name for a screen reader."""
    from selenium.webdriver.common.keys import Keys

    run = start_run(web_port, "ncgate-browser-keys")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "the grid", lambda d: d.find_elements(By.ID, "sa-17"))
        grid = browser.find_element(By.ID, "sa")
        assert grid.get_attribute("role") == "grid"
        first = browser.find_element(By.ID, "sa-0")
        assert first.get_attribute("tabindex") == "0"
        assert browser.find_element(By.ID, "sa-1").get_attribute("tabindex") == "-1"
        first.click()  # (a click asks; dismissed)
        answer_dialog(browser, accept=False)
        first.send_keys(Keys.ARROW_RIGHT)
        until(browser, "SA1 focused", lambda d: d.switch_to.active_element.get_attribute("id")
              == "sa-1")
        browser.switch_to.active_element.send_keys(Keys.ARROW_DOWN)  # 16 a row: SA17
        until(browser, "SA17 focused", lambda d: d.switch_to.active_element.get_attribute("id")
              == "sa-17")
        browser.switch_to.active_element.send_keys(Keys.ENTER)
        assert "SA17 = 1" in answer_dialog(browser, accept=True)
        until(browser, "SA17 written", lambda d: "on" in d.find_element(By.ID, "sa-17")
              .get_attribute("class"))
        label = browser.find_element(By.ID, "sa-17").get_attribute("aria-label")
        assert label.startswith("SA17 = 1")
    finally:
        run.stop()


def test_each_trend_has_a_scale_of_its_own(browser: Any, web_port: int,
                                           tmp_path: Path) -> None:
    """A bit beside a value of thousands: on one shared scale the bit was a flat line; each
    trend now spans the chart on its own scale, which its legend says."""
    run = named_cell(tmp_path, web_port, "ncgate-browser-scales")
    try:
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        for name in ("SA12", "SYVAR3"):
            browser.find_element(By.ID, "trend-var").send_keys(name)
            browser.find_element(By.CSS_SELECTOR, "#trend-form button").click()
        api(web_port, "POST", "/api/write", {"var": "SYVAR3", "value": 2000})

        def points(d: Any) -> list[str]:
            # Read in the page in one call: the chart is drawn anew every 250 ms, and on a
            # loaded machine a line found by one WebDriver call was replaced before the next
            # read its points, every time until the wait ran out.
            found = d.execute_script("const l = document.querySelector(\"#trend "
                                     "polyline[data-name='SA12']\"); "
                                     "return l ? l.getAttribute('points') : '';")
            return str(found or "").split()

        until(browser, "SA12 sampled at 0", lambda d: len(points(d)) > 2)
        api(web_port, "POST", "/api/write", {"var": "SA12", "value": 1})

        def span(d: Any) -> float:
            ys = [float(p.split(",")[1]) for p in points(d)]
            return max(ys) - min(ys) if ys else 0.0

        # The chart's plot is 150 - 8 - 20 = 122 px high: the bit spans it from 0 to 1.
        until(browser, "the bit spanning the chart", lambda d: span(d) > 100)
        until(browser, "each range in the legend",
              lambda d: "SA12 = 1 (0..1)" in text(d, "#trend-legend"))
    finally:
        run.stop()
