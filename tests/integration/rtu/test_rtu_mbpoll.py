"""Modbus RTU through an independent master: mbpoll (Debian, on libmodbus) in its RTU mode,
19,200 bit/s, even parity, on a socat pty pair -- and RTU over TCP, mbpoll on a pty that
socat relays to the gateway's RTU-over-TCP port, as a serial device server would."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from ncgate.gateway import Gateway

from ..mbpoll import mbpoll, rtu, tcp
from .conftest import need, socat

# Every table, over the map's regions (docs/modbus map): coils (SA bits), discrete inputs
# (process flags), input registers (info, status blocks, SND log, PLC status) and holding
# registers (K bytes, SYVARs, SA bytes, the command word and mailbox, the overrides).
RANGES = [("coils", 0, 64), ("discrete", 0, 64), ("input", 0, 8), ("input", 100, 80),
          ("input", 200, 98), ("input", 300, 14), ("holding", 0, 100), ("holding", 1000, 50),
          ("holding", 1500, 16), ("holding", 2000, 3), ("holding", 2010, 8)]


@pytest.fixture(autouse=True)
def _mbpoll() -> None:
    need("mbpoll", "mbpoll")


async def test_mbpoll_rtu_reads_every_table_as_tcp_does(ncgate_gateway: Gateway,
                                                        socat_pair: tuple[str, str]) -> None:
    gw = ncgate_gateway
    # Something in every table first: a cycle start (P1 runs), an SND, a K byte, an SA bit.
    assert (await mbpoll(rtu(socat_pair[1]), "holding", 2000, write=[1]))[0] == 0
    await gw.wait_state(2, "WAIT_COND", timeout_s=10)
    assert (await mbpoll(rtu(socat_pair[1]), "holding", 3, write=[77]))[0] == 0
    assert (await mbpoll(rtu(socat_pair[1]), "coils", 12, write=[1]))[0] == 0
    await gw.wait_state(1, "WAIT_COND", timeout_s=10)  # at rest: P1 and P2 both wait
    for table, address, count in RANGES:
        rc_rtu, over_rtu, text = await mbpoll(rtu(socat_pair[1]), table, address, count)
        rc_tcp, over_tcp, _ = await mbpoll(tcp(gw), table, address, count)
        assert rc_rtu == rc_tcp == 0, text
        assert len(over_rtu) == count and over_rtu == over_tcp, (table, address)
    assert gw.image.k[3] == 77 and (gw.image.sa[1] >> 4) & 1
    writes = {e["who"] for e in gw.trace if e["event"] == "write"}
    assert f"modbus-rtu {socat_pair[0]}" in writes


async def test_an_rtu_master_releases_a_wait_and_reads_the_snd_log(
        ncgate_gateway: Gateway, socat_pair: tuple[str, str]) -> None:
    gw, line = ncgate_gateway, rtu(socat_pair[1])
    assert (await mbpoll(line, "holding", 2000, write=[1]))[0] == 0  # cycle start
    await gw.wait_state(1, "WAIT_COND", timeout_s=10)  # P1 at N3 (WAI,SA10=1)
    assert (await mbpoll(line, "holding", 5, write=[200]))[0] == 0  # SK5 = 200: P2 goes on
    assert (await mbpoll(line, "coils", 10, write=[1]))[0] == 0  # SA10 = 1: P1 goes on
    await gw.wait_state(1, "WAIT_PROC", timeout_s=10)  # past its SND to P4, at (WAI,4)
    rc, values, text = await mbpoll(line, "input", 200, 5)  # the SND log's head and newest
    assert rc == 0, text
    assert values[200] << 16 | values[201] == 1  # one SND so far
    rc, values, text = await mbpoll(line, "input", 4, 4)  # the last SND: P1 -> P4 at N4
    assert rc == 0 and [values[4], values[5], values[6]] == [1, 4, 4], text


async def test_mbpoll_rtu_sees_the_exceptions(ncgate_gateway: Gateway,
                                              socat_pair: tuple[str, str]) -> None:
    rc, _, text = await mbpoll(rtu(socat_pair[1]), "holding", 600)
    assert rc != 0 and "Illegal data address" in text
    rc, _, text = await mbpoll(rtu(socat_pair[1]), "holding", 7, write=[300])
    assert rc != 0 and "Illegal data value" in text
    rc, _, text = await mbpoll(rtu(socat_pair[1]), "input", 0, unit=9)  # not ours: silence
    assert rc != 0 and "timed out" in text.lower()
    assert ncgate_gateway.image.k[7] == 0


@pytest.fixture
def rtu_tcp_pty(ncgate_gateway: Gateway, tmp_path: Path) -> Iterator[str]:
    """A pty that socat relays to the gateway's RTU-over-TCP port (a serial device server
    seen from the master's side)."""
    server = ncgate_gateway.adapters["modbus_rtu"].tcp
    host, port = server.address
    device = str(tmp_path / "ttyNET")
    proc = socat(f"pty,raw,echo=0,link={device}", f"tcp:{host}:{port}")
    yield device
    proc.terminate()
    proc.wait()


async def test_rtu_over_tcp_through_mbpoll_and_socat(ncgate_gateway: Gateway,
                                                     rtu_tcp_pty: str) -> None:
    gw = ncgate_gateway
    rc, values, text = await mbpoll(rtu(rtu_tcp_pty), "input", 0, 2)
    assert rc == 0 and (values[0], values[1]) == (1, 4), text
    assert (await mbpoll(rtu(rtu_tcp_pty), "holding", 1001, write=[1234]))[0] == 0
    assert gw.image.syvar[1] == 1234
    rc, values, _ = await mbpoll(tcp(gw), "holding", 1001)
    assert values[1001] == 1234
    status = gw.adapters["modbus_rtu"].status()
    (_, over_tcp) = status["ports"]
    assert over_tcp["answered"] == 2 and over_tcp["crc_errors"] == 0
    who = [e["who"] for e in gw.trace if e["event"] == "write"][-1]
    assert who.startswith("modbus-rtu 127.0.0.1:")
