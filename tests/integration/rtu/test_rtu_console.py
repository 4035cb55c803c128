"""The console shows each RTU port's counters (a real browser against `ncgate run --rtu`),
and they move with what the line carries: a good frame, a bad CRC."""

from __future__ import annotations

import os
import time
import tty
from typing import Any

from ..web.test_browser import (  # the browser, run in a process, waits on the page
    RunProcess,
    browser,
    free_port,
    text,
    until,
    web_port,
)
from .conftest import frame

__all__ = ["browser", "web_port"]  # fixtures, taken by name


def test_the_fieldbus_panel_counts_each_rtu_ports_frames(browser: Any, web_port: int) -> None:
    master, slave = os.openpty()
    tty.setraw(master)
    device = os.ttyname(slave)
    run = RunProcess("--port", "0", "--web", f"127.0.0.1:{web_port}", "--rtu", device,
                     "--rtu-tcp", str(free_port()), "--set", f"canopen.channel=rtu-{web_port}")
    try:
        run.wait_for(f"web console on http://127.0.0.1:{web_port}/")
        run.wait_for("Modbus RTU on")
        os.write(master, frame("01 04 0000 0002"))
        assert len(os.read(master, 9)) == 9  # answered (a blocking read: the answer comes)
        bad = bytearray(frame("01 04 0000 0002"))
        bad[-1] ^= 0xFF
        os.write(master, bytes(bad))
        time.sleep(0.05)  # the line's silence after the bad frame: the input itself
        os.write(master, frame("01 04 0000 0002"))
        assert len(os.read(master, 9)) == 9
        browser.get(f"http://127.0.0.1:{web_port}/")
        until(browser, "the serial port's counters",
              lambda d: f"Modbus RTU {device} (19200 8E1): 2 frames, 1 CRC errors, 0 partial, "
                        "0 exceptions" in text(d, "#fieldbus"))
        assert "Modbus RTU over tcp 127.0.0.1:" in text(browser, "#fieldbus")
    finally:
        run.stop()
        os.close(master)
        os.close(slave)
