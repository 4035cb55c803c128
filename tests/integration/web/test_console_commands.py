"""The console's command names come from the command table (ncgate.commands), over real HTTP:
``GET /api/commands`` lists them and the lane buttons the page draws, and ``POST
/api/command`` takes each of them."""

from __future__ import annotations

import aiohttp

from ncgate.commands import COMMANDS
from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config


async def test_the_console_lists_the_command_table_and_takes_its_names() -> None:
    config = ncgate_test_config(**{"web.port": 0})
    async with Gateway(config, console=True) as gw:
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            async with http.get("/api/commands") as r:
                assert r.status == 200
                listed = await r.json()
            assert [c["word"] for c in listed["commands"]] == [
                c.word for c in COMMANDS if not c.with_n]
            assert listed["lane"] == [[c.name, c.button] for c in COMMANDS
                                      if c.button is not None and not c.cell_only]
            assert listed["switches"] == ["block_skip", "optional_stop", "single_block"]
            for row in listed["commands"]:  # each name is a command the API takes
                if row["name"] in ("restart_plc", "reload_plc"):
                    continue  # (no PLC logic here: refused as not configured, 409)
                async with http.post("/api/command", json={"command": row["name"]}) as r:
                    assert r.status == 200, (row["name"], await r.text())
