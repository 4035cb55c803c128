"""The heartbeat consumer (CiA 301 7.2.8.3.2.2, object 0x1016): the node watches the heartbeat
of up to four nodes -- in practice the master's -- and says when one stops.

Each entry of 0x1016 is ``node id << 16 | time in ms`` (0 in either: unused).  Watching starts
with the first heartbeat after the entry is written; a boot-up message (state 0) stops it
until the next heartbeat (the node restarted and says so itself).  When no heartbeat came for
the entry's time, ``lost(node_id, ms)`` is called once; the next heartbeat calls
``back(node_id)``.  Both run on the loop.

Frames arrive on python-can's receive thread; the deadline is a timer on the node's clock
(one per watched node, moved on by each heartbeat rather than re-armed for each).
"""

from __future__ import annotations

import functools
from collections.abc import Callable

from canopen.sdo.exceptions import SdoAbortedError

from ncgate.gateway.canopen.clock import Clock, Timer
from ncgate.gateway.canopen.codes import (
    ABORT_PARAMETER_INCOMPATIBLE,
)


def entry(value: int) -> tuple[int, int] | None:
    """(node id, ms) of a 0x1016 entry, or None when it is unused."""
    node_id, ms = value >> 16 & 0xFF, value & 0xFFFF
    return (node_id, ms) if node_id and ms and node_id <= 127 else None


def check_entries(entries: list[int]) -> None:
    """CiA 301: two used entries for the same node are refused (0x06040043)."""
    nodes = [e[0] for e in map(entry, entries) if e is not None]
    if len(nodes) != len(set(nodes)):
        raise SdoAbortedError(ABORT_PARAMETER_INCOMPATIBLE)


class _Watch:
    def __init__(self, node_id: int, ms: int) -> None:
        self.node_id, self.ms = node_id, ms
        self.active = False  # a heartbeat came since the entry was written or a boot-up
        self.lost = False
        self.last = 0.0
        self.timer: Timer | None = None


class HeartbeatConsumer:
    def __init__(self, clock: Clock,
                 subscribe: Callable[[int, Callable[[int, bytearray, float], None]], None],
                 unsubscribe: Callable[[int, Callable[[int, bytearray, float], None]], None],
                 call_soon: Callable[[Callable[[], None]], None],
                 lost: Callable[[int, int], None], back: Callable[[int], None]) -> None:
        self.clock = clock
        self._subscribe, self._unsubscribe, self._call_soon = subscribe, unsubscribe, call_soon
        self._lost, self._back = lost, back
        self._watches: dict[int, _Watch] = {}  # by node id

    def configure(self, entries: list[int]) -> None:
        """Watch what 0x1016 says now (receive thread: after a write, a reset, at start).
        A node that was lost and is no longer watched comes back (its alarm clears)."""
        wanted = dict(e for e in map(entry, entries) if e is not None)
        for node_id, watch in list(self._watches.items()):
            if wanted.get(node_id) != watch.ms:
                self._stop(watch)
                self._unsubscribe(0x700 + node_id, self._on_frame)
                del self._watches[node_id]
                if watch.lost:
                    self._call_soon(functools.partial(self._back, node_id))
        for node_id, ms in wanted.items():
            if node_id not in self._watches:
                self._watches[node_id] = _Watch(node_id, ms)
                self._subscribe(0x700 + node_id, self._on_frame)

    def close(self) -> None:
        for watch in self._watches.values():
            self._stop(watch)

    @property
    def lost_nodes(self) -> list[int]:
        return [w.node_id for w in self._watches.values() if w.lost]

    def _stop(self, watch: _Watch) -> None:
        watch.active = False
        if watch.timer is not None:
            watch.timer.cancel()
            watch.timer = None

    def _on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        watch = self._watches.get(can_id - 0x700)
        if watch is None or not data:
            return
        if data[0] & 0x7F == 0:  # boot-up: it restarted; watch again from its next heartbeat
            self._stop(watch)
            return
        watch.last = self.clock.monotonic()
        if watch.lost:
            watch.lost = False
            self._call_soon(lambda: self._back(watch.node_id))
        if not watch.active:
            watch.active = True
            watch.timer = self.clock.call_later(watch.ms / 1000, lambda: self._due(watch))

    def _due(self, watch: _Watch) -> None:
        """The deadline as armed: if a heartbeat came since, the deadline moves on."""
        watch.timer = None
        if not watch.active:
            return
        left = watch.last + watch.ms / 1000 - self.clock.monotonic()
        if left > 1e-9:
            watch.timer = self.clock.call_later(left, lambda: self._due(watch))
            return
        watch.active = False
        watch.lost = True
        self._lost(watch.node_id, watch.ms)
