"""The console under axe-core (Deque's accessibility engine, from npm at the version of
a11y/package-lock.json) in a real browser: no critical or serious WCAG 2.x A/AA finding, in
the light and the dark theme, idle and with processes running and waiting.

CI installs the package (.ci/run: npm ci in a11y/); on a developer machine without it the
test is skipped with that command -- never in CI, where it is a failure.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest

from .test_browser import CHROMIUM, api, browser, start_run, text, until, web_port

__all__ = ["browser", "web_port"]  # fixtures, taken by name

AXE = Path(__file__).with_name("a11y") / "node_modules" / "axe-core" / "axe.min.js"
if CHROMIUM is not None and not AXE.exists():
    if os.environ.get("CI"):
        pytest.fail("axe-core is not installed: .ci/run must run npm ci in "
                    "tests/integration/web/a11y", pytrace=False)
    pytestmark = pytest.mark.skip(reason="axe-core not installed (npm ci --prefix "
                                  "tests/integration/web/a11y); CI runs this")


def findings(driver: Any) -> list[str]:
    """axe's critical and serious violations of WCAG 2.x A and AA on the page as it is."""
    driver.execute_script(AXE.read_text(encoding="utf-8"))
    result = driver.execute_async_script("""
        const done = arguments[arguments.length - 1];
        axe.run(document, {runOnly: {type: 'tag', values: ['wcag2a', 'wcag2aa', 'wcag21a',
                                                            'wcag21aa']}})
           .then((r) => done(JSON.stringify(r.violations)), (e) => done(String(e)));""")
    violations = json.loads(result)
    return [f"{v['id']} ({v['impact']}): {v['help']} -- " + "; ".join(
                node["target"][0] if isinstance(node["target"][0], str) else str(node["target"])
                for node in v["nodes"][:5])
            for v in violations if v["impact"] in ("critical", "serious")]


def test_the_console_has_no_serious_accessibility_finding(browser: Any, web_port: int) -> None:
    run = start_run(web_port, "ncgate-browser-a11y")
    try:
        browser.set_script_timeout(60)
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "a live stream", lambda d: text(d, "#conn") == "live")
        assert findings(browser) == []
        api(web_port, "POST", "/api/command", {"command": "start"})  # P2 waits for SA10
        until(browser, "a waiting process", lambda d: "WAIT" in text(d, "#lanes"))
        assert findings(browser) == []
        toggle = browser.find_element("id", "theme")
        assert "auto" in toggle.text
        toggle.click()  # the page's dark theme, whatever the system's is
        assert "dark" in toggle.text
        rgb = browser.execute_script("return getComputedStyle(document.body).backgroundColor")
        assert sum(int(v) for v in rgb[rgb.index("(") + 1:-1].split(",")[:3]) < 150, rgb
        assert findings(browser) == []
    finally:
        run.stop()
