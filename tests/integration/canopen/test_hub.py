"""A CANopen master in another process reaches the node through the gateway's loopback hub
(python-can-remote; `interface = "remote"`), on a machine without SocketCAN."""

from __future__ import annotations

import asyncio
import json
import signal
import sys

import can
import pytest

from ncgate.config import Config
from ncgate.gateway import Gateway

from .conftest import Master, u32

MASTER = """
import json, sys, canopen
network = canopen.Network()
network.NOTIFIER_CYCLE = 0.05
network.connect(interface="remote", channel=sys.argv[1], bitrate=500000)
node = canopen.RemoteNode(16, None)
network.add_node(node)
state = node.sdo.upload(0x2500, 1)[0]            # process 1 state
node.sdo.download(0x2000, 2, bytes([0b100]))      # SA byte 1 -> SA10 = 1
print(json.dumps({"state": state}), flush=True)
network.disconnect()
"""


@pytest.mark.parametrize("ncgate_config", [{"canopen.hub": True, "canopen.hub_port": 0}],
                         indirect=True)
async def test_master_in_a_child_process(gw: Gateway) -> None:
    node = gw.canopen_node
    assert node is not None and node.hub_address is not None
    host, port = node.hub_address
    await gw.start("MAIN")  # P1 waits at N2 for SA10 = 1
    await gw.wait_state(1, "WAIT_COND", timeout_s=5)
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", MASTER, f"ws://{host}:{port}/",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    async with asyncio.timeout(30):
        out, err = await proc.communicate()
    assert proc.returncode == 0, err.decode()
    assert json.loads(out) == {"state": 3}  # WAIT_COND, read across processes
    await gw.wait_state(1, "WAIT_PROC", timeout_s=5)  # SA10 released it; now waits for P4
    write = next(e for e in gw.trace if e["event"] == "write" and e["var"] == "SA1.BY")
    assert write["who"] == "canopen SDO 0x610"


async def test_plugin_master_fixture(ncgate_gateway: Gateway, canopen_master: object) -> None:
    from ncgate.gateway.testing.canopen_kit import CanopenMaster

    assert isinstance(canopen_master, CanopenMaster)
    canopen_master.nmt(0x01)
    assert await canopen_master.next_frame(0x190) == bytes(4)  # states on entering OPERATIONAL
    await ncgate_gateway.start("MAIN")
    await canopen_master.download(0x2000, 2, b"\x04")  # SA10 -> P1 goes on, sends to P4
    frame = await canopen_master.next_frame(0x290)
    assert frame[4:6] == b"\x01\x04"  # sender 1, target 4


async def test_plugin_master_syncs_and_beats(ncgate_gateway: Gateway,
                                             canopen_master: object) -> None:
    from ncgate.gateway.testing.canopen_kit import CanopenMaster

    assert isinstance(canopen_master, CanopenMaster)
    await canopen_master.download(0x1800, 1, (0xC0000190).to_bytes(4, "little"))
    await canopen_master.download(0x1800, 2, b"\x01")  # TPDO1 on every SYNC
    await canopen_master.download(0x1800, 1, (0x40000190).to_bytes(4, "little"))
    canopen_master.nmt(0x01)
    canopen_master.sync()
    assert await canopen_master.next_frame(0x190) == bytes(4)
    # the node watches node 1's heartbeat for 50 ms: one beat, then silence
    await canopen_master.download(0x1016, 1, (1 << 16 | 50).to_bytes(4, "little"))
    canopen_master.heartbeat(1)
    emcy = await canopen_master.next_frame(0x90)
    assert emcy[:3] == b"\x30\x81\x11"  # 0x8130 heartbeat error, register 0x11
    assert [e["code"] for e in ncgate_gateway.trace if e["event"] == "alarm"] == ["AL150"]


BEATING_MASTER = """
import sys, time, canopen
network = canopen.Network()
network.NOTIFIER_CYCLE = 0.05
network.connect(interface="remote", channel=sys.argv[1], bitrate=500000)
# The hub sends it: python-can-remote hands send_periodic to the server (periodic_start).
network.send_periodic(0x701, b"\\x05", 0.02)  # node 1's heartbeat, OPERATIONAL, every 20 ms
print("beating", flush=True)
time.sleep(60)
"""


@pytest.mark.parametrize("ncgate_config", [{"canopen.hub": True, "canopen.hub_port": 0,
                                            "canopen.heartbeat_ms": 2}], indirect=True)
