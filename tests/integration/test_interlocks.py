"""The PLC's interlocks as levels, and a restart of the PLC alone (issue 27, items 6 and 7),
over real Modbus TCP: the PLC (here the test, as a virtual PLC) sets an input, the NC holds
and refuses a cycle start while it is set; a faulted PLC restarts without touching the NC."""

from __future__ import annotations

from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient

from ncgate.errors import InputRefused, Reason
from ncgate.gateway import Gateway
from ncgate.gateway.testing.plc_kit import PlcFaulted, PlcWatch
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.inputs import CommandKind
from ncgate.interpreter.engine import ProcessState
from ncgate.plc.scan import PlcState

COMMAND = 2000  # holding register: the command word


def _cell(tmp_path: Path, extra: str = "") -> Path:
    (tmp_path / "A.nc").write_text("N1G1X1000F600\nN2M30\n")  # 100 s of motion
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\nfeed_hold_input = "SA100"\ncycle_start_inhibit_input = "SA101"\n'
        f'[nc.storage]\nMP0 = "."\n[canopen]\nenabled = false\n{extra}')
    return tmp_path / "ncgate.toml"


async def test_a_feed_hold_input_holds_and_refuses_cycle_start_while_set(
        tmp_path: Path) -> None:
    async with Gateway(ncgate_test_config(_cell(tmp_path))) as gw:
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            async def command(word: int) -> int:
                answer = await client.write_register(COMMAND, word, device_id=1)
                return answer.exception_code if answer.isError() else 0

            assert await command(1) == 0
            await gw.wait_state(1, "RUNNING", timeout_s=10)
            await client.write_coil(100, True, device_id=1)  # the door opens
            await gw.wait_state(1, "HOLD", timeout_s=10)
            assert await command(1) == 6  # SERVER DEVICE BUSY: the interlock is set
            assert gw.status(1).state is ProcessState.HOLD  # the cycle start changed nothing
            with pytest.raises(InputRefused, match="feed hold input SA100 is set") as caught:
                gw.command(CommandKind.CYCLE_START)
            assert caught.value.reason is Reason.INTERLOCK
            await client.write_coil(100, False, device_id=1)  # closed: still held ...
            assert gw.status(1).state is ProcessState.HOLD
            assert await command(1) == 0  # ... until a cycle start
            await gw.wait_state(1, "RUNNING", timeout_s=10)
            # The inhibit refuses a cycle start too, and holds nothing.
            await client.write_coil(101, True, device_id=1)
            assert await command(2) == 0  # feed hold: always allowed
            await gw.wait_state(1, "HOLD", timeout_s=10)
            assert await command(1) == 6
            with pytest.raises(InputRefused, match="cycle start inhibit input SA101 is set"):
                gw.command(CommandKind.CYCLE_START)
        finally:
            client.close()
        holds = [e for e in gw.trace if e["event"] == "write" and e["var"] == "SA100"]
    assert [e["value"] for e in holds] == [1, 0]


def test_an_interlock_input_outside_the_image_is_a_config_error(tmp_path: Path) -> None:
    from ncgate.config import ConfigError, load_config

    (tmp_path / "ncgate.toml").write_text('[nc]\nfeed_hold_input = "SA99999"\n')
    with pytest.raises(ConfigError, match=r"nc\.feed_hold_input: SA99999 is outside the image"):
        load_config(tmp_path / "ncgate.toml")
    (tmp_path / "ncgate.toml").write_text('[nc]\ncycle_start_inhibit_input = "door"\n')
    with pytest.raises(ConfigError, match=r"nc\.cycle_start_inhibit_input: expected SA<n>"):
        load_config(tmp_path / "ncgate.toml")


FAULTY = """PROGRAM main
VAR q : INT; END_VAR
q := 100 / SYVAR[1];
SYVAR[2] := q;
END_PROGRAM
"""


async def test_a_restart_of_the_plc_alone_leaves_the_nc_as_it_is(tmp_path: Path) -> None:
    """A faulted PLC restarts on command 4 (Modbus), while P1 keeps moving and the NC is
    not reset (a reset of the cell would end P1's program)."""
    (tmp_path / "logic.st").write_text(FAULTY)
    path = _cell(tmp_path, '[plc]\nlogic = "logic.st"\n')
    async with Gateway(ncgate_test_config(path)) as gw:
        watch = PlcWatch(gw)
        with pytest.raises(PlcFaulted):
            await watch.until("main.q", 25)  # SYVAR1 = 0: the first scan faults
        gw.command(CommandKind.CYCLE_START)
        await gw.wait_state(1, "RUNNING", timeout_s=10)
        gw.write("SYVAR1", 4)
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            answer = await client.write_register(COMMAND, 4, device_id=1)
            assert not answer.isError()
            # Of one process it is refused: the PLC is the cell's.
            answer = await client.write_register(COMMAND, 0x0104, device_id=1)
            assert answer.isError() and answer.exception_code == 3
        finally:
            client.close()
        assert await watch.until("main.q", 25) == 25
        assert gw.plc.status.state is PlcState.RUNNING
        assert gw.status(1).state is ProcessState.RUNNING  # untouched
        ends = [e for e in gw.trace if e["event"] == "end"]
    assert ends == []


async def test_a_restart_of_the_plc_without_plc_logic_is_refused(tmp_path: Path) -> None:
    async with Gateway(ncgate_test_config(_cell(tmp_path))) as gw:
        with pytest.raises(InputRefused, match="no PLC logic") as caught:
            gw.command(CommandKind.RESTART_PLC)
        assert caught.value.reason is Reason.NOT_CONFIGURED


LEVELS = """PROGRAM main
VAR n : INT; END_VAR
n := n + 1;
NC.P[2].START := SA[30];
NC.HOLD_LEVEL := SA[31];
NC.FEED_OVERRIDE := SYVAR[9];
END_PROGRAM
"""


async def test_the_plc_logic_starts_a_process_holds_as_a_level_and_sets_the_override(
        tmp_path: Path) -> None:
    """Issue 27's ST names through a running gateway: NC.P[2].START starts process 2's own
    main; NC.HOLD_LEVEL holds the cell and refuses a Modbus cycle start while TRUE;
    NC.FEED_OVERRIDE sets every process's feed override."""
    (tmp_path / "logic.st").write_text(LEVELS)
    (tmp_path / "B.nc").write_text("N1G1X1000F600\nN2M30\n")
    path = _cell(tmp_path, '[plc]\nlogic = "logic.st"\n[[nc.process]]\nnumber = 2\n'
                           'main = "B"\n')
    async with Gateway(ncgate_test_config(path)) as gw:
        watch = PlcWatch(gw)
        gw.write("SYVAR9", 100)
        gw.write("SA30", 1)  # the logic's NC.P[2].START rises
        await gw.wait_state(2, "RUNNING", timeout_s=10)
        gw.write("SYVAR9", 40)
        n = watch.read("main.n")
        await watch.until("main.n", test=lambda v: v >= n + 2)  # two scans later
        assert gw.engine.processes[2].feed_override == 40
        gw.write("SA31", 1)  # NC.HOLD_LEVEL
        await gw.wait_state(2, "HOLD", timeout_s=10)
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus_address[1])
        assert await client.connect()
        try:
            refused = await client.write_register(COMMAND, 1, device_id=1)
        finally:
            client.close()
        assert refused.isError() and refused.exception_code == 6
        starts = [(e["proc"], e["by"]) for e in gw.trace if e["event"] == "start"]
    assert starts == [(2, "plc logic.st:4")]
