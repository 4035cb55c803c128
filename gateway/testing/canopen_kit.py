"""A CANopen master on the gateway's bus, for integration tests (spec 4.5).

    master = CanopenMaster(config)            # same interface/channel as the node
    value = await master.upload(0x2500, 1)    # process 1 state
    await master.download(0x2000, 2, b"\\x04") # SA byte 1 -> SA10
    frame = await master.next_frame(0x290)    # the next TPDO2 (an SND)
    master.sync()                             # synchronous PDOs
    master.heartbeat(1)                       # the master's heartbeat, if 0x1016 watches it
    master.close()

canopen's SDO client blocks, and the node answers from the asyncio loop that runs your test:
the async helpers call it from a worker thread.  Frames are queued as they arrive and awaited
with a timeout.
"""

from __future__ import annotations

import asyncio
import queue

import canopen

from ncgate.config import Config
from ncgate.gateway.canopen.dictionary import build_dictionary


class CanopenMaster:
    def __init__(self, config: Config, listen: tuple[int, ...] = ()) -> None:
        cfg = config.canopen
        self.node_id = cfg.node_id
        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = 0.05
        channel = f"ws://{cfg.hub_host}:{cfg.hub_port}/" if cfg.interface == "remote" \
            else cfg.channel
        self.network.connect(interface=cfg.interface, channel=channel, bitrate=cfg.bitrate)
        self.node = canopen.RemoteNode(cfg.node_id, build_dictionary(config))
        self.network.add_node(self.node)
        self._queues: dict[int, queue.Queue[bytes]] = {}
        for cob_id in listen:
            self.listen(cob_id)

    def listen(self, cob_id: int) -> None:
        """Queue every frame on this COB-ID from now on."""
        q: queue.Queue[bytes] = queue.Queue()
        self.network.subscribe(cob_id, lambda can_id, data, ts: q.put(bytes(data)))
        self._queues[cob_id] = q

    async def next_frame(self, cob_id: int, timeout_s: float = 5.0) -> bytes:
        return await asyncio.to_thread(self._queues[cob_id].get, True, timeout_s)

    async def upload(self, index: int, subindex: int) -> bytes:
        return await asyncio.to_thread(self.node.sdo.upload, index, subindex)

    async def download(self, index: int, subindex: int, data: bytes) -> None:
        await asyncio.to_thread(self.node.sdo.download, index, subindex, data)

    def nmt(self, command: int) -> None:
        """NMT: 0x01 start, 0x02 stop, 0x80 pre-operational, 0x81/0x82 resets."""
        self.network.send_message(0, bytes((command, self.node_id)))

    def sync(self, counter: int | None = None, cob_id: int = 0x80) -> None:
        """A SYNC (with the counter byte if given): synchronous TPDOs answer, synchronous
        RPDOs take effect."""
        self.network.send_message(cob_id, b"" if counter is None else bytes((counter,)))

    def heartbeat(self, node_id: int = 1, state: int = 0x05) -> None:
        """One heartbeat of the master (node ``node_id``, OPERATIONAL), for a node that
        watches it through 0x1016."""
        self.network.send_message(0x700 + node_id, bytes((state,)))

    def close(self) -> None:
        self.network.disconnect()