async def test_a_killed_masters_heartbeat_ends_with_it_in_the_hub(gw: Gateway,
                                                                   master: Master) -> None:
    """The master's heartbeat is a periodic task in the hub, and the hub writes the bus's
    traffic (here the node's own heartbeat, every 2 ms) to it when it is killed: its session
    ends, the task with it, and the node sees the master lost within its consumer time."""
    node = gw.canopen_node
    assert node is not None and node.hub_address is not None
    host, port = node.hub_address
    beats = master.listen(0x701)
    emcy = master.listen(0x90)
    await master.download(0x1016, 1, u32(1 << 16 | 200))  # node 1's heartbeat, 200 ms
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-c", BEATING_MASTER, f"ws://{host}:{port}/",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
    try:
        assert proc.stdout is not None
        async with asyncio.timeout(30):
            assert await proc.stdout.readline() == b"beating\n"
        for _ in range(3):
            assert await master.next(0x701) == b"\x05"  # sent by the hub, for the master
        assert emcy.empty()
        # Hung, then killed: frames the hub wrote to it meanwhile are unread when it dies,
        # so the hub's next write fails (a killed master that was reading may not).
        proc.send_signal(signal.SIGSTOP)
        node_beats = master.frames[0x700 + master.node_id]
        while not node_beats.empty():
            node_beats.get_nowait()
        for _ in range(3):
            await master.next(0x700 + master.node_id)  # the hub writes these to it too
    finally:
        proc.kill()  # SIGKILL: no goodbye, no periodic_stop
        await proc.wait()
    frame = await master.next(0x90, timeout_s=5)  # 200 ms after its last heartbeat
    assert frame[:3] == b"\x30\x81\x11"  # EMCY 0x8130 heartbeat error, register 0x11
    assert [e["code"] for e in gw.trace if e["event"] == "alarm"] == ["AL150"]
    while not beats.empty():
        beats.get_nowait()
    await master.barrier()
    assert beats.empty()  # nobody beats for the dead master


@pytest.mark.parametrize("ncgate_config", [{"canopen.hub": True, "canopen.hub_port": 0}],
                         indirect=True)
async def test_a_masters_heartbeat_in_the_hub_ends_when_the_gateway_closes(
        master: Master, ncgate_config: Config) -> None:
    """The gateway closes under a master that lives on: what it asked the hub to send stops
    with the hub (its session's thread is a daemon that would otherwise send on)."""
    beats = master.listen(0x701)
    ticks = master.listen(0x702)

    async def ticks_from_now(count: int) -> None:
        while not ticks.empty():
            ticks.get_nowait()
        for _ in range(count):
            await master.next(0x702)

    ticker = can.Bus(interface="virtual", channel=ncgate_config.canopen.channel)
    tick = ticker.send_periodic(can.Message(arbitration_id=0x702, data=b"",
                                            is_extended_id=False), 0.02)
    try:
        async with Gateway(ncgate_config) as gw:
            node = gw.canopen_node
            assert node is not None and node.hub_address is not None
            host, port = node.hub_address
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-c", BEATING_MASTER, f"ws://{host}:{port}/",
                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
            try:
                assert proc.stdout is not None
                async with asyncio.timeout(30):
                    assert await proc.stdout.readline() == b"beating\n"
                assert await master.next(0x701) == b"\x05"
            except BaseException:
                proc.kill()
                await proc.wait()
                raise
        try:
            await ticks_from_now(2)  # a beat on its way as the hub closed
            while not beats.empty():
                beats.get_nowait()
            await ticks_from_now(10)  # 200 ms: ten of its beats, were it still beating
            assert beats.empty()
        finally:
            proc.kill()
            await proc.wait()
    finally:
        tick.stop()
        ticker.shutdown()


@pytest.mark.parametrize("ncgate_config", [{"canopen.hub": True, "canopen.hub_port": 0}],
                         indirect=True)
async def test_a_client_that_sends_half_a_request_is_let_go_and_says_one_line(
        ncgate_config: Config, master: Master, monkeypatch: pytest.MonkeyPatch,
        capfd: pytest.CaptureFixture[str]) -> None:
    """A hub client that sent half a request line held a thread reading it for ever, also
    after the gateway's close, and socketserver printed a traceback to stderr for each one
    when they went (296 of 300, a hostile try).  It has hub.HANDSHAKE_S for its handshake."""
    from ncgate.gateway.canopen import hub

    monkeypatch.setattr(hub, "HANDSHAKE_S", 0.3)
    async with Gateway(ncgate_config) as gw:
        node = gw.canopen_node
        assert node is not None and node.hub_address is not None
        half = []
        for _ in range(5):
            reader, writer = await asyncio.open_connection(*node.hub_address)
            writer.write(b"GET / HT")
            await writer.drain()
            half.append((reader, writer))
        for reader, writer in half:
            async with asyncio.timeout(10):
                assert await reader.read() == b""  # let go by the hub
            writer.close()
    assert "Traceback" not in capfd.readouterr().err
