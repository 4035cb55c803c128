"""A cycle start against an interlock is refused in the answer, whatever the program
(issue "What the field found", items 2 and 3): over real Modbus TCP and real HTTP, on a fresh
gateway whose main program is not read yet.  And after an interlock's hold, the first cycle
start only releases the hold, and the answer says so."""

from __future__ import annotations

from pathlib import Path

import aiohttp
import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.errors import InputRefused, Reason
from ncgate.gateway import Gateway
from ncgate.gateway.modbus.codes import REFUSAL
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.gateway.web.console import HTTP_STATUS
from ncgate.inputs import CommandKind
from ncgate.interpreter.engine import ProcessState

COMMAND = 2000  # holding register: the command word
FEED_HOLD_INPUT, INHIBIT_INPUT = 100, 101  # SA100, SA101: coils 100, 101


def _cell(tmp_path: Path, extra: str = "") -> Path:
    (tmp_path / "A.nc").write_text("N1G1X1000F600\nN2M30\n")  # 100 s of motion
    (tmp_path / "ncgate.toml").write_text(
        f'[nc]\nmain = "A"\nfeed_hold_input = "SA{FEED_HOLD_INPUT}"\n'
        f'cycle_start_inhibit_input = "SA{INHIBIT_INPUT}"\n'
        f'[nc.storage]\nMP0 = "."\n[canopen]\nenabled = false\n{extra}')
    return tmp_path / "ncgate.toml"


@pytest.mark.parametrize("interlock", [FEED_HOLD_INPUT, INHIBIT_INPUT])
async def test_an_interlocked_cycle_start_is_refused_before_its_program_is_read(
        tmp_path: Path, interlock: int) -> None:
    async with Gateway(ncgate_test_config(_cell(tmp_path))) as gw:
        assert not gw.runtime.store.ready("A", 1)  # fresh: the main program is not read
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            assert not (await client.write_coil(interlock, True, device_id=1)).isError()
            for word in (0x0101, 0x0001, 0x0105):  # P1's cycle start, the cell's, P1's step
                answer = await client.write_register(COMMAND, word, device_id=1)
                assert answer.isError(), hex(word)
                assert answer.exception_code == REFUSAL[Reason.INTERLOCK]  # 06: busy
        finally:
            client.close()
        with pytest.raises(InputRefused, match=r"input SA10[01] is set") as caught:
            gw.command(CommandKind.CYCLE_START, process=1)
        assert caught.value.reason is Reason.INTERLOCK
        await gw.wait_idle(timeout_s=10)  # nothing read in the background to start later
        assert gw.status(1).state is ProcessState.IDLE
        assert not gw.runtime.store.ready("A", 1)  # refused before anything was read
    assert [e for e in gw.trace if e["event"] == "start"] == []


async def test_the_console_refuses_an_interlocked_cycle_start_with_its_status(
        tmp_path: Path) -> None:
    config = ncgate_test_config(_cell(tmp_path), **{"web.port": 0})
    async with Gateway(config, console=True) as gw:
        gw.write(f"SA{INHIBIT_INPUT}", 1)
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            for body in ({"command": "start"}, {"command": "cycle_start", "process": 1}):
                async with http.post("/api/command", json=body) as r:
                    assert r.status == HTTP_STATUS[Reason.INTERLOCK], await r.text()
                    assert "cycle start inhibit input SA101 is set" in (await r.json())["error"]
        assert not gw.runtime.store.ready("A", 1)
        assert gw.status(1).state is ProcessState.IDLE


async def test_after_an_interlock_hold_the_first_cycle_start_says_it_only_released_it(
        tmp_path: Path) -> None:
    """The feed-hold input held the idle cell; once it clears, the first cycle start releases
    the hold and starts nothing (answered OK, and the answer says so), the second starts."""
    config = ncgate_test_config(_cell(tmp_path), **{"web.port": 0})
    async with Gateway(config, console=True) as gw:
        gw.write(f"SA{FEED_HOLD_INPUT}", 1)  # the door opens: the cell holds
        gw.write(f"SA{FEED_HOLD_INPUT}", 0)  # and closes: still held
        assert all(p.held for p in gw.engine.processes.values())
        host, port = gw.web_address
        async with aiohttp.ClientSession(f"http://{host}:{port}") as http:
            async with http.post("/api/command", json={"command": "start"}) as r:
                assert r.status == 200
                answer = await r.json()
            assert answer["command"] == "start"
            assert "released the feed hold" in answer["message"]
            assert "P1" in answer["message"] and "nothing started" in answer["message"]
            assert gw.status(1).state is ProcessState.IDLE
            assert not any(p.held for p in gw.engine.processes.values())
            async with http.post("/api/command", json={"command": "start"}) as r:
                assert r.status == 200
                assert await r.json() == {"command": "start"}  # a plain start says nothing
        await gw.wait_state(1, "RUNNING", timeout_s=10)
