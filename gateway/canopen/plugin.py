"""The CANopen node as a gateway adapter (``ncgate.gateway.adapters``).  Light: the node,
canopen and python-can are imported only when it is built."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ncgate.gateway.adapters import AdapterPlugin

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.canopen.node import CanopenNode
    from ncgate.gateway.canopen.pdo import Pdos
    from ncgate.gateway.plant import ActiveFault


def _factory(gw: Gateway) -> CanopenNode:
    from ncgate.gateway.canopen.node import CanopenNode

    return CanopenNode(gw.config, gw, gw.canopen_clock)


def status(node: CanopenNode) -> dict[str, Any]:
    heartbeats = node.heartbeats
    return {
        "node_id": node.node_id,
        "nmt": node.node.nmt.state,  # its name, e.g. "PRE-OPERATIONAL"
        "heartbeat_ms": node.config.canopen.heartbeat_ms,
        "faults": node.faults(),  # the plant's CANopen faults in force (docs/plant.md)
        "masters_lost": list(heartbeats.lost_nodes) if heartbeats is not None else [],
        "sync": sync_status(node.pdos),
    }


def sync_status(pdos: Pdos) -> dict[str, Any]:
    """How the node kept up with the SYNC: the SYNCs it answered with TPDOs, the longest
    time from a SYNC's arrival to its TPDOs sent and how many took longer than each bound,
    the synchronous TPDOs it dropped (their SYNC handled too late) and the synchronous
    RPDOs that came outside the window (0x1007)."""
    from ncgate.gateway.canopen.pdo import SYNC_LATENCY_BOUNDS

    return {
        "answered": pdos.sync_answered,
        "latency_max_ms": round(pdos.sync_latency_max * 1000, 3),
        "later_than_ms": {f"{bound * 1000:g}": n for bound, n
                          in zip(SYNC_LATENCY_BOUNDS, pdos.sync_latency_over, strict=True)},
        "tpdos_dropped": pdos.sync_dropped,
        "rpdos_late": pdos.sync_late_rpdos,
    }


def describe(node: CanopenNode) -> list[str]:
    canopen = node.config.canopen
    line = (f"CANopen node {node.node_id} on {canopen.interface} channel {canopen.channel}")
    if node.hub_address is not None:
        line += f", hub on {node.hub_address[0]}:{node.hub_address[1]}"
    return [line]


def faults(node: CanopenNode, faults: list[ActiveFault]) -> None:
    """The plant's CANopen faults in force, on the node."""
    kinds = {f.kind: f for f in faults if f.target == "canopen"}
    emcy = kinds.get("emcy")
    node.set_faults("heartbeat_stop" in kinds, "pdo_stop" in kinds,
                    None if emcy is None else int(emcy.params["code"]))


PLUGIN = AdapterPlugin(enabled=lambda gw: gw.config.canopen.enabled, factory=_factory,
                       status=status, describe=describe, faults=faults,
                       fault_target="canopen")
