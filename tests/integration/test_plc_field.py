"""The gateway's side of "What the field found": ``run --watch`` and the PLC logic as the
field writes it."""

from __future__ import annotations

import asyncio
from pathlib import Path

from ncgate.gateway.plc import LogicWatcher, read_sources

PROGRAM = "PROGRAM p\nVAR x : INT; END_VAR\nx := 1;\nEND_PROGRAM\n"


async def test_run_watch_reloads_a_save_made_while_the_logic_was_first_read(
        tmp_path: Path) -> None:
    logic = tmp_path / "p.st"
    logic.write_text(PROGRAM)
    read_sources((logic,))  # the PLC reads the logic (as start_plc does) ...
    logic.write_text(PROGRAM.replace("x := 1;", "x := 22;"))  # ... and a save lands meanwhile
    reloaded = asyncio.Event()
    watcher = LogicWatcher((logic,), reloaded.set, asyncio.get_running_loop(),
                           interval_s=0.01)
    watcher.start()  # (made once the gateway is up: after the read)
    try:
        async with asyncio.timeout(10):
            await reloaded.wait()
    finally:
        watcher.close()
