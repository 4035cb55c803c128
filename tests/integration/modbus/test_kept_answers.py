"""The answers the server keeps for reads of the image alone (docs/decisions.md, "Speed
against C"): a poller that reads the same K bytes, SA bytes or SYVARs again gets the same
bytes without the image being read again -- and the first read after any writer changed the
image reads the new value, whoever wrote it: a Modbus client, the API, the PLC's scan, an NC
program, a plant model, a force, a held (stuck) input.  Over real Modbus TCP on loopback,
one whole request a segment (the pollers' direct path)."""

from __future__ import annotations

import asyncio
import struct
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.modbus.framer import mbap_tail
from ncgate.gateway.modbus.map import ModbusMap
from ncgate.gateway.modbus.server import RequestHandler
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from ...helpers import write_cell
from .rawclient import Raw, pdu

CELL = """
[nc]
processes = 1
main = "MAIN"
[nc.storage]
MP0 = "."
[plc]
logic = "logic.st"
[plant]
scan_ms = 10
[[plant.model]]
name = "relay"
kind = "delay"
input = "SA20"
output = "SA30"
on_ms = 300
off_ms = 50
"""
# Each writer that acts later than what sets it going: the PLC 300 ms after SYVAR30 = 1, the
# NC 300 ms after SYVAR40 = 1, the relay (above) 300 ms after SA20 = 1.  A poller reads in
# between, so that its answer is kept at the image as the trigger left it.
LOGIC = """PROGRAM main
VAR
  t : TON;
END_VAR
t(IN := SYVAR[30] = 1, PT := T#300ms);
IF t.Q THEN
  SK[7] := 99;
END_IF
END_PROGRAM
"""
PROGRAMS = {"MAIN": "N1(WAI,SYVAR40=1)\nN2(DLY,0.3)\nN3#SYVAR41=123\nN4M30\n"}
# The ranges the poller reads: K bytes 0..9, SA bytes 0..5, SYVARs 28..43.
RANGES = ((0, 10), (1500, 6), (1028, 16))


@pytest.fixture
async def gw(tmp_path: Path) -> AsyncIterator[Gateway]:
    cell = write_cell(tmp_path, CELL, PROGRAMS)
    (cell / "logic.st").write_text(LOGIC)
    async with Gateway(ncgate_test_config(cell / "ncgate.toml")) as gateway:
        yield gateway


def _handler(gw: Gateway) -> RequestHandler:
    assert gw.modbus_server is not None
    return gw.modbus_server.handler


async def _read(raw: Raw, address: int, count: int) -> list[int]:
    answer = await raw.ask(pdu(3, "HH", address, count))
    assert answer[:2] == bytes((3, 2 * count)), answer.hex()
    return list(struct.unpack(f">{count}H", answer[2:]))


class Poller:
    """A poller of RANGES on its own connection: the values by variable name."""

    def __init__(self, gw: Gateway, raw: Raw) -> None:
        self.gw, self.raw = gw, raw

    async def poll(self) -> dict[str, int]:
        k, sa, syvar = [await _read(self.raw, a, n) for a, n in RANGES]
        values = {f"SK{i}": v for i, v in enumerate(k)}
        values |= {f"SA{8 * i + bit}": v >> bit & 1 for i, v in enumerate(sa) for bit in range(8)}
        values |= {f"SYVAR{28 + i}": v - 0x10000 if v & 0x8000 else v
                   for i, v in enumerate(syvar)}
        return values

    def kept(self) -> bool:
        """Whether every range's answer is kept (the next poll takes them)."""
        kept = _handler(self.gw).kept
        return all(mbap_tail(1, pdu(3, "HH", a, n)) in kept for a, n in RANGES)


async def _written(gw: Gateway, var: str, value: int, timeout_s: float = 10.0) -> None:
    """Until a write (whoever's) leaves ``var`` at ``value`` in the image."""
    if gw.read(var) == value:
        return
    came = asyncio.Event()

    def hear(changes: object, writer: str) -> None:
        if gw.read(var) == value:
            came.set()

    stop = gw.image.subscribe(hear)
    try:
        async with asyncio.timeout(timeout_s):
            await came.wait()
    finally:
        stop()


