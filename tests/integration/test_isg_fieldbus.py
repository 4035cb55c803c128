"""The ISG dialect on the fieldbus (spec 5.6), as a Modbus client sees it: a signal wait is
WAIT_PROC (wait kind 1, target the channel it needs), a flush WAIT_COND with wait kind 5
("flush"), and a signal counts like an SND -- the SND log shows sender, addressee, N and the
signal's number; channels start one by one through the API."""

from __future__ import annotations

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.interpreter.engine import ProcessState, WaitKind

from ..conftest import EXAMPLES


@pytest.fixture
def ncgate_config():  # type: ignore[no-untyped-def]
    # Machine time at wall-clock speed: channel 1's #FLUSH lasts one real second.
    return ncgate_test_config(EXAMPLES / "isg_decoders" / "ncgate.toml",
                              **{"nc.time_scale": 1.0})


async def test_signal_wait_flush_and_snd_log_over_modbus(ncgate_gateway: Gateway,
                                                         virtual_plc: VirtualPLC) -> None:
    await ncgate_gateway.start("DECODERS", process=1)  # its section %kanal_1
    await ncgate_gateway.start("DECODERS", process=3)  # its section % kanal_3
    await virtual_plc.wait_state(3, "WAIT_PROC")
    state, _, line, kind, target = (await virtual_plc.status(3))[:5]
    assert (state, line, kind, target) == (ProcessState.WAIT_PROC, 16, WaitKind.PROC, 1)
    state, n, _, kind, _ = (await virtual_plc.status(1))[:5]
    assert (state, n, kind) == (ProcessState.WAIT_COND, 20, WaitKind.FLUSH)
    seen = await virtual_plc.next_snd()
    assert (seen.sender, seen.target, seen.n, seen.id) == (1, 3, 50, 814)
    await ncgate_gateway.wait_idle(timeout_s=30)
    p1, p3 = await virtual_plc.status(1), await virtual_plc.status(3)
    assert (p1[7], p3[9]) == (1, 1)  # sent by channel 1, received by channel 3
    assert p3[0] == ProcessState.IDLE
