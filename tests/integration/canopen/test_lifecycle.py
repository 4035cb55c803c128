"""The node's life cycle and its bridge to the loop: nothing scheduled from the CAN thread
runs after close, and an SDO answered with an abort never acts afterwards."""

from __future__ import annotations

import asyncio
import logging
import time

import pytest
from canopen.sdo.exceptions import SdoAbortedError

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.canopen.codes import ABORT_GENERAL_ERROR
from ncgate.gateway.canopen.dictionary import SA_BYTES

from .conftest import Master


@pytest.mark.parametrize("ncgate_config", [{"canopen.nmt_autostart": True}], indirect=True)
async def test_enter_and_leave_at_once_logs_nothing_amiss(
        master: Master, ncgate_config: Config, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING)
    async with Gateway(ncgate_config):
        pass
    await asyncio.sleep(0)  # one more turn: what the node left on the loop would run here
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []


async def test_an_sdo_aborted_for_a_stalled_loop_is_never_applied(
        master: Master, gw: Gateway) -> None:
    master.node.sdo.RESPONSE_TIMEOUT = 5.0
    download = asyncio.ensure_future(asyncio.to_thread(
        master.node.sdo.download, SA_BYTES, 1, b"\x05"))
    await asyncio.sleep(0)  # the download's thread has started
    # The stimulus, not a wait: the loop stalls past the node's 2 s bridge timeout while
    # the request is on its way.
    time.sleep(2.5)  # noqa: ASYNC251 - the stalled loop is what is tested
    with pytest.raises(SdoAbortedError) as caught:
        await download
    assert caught.value.code == ABORT_GENERAL_ERROR
    await master.barrier()  # everything the node handed the loop has run
    assert gw.image.read("SA", 0, "BY") == 0  # the aborted write did not happen later
    assert not any(e["event"] == "write" for e in gw.trace)
