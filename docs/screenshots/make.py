"""The console's screenshots in docs/screenshots/ (docs/console.md shows them), made again.

``ncgate run`` on a copy of examples/plclogic with a few I/O names; headless Chromium through
Selenium opens the console at 1366x768 and at 390x844 (a phone), starts the cell, forces a bit,
adds two trends, and saves the page once the PLC has answered P2 twice::

    .venv/bin/python docs/screenshots/make.py            # writes docs/screenshots/*.png

Needs chromium and chromedriver (apt-get install chromium chromium-driver).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
EXAMPLE = HERE.parent.parent / "examples" / "plclogic"
SYMBOLS = """
[symbols]
answer_p2 = { var = "SA10", comment = "the PLC's answer at N40" }
waited_too_long = "SA11"
answers_given = "SYVAR20"
"""
SIZES = {"console-1366x768.png": (1366, 768), "console-390x844.png": (390, 844)}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def until(driver: Any, script: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not driver.execute_script(script):
        if time.monotonic() > deadline:
            sys.exit(f"the page never showed: {script}")
        time.sleep(0.2)


def shoot(chromium: str, chromedriver: str, url: str, name: str, size: tuple[int, int],
          theme: str, below: str = "") -> None:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By

    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--hide-scrollbars", f"--window-size={size[0]},{size[1]}"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service(chromedriver), options=options)
    try:
        driver.get(url)
        driver.execute_script("localStorage.setItem('ncgate-theme', arguments[0])", theme)
        driver.get(url)
        until(driver, "return document.querySelector('#conn').textContent === 'live'")
        for name_ in ("answers_given", "cell.answer.ET"):
            driver.find_element(By.ID, "trend-var").send_keys(name_)
            driver.find_element(By.CSS_SELECTOR, "#trend-form button").click()
        until(driver, "return document.querySelectorAll('#trend polyline').length === 2"
              " && document.querySelector('#lane-2 .state').textContent !== ''")
        time.sleep(8)  # a few seconds of trend
        # The viewport itself at the size (the window's would include the browser's frame).
        driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
            "width": size[0], "height": size[1], "deviceScaleFactor": 1,
            "mobile": size[0] < 700})
        driver.execute_script("window.scrollTo(0, 0); document.activeElement.blur()")
        time.sleep(0.5)  # a tick: the timeline and the trends drawn at the new width
        driver.save_screenshot(str(HERE / name))
        print(f"wrote {HERE / name}")
        if below:  # the trends, the force list, the image grid and the PLC's variables
            driver.execute_script("window.scrollTo(0, document.getElementById('trend-box')"
                                  ".offsetTop - document.querySelector('header').offsetHeight"
                                  " - 8)")
            time.sleep(0.5)
            driver.save_screenshot(str(HERE / below))
            print(f"wrote {HERE / below}")
    finally:
        driver.quit()


def main() -> None:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    chromedriver = shutil.which("chromedriver")
    if chromium is None or chromedriver is None:
        sys.exit("needs chromium and chromedriver (apt-get install chromium chromium-driver)")
    with tempfile.TemporaryDirectory() as folder:
        cell = Path(folder) / "cell"
        shutil.copytree(EXAMPLE, cell)
        config = cell / "ncgate.toml"
        config.write_text(config.read_text() + SYMBOLS)
        web = free_port()
        run = subprocess.Popen([sys.executable, "-m", "ncgate", "run", "-q", "--cold",
                                "--config", str(config), "--port", "0",
                                "--web", f"127.0.0.1:{web}", "--set", "canopen.enabled=false",
                                "--set", "nc.time_scale=5"],
                               cwd=folder)
        try:
            url = f"http://127.0.0.1:{web}/"
            deadline = time.monotonic() + 20
            while True:
                try:
                    with socket.create_connection(("127.0.0.1", web), timeout=1):
                        break
                except OSError:
                    if time.monotonic() > deadline or run.poll() is not None:
                        sys.exit("ncgate run did not start")
                    time.sleep(0.1)
            api = _Api(url)
            api.post("/api/command", {"command": "start"})
            api.post("/api/force", {"var": "SA30", "value": 1})
            for name, size in SIZES.items():
                shoot(chromium, chromedriver, url, name, size, "light",
                      name.replace(".png", "-below.png") if size[0] > 700 else "")
            shoot(chromium, chromedriver, url, "console-dark-1366x768.png", (1366, 768),
                  "dark")
        finally:
            run.terminate()
            run.wait(10)


class _Api:
    def __init__(self, url: str) -> None:
        self.url = url.rstrip("/")

    def post(self, path: str, body: dict[str, Any]) -> None:
        import json
        import urllib.request

        request = urllib.request.Request(self.url + path, method="POST",
                                         data=json.dumps(body).encode(),
                                         headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(request, timeout=10):
            pass


if __name__ == "__main__":
    main()
