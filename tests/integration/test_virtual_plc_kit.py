"""The virtual-PLC kit as a user writes it (this is the README's example): the manual's
three-process scheme over Modbus TCP, the test playing the PLC that sets SA10."""

from __future__ import annotations

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from ..conftest import EXAMPLES


@pytest.fixture
def ncgate_config():  # type: ignore[no-untyped-def]
    return ncgate_test_config(EXAMPLES / "scheme3" / "ncgate.toml", **{"nc.time_scale": 200.0})


async def test_scheme3_with_a_virtual_plc(ncgate_gateway: Gateway,
                                          virtual_plc: VirtualPLC) -> None:
    await virtual_plc.command(1)  # cycle start: PROG91 in process 1
    await virtual_plc.wait_state(2, "WAIT_COND")  # P2 at N40 waits for SA10 ...
    assert (await virtual_plc.status(2))[1] == 40
    seen = await virtual_plc.next_snd()  # P1 has released P2 and P3 by now
    assert (seen.sender, seen.target) in {(1, 2), (1, 3), (3, 1)}
    await virtual_plc.set("SA10", 1)  # ... which the PLC sets
    await ncgate_gateway.wait_idle(timeout_s=30)
    p1, p2 = await virtual_plc.status(1), await virtual_plc.status(2)
    assert p1[0] == 0 and p2[0] == 0  # both IDLE again
    assert (p1[6] << 16 | p1[7], p1[8] << 16 | p1[9]) == (4, 8)  # 2 cycles: sent 4, got 8
    assert (p2[6] << 16 | p2[7], p2[8] << 16 | p2[9]) == (4, 2)
    # Every SND after the first, in order, from the SND log (fewer than 16 came since):
    total = 0
    for k in (1, 2, 3):
        total += (await virtual_plc.status(k))[7]  # SNDs sent (low word)
    rest = [await virtual_plc.next_snd() for _ in range(total - 1)]
    snds = [(e["proc"], e["to"], e["n"]) for e in ncgate_gateway.trace if e["event"] == "snd"]
    assert [(seen.sender, seen.target, seen.n)] + [(s.sender, s.target, s.n) for s in rest] == snds
    assert snds[-1] == (3, 1, 94)  # the last SND of the run: P3's N94 to P1
