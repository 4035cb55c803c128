"""The same map rows through an independent Modbus client: mbpoll (Debian), as a subprocess.

CI installs mbpoll (.ci/run); on a developer machine without it these tests are skipped with
that reason -- never in CI, where a missing mbpoll is a failure.
"""

from __future__ import annotations

import os
import shutil

import pytest

from ncgate.gateway import Gateway

from ..mbpoll import mbpoll as poll
from ..mbpoll import tcp

if shutil.which("mbpoll") is None:
    if os.environ.get("CI"):
        pytest.fail("mbpoll is not installed: .ci/run must install it", pytrace=False)
    pytestmark = pytest.mark.skip(reason="mbpoll not installed (apt-get install mbpoll); "
                                         "CI runs these")


async def mbpoll(gw: Gateway, table: str, address: int, count: int = 1,
                 write: list[int] | None = None, unit: int = 1) -> tuple[int, dict[int, int], str]:
    """mbpoll once over Modbus TCP, on the gateway's port."""
    return await poll(tcp(gw), table, address, count, write, unit)


async def test_mbpoll_reads_info_and_status(ncgate_gateway: Gateway) -> None:
    rc, values, _ = await mbpoll(ncgate_gateway, "input", 0, 8)
    assert rc == 0 and values[0] == 1 and values[1] == 4
    rc, values, _ = await mbpoll(ncgate_gateway, "input", 100, 18)
    assert rc == 0 and values[100] == 0 and len(values) == 18


async def test_mbpoll_plays_the_plc_through_a_whole_cell(ncgate_gateway: Gateway) -> None:
    gw = ncgate_gateway
    assert (await mbpoll(gw, "holding", 2000, write=[1]))[0] == 0  # cycle start
    await gw.wait_state(2, "WAIT_COND", timeout_s=10)
    assert (await mbpoll(gw, "holding", 5, write=[200]))[0] == 0  # SK5 = 200 releases P2
    assert (await mbpoll(gw, "coils", 10, write=[1]))[0] == 0  # SA10 = 1 releases P1
    await gw.wait_state(1, "WAIT_PROC", timeout_s=10)
    rc, values, _ = await mbpoll(gw, "input", 4, 4)  # last SND: P1 -> external P4 at N4
    assert rc == 0 and [values[4], values[5], values[6]] == [1, 4, 4]
    assert (await mbpoll(gw, "holding", 2001, write=[4, 1]))[0] == 0  # mailbox: P4 -> P1
    await gw.wait_idle(timeout_s=10)
    rc, values, _ = await mbpoll(gw, "holding", 1003)
    assert rc == 0 and values[1003] == 0x10000 - 7  # SYVAR3 = -7, as a 16-bit register
    rc, values, _ = await mbpoll(gw, "discrete", 0, 16)
    assert rc == 0 and not any(values.values())  # P1 idle again


async def test_mbpoll_sees_exceptions(ncgate_gateway: Gateway) -> None:
    rc, _, text = await mbpoll(ncgate_gateway, "holding", 600)
    assert rc != 0 and "Illegal data address" in text
    rc, _, text = await mbpoll(ncgate_gateway, "holding", 7, write=[300])
    assert rc != 0 and "Illegal data value" in text
    assert ncgate_gateway.image.read("SK", 7, "BY") == 0
