"""A CANopen master in another process reaches the node through the gateway's loopback hub
(python-can-remote; `interface = "remote"`), on a machine without SocketCAN."""

from __future__ import annotations

import asyncio
import json
import sys

import pytest

from ncgate.gateway import Gateway

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
