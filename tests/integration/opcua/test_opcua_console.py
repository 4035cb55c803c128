"""The console's fieldbus panel shows the OPC UA server (a real browser against `ncgate run
--opcua`, node-opcua as its client): the endpoint, the security, what clients may write, and
the sessions, subscriptions, writes and refusals moving with what the client does."""

from __future__ import annotations

import asyncio
import re
from typing import Any

from ..web.test_browser import (  # the browser, run in a process, waits on the page
    RunProcess,
    browser,
    text,
    until,
    web_port,
)
from .conftest import IMAGE, UaClient

__all__ = ["browser", "web_port"]  # fixtures, taken by name


async def test_the_fieldbus_panel_shows_the_opcua_endpoint_its_clients_and_counts(
        browser: Any, web_port: int, ua_client: UaClient) -> None:
    run = RunProcess("--port", "0", "--web", f"127.0.0.1:{web_port}", "--opcua", "0",
                     "--set", 'opcua.writable=["sa_bits"]',
                     "--set", f"canopen.channel=opcua-{web_port}")
    try:
        line = await asyncio.to_thread(run.wait_for, "OPC UA on")
        found = re.search(r"(opc\.tcp://127\.0\.0\.1:\d+/)", line)
        assert found, line
        endpoint = found.group(1)
        shown = f"OPC UA {endpoint} (security none, writes sa_bits): "

        def panel(counts: str) -> Any:
            return asyncio.to_thread(until, browser, counts,
                                     lambda d: shown + counts in text(d, "#fieldbus"))

        await asyncio.to_thread(browser.get, f"http://127.0.0.1:{web_port}/")
        await panel("0 sessions, 0 subscriptions, 0 writes, 0 refused")
        await ua_client.call("connect", url=endpoint)
        await ua_client.call("subscribe", interval=50)
        assert await ua_client.call("write", node={"ns": IMAGE, "id": "SA12"},
                                    type="Boolean", value=True) == "Good"
        assert await ua_client.call("write", node={"ns": IMAGE, "id": "SK2"}, type="Byte",
                                    value=3) == "BadNotWritable"
        await panel("1 sessions, 1 subscriptions, 1 writes, 1 refused")
        await ua_client.call("close")  # the session ends, and its subscription with it
        await panel("0 sessions, 0 subscriptions, 1 writes, 1 refused")
    finally:
        await asyncio.to_thread(run.stop)