async def test_a_read_of_the_image_again_is_answered_without_reading_the_image(
        gw: Gateway, monkeypatch: pytest.MonkeyPatch) -> None:
    reads: list[object] = []
    original = ModbusMap._read_region

    def counted(self: ModbusMap, *args: object) -> list[int]:
        reads.append(args[1])
        return original(self, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(ModbusMap, "_read_region", counted)
    gw.write("SK3", 42)
    raw = await Raw.open(*gw.modbus_address)
    try:
        first = await raw.ask(pdu(3, "HH", 0, 10))
        again = [await raw.ask(pdu(3, "HH", 0, 10)) for _ in range(5)]  # each its own tid
        assert again == [first] * 5 and first[2 + 2 * 3:2 + 2 * 4] == b"\x00\x2a"
        assert len(reads) == 1
        # The process status (the view's) is read each time: it is not the image's.
        await raw.ask(pdu(4, "HH", 100, 18))
        await raw.ask(pdu(4, "HH", 100, 18))
        assert len(reads) == 3
    finally:
        raw.close()


async def test_the_first_read_after_any_writer_changed_the_image_has_the_new_value(
        gw: Gateway) -> None:
    await gw.start()  # MAIN waits for SYVAR40
    raw, other = await Raw.open(*gw.modbus_address), await Raw.open(*gw.modbus_address)
    poller = Poller(gw, raw)
    try:
        async def sees(var: str, value: int) -> None:
            """The image holds ``value`` now: so does the poller's next read."""
            assert gw.read(var) == value
            assert (await poller.poll())[var] == value, var

        async def after_trigger(trigger: str, var: str, old: int, new: int) -> None:
            """``var`` changes some time after ``trigger`` is set: a poll in between is kept
            with the old value, the first after the change sees the new."""
            gw.write(trigger, 1)
            assert (await poller.poll())[var] == old and poller.kept()
            await _written(gw, var, new)
            await sees(var, new)

        assert (await poller.poll())["SK3"] == 0 and poller.kept()
        # A Modbus client on another connection: FC6 on K byte 3, FC5 on coil 10.
        assert await other.ask(pdu(6, "HH", 3, 17)) == pdu(6, "HH", 3, 17)
        await sees("SK3", 17)
        assert poller.kept()
        assert await other.ask(pdu(5, "HH", 10, 0xFF00)) == pdu(5, "HH", 10, 0xFF00)
        await sees("SA10", 1)
        # The API.
        gw.write("SK5", 12)
        await sees("SK5", 12)
        # The PLC's scan, the NC program, the plant's relay.
        await after_trigger("SYVAR30", "SK7", 0, 99)
        await after_trigger("SYVAR40", "SYVAR41", 0, 123)
        await after_trigger("SA20", "SA30", 0, 1)
        # A force, over the Modbus force request too; a held input (a stuck fault).
        assert poller.kept()
        gw.force("SK8", 55)
        await sees("SK8", 55)
        assert await other.ask(pdu(16, "HHB4H", 2100, 4, 8, 1, 4, 6, 66)) == pdu(
            16, "HH", 2100, 4)  # force K byte 6 to 66
        await sees("SK6", 66)
        gw.fault("SK9", "stuck", value=33)
        await sees("SK9", 33)
        gw.write("SK9", 1)  # held: every reader sees 33 still
        await sees("SK9", 33)
        gw.clear_fault("SK9")
        gw.write("SK9", 2)
        await sees("SK9", 2)
        # The search N (holding 2003) is the map's, not the image's: never kept.
        assert await other.ask(pdu(6, "HH", 2003, 40)) == pdu(6, "HH", 2003, 40)
        assert await _read(raw, 2003, 1) == [40]
        assert await other.ask(pdu(6, "HH", 2003, 41)) == pdu(6, "HH", 2003, 41)
        assert await _read(raw, 2003, 1) == [41]
    finally:
        raw.close()
        other.close()
