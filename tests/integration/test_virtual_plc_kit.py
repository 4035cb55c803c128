"""The virtual-PLC kit as a user writes it (this is the README's example): the manual's
three-process scheme over Modbus TCP, the test playing the PLC that sets SA10."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

import pytest

from ncgate.config import Config
from ncgate.gateway import Gateway
from ncgate.gateway.errors import VirtualPLCError, WaitIdleTimeout
from ncgate.gateway.testing import wait_event
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.interpreter.engine import ProcessState, WaitKind

from ..conftest import EXAMPLES

T = TypeVar("T")


@pytest.fixture
def ncgate_config(request: pytest.FixtureRequest) -> Config:
    return ncgate_test_config(EXAMPLES / "scheme3" / "ncgate.toml",
                              **{"nc.time_scale": 200.0, **getattr(request, "param", {})})


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


async def test_status_is_a_named_record_that_still_reads_by_position(
        ncgate_gateway: Gateway, virtual_plc: VirtualPLC) -> None:
    await virtual_plc.command(1)
    seen = await virtual_plc.wait_state(2, "WAIT_COND")  # P2 at N40 waits for SA10
    assert (seen.process, seen.state, seen.n, seen.wait_kind) == (
        2, ProcessState.WAIT_COND, 40, WaitKind.COND)
    status = await virtual_plc.status(2)
    engine = ncgate_gateway.status(2)
    assert (status.state, status.n, status.line, status.alarm_code) == (
        engine.state, engine.n, engine.line, 0)
    assert status[:3] == [int(ProcessState.WAIT_COND), 40, engine.line]  # as the registers
    assert status[1] == status.n and len(status.registers) == 18
    assert status.why() == f"P2 WAIT_COND at line {engine.line} N40, wait COND 0"


@pytest.mark.parametrize("ncgate_config", [{"nc.stall_s": 0.5}], indirect=True)
async def test_wait_event_awaits_a_stall_and_explains_a_timeout(
        ncgate_gateway: Gateway, virtual_plc: VirtualPLC) -> None:
    gw = ncgate_gateway
    # Listening before the cycle start (the task subscribes in its first step, which runs
    # before the gateway reads the command): only the events from then on count.
    stalled = asyncio.create_task(wait_event(gw, "stall", timeout_s=30))
    await virtual_plc.command(1)
    stall = await stalled  # P2 waits for SA10, which no one sets
    assert stall.kind == "stall" and any(b.proc == 2 for b in stall.blocked)  # type: ignore[union-attr]
    with pytest.raises(WaitIdleTimeout) as failed:
        await wait_event(gw, "snd", timeout_s=0.2, test=lambda e: e.proc == 2)
    assert "no 'snd' event that passes the test in 0.2 s" in str(failed.value)
    assert "P2 " in str(failed.value)  # the why-records, as wait_idle gives them


# -- every kit wait ends by its own deadline ----------------------------------------------------

AUX_CONFIG = {"nc.aux.codes": {"M8": "before_motion"}}
WAITS: dict[str, Callable[[VirtualPLC], Awaitable[object]]] = {
    "wait_state": lambda plc: plc.wait_state(1, "RUNNING", timeout_s=0.2),
    "next_snd": lambda plc: plc.next_snd(timeout_s=0.2),
    "expect_aux": lambda plc: plc.expect_aux("M8", timeout_s=0.2),
}


@pytest.fixture
def aux_config() -> Config:
    return ncgate_test_config(**AUX_CONFIG)


async def silent_server() -> tuple[asyncio.Server, list[bytes]]:
    """A TCP server on loopback that accepts and reads every request, and never answers."""
    heard: list[bytes] = []

    class Silent(asyncio.Protocol):
        def data_received(self, data: bytes) -> None:
            heard.append(data)

    server = await asyncio.get_running_loop().create_server(Silent, "127.0.0.1", 0)
    return server, heard


@pytest.mark.timeout(30)  # a wait that does not end fails here instead of hanging the run
@pytest.mark.parametrize("wait", sorted(WAITS))
async def test_a_kit_wait_on_a_gateway_that_never_answers_ends_by_its_timeout(
        wait: str, aux_config: Config) -> None:
    """wait_state read the state once more after its timeout, with no bound of its own: the
    client's 3 s answer timeout, then a ModbusIOException instead of the kit's error."""
    server, heard = await silent_server()
    async with server:
        port = server.sockets[0].getsockname()[1]
        plc = VirtualPLC("127.0.0.1", port, aux_config)
        assert await plc.client.connect()  # not plc.connect(): it reads the SND log first
        try:
            with pytest.raises(VirtualPLCError) as failed:
                await WAITS[wait](plc)
        finally:
            plc.close()
    assert heard  # it did ask
    assert "in 0.2 s" in str(failed.value)
    assert "the processes' status could not be read" in str(failed.value)


def answering_only_when_cancelled(call: Callable[..., Awaitable[T]]
                                  ) -> Callable[..., Awaitable[T]]:
    """The injected fault, made certain: a client call that hands its answer over only when it
    is cancelled, and then returns it, dropping the cancellation. Python 3.11's
    asyncio.wait_for, with which pymodbus awaits every answer, does that when the answer and
    the cancellation come in the same turn of the loop (7 calls in 90 under load)."""

    async def call_on(*args: Any, **kwargs: Any) -> T:
        answer = await call(*args, **kwargs)
        # Held back until a cancellation comes, which is then dropped.
        with contextlib.suppress(asyncio.CancelledError):
            await asyncio.Event().wait()
        return answer

    return call_on


@pytest.mark.timeout(30)  # it hung for ever before: its one cancellation was dropped
@pytest.mark.parametrize("ncgate_config", [AUX_CONFIG], indirect=True)
@pytest.mark.parametrize("wait", sorted(WAITS))
async def test_a_kit_wait_ends_by_its_deadline_though_the_client_drops_a_cancellation(
        wait: str, ncgate_gateway: Gateway, virtual_plc: VirtualPLC,
        monkeypatch: pytest.MonkeyPatch) -> None:
    client = virtual_plc.client
    for name in ("read_input_registers", "read_holding_registers", "read_coils"):
        monkeypatch.setattr(client, name, answering_only_when_cancelled(getattr(client, name)))
    with pytest.raises(VirtualPLCError) as failed:
        await WAITS[wait](virtual_plc)  # nothing runs: the wait cannot succeed
    message = str(failed.value)
    assert "in 0.2 s" in message
    # Why, as the gateway reports each process: nothing is loaded, so every one is IDLE.
    assert [line.split()[:2] for line in message.splitlines()[1:]] == [
        [f"P{k}", "IDLE"] for k in range(1, ncgate_gateway.config.nc.processes + 1)]


async def test_the_kit_sets_and_gets_by_the_configs_io_names() -> None:
    """`virtual_plc.set("clamp_valve", 1)` as the machine example's I/O list names it (a new
    user got "C needs a value"): the name is the variable [symbols] gives it, any case."""
    config = ncgate_test_config(**{"symbols.clamp_valve": "SA20", "symbols.speed": "SYVAR7",
                                   "symbols.mode": "K12"})
    async with Gateway(config) as gw:
        host, port = gw.modbus_address
        async with VirtualPLC(host, port, gw.config) as plc:
            await plc.set("clamp_valve", 1)
            await plc.set("Speed", 1234)
            await plc.set("MODE", 7)
            assert (gw.image.read("SA", 20, "bit"), gw.image.read("SYVAR", 7, "IN"),
                    gw.image.read("SK", 12, "BY")) == (1, 1234, 7)
            assert [await plc.get(n) for n in ("clamp_valve", "speed", "mode")] == [1, 1234, 7]
            with pytest.raises(ValueError):
                await plc.set("no_such_name", 1)
