"""The Modbus TCP server as a gateway adapter (``ncgate.gateway.adapters``).  Light: the
server and pymodbus are imported only when it is built."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ncgate.gateway.adapters import AdapterPlugin

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.modbus.faults import ModbusFault
    from ncgate.gateway.modbus.server import ModbusServer
    from ncgate.gateway.plant import ActiveFault


def _factory(gw: Gateway) -> ModbusServer:
    from ncgate.gateway.modbus.server import ModbusServer

    return ModbusServer(gw.config.modbus, gw.map, gw)


def status(server: ModbusServer) -> dict[str, Any]:
    from ncgate.gateway.modbus.faults import row_status

    return {
        "address": list(server.address) if server.address else None,
        "tls_address": list(server.tls_address) if server.tls_address else None,
        "clients": sorted(c.source.peer or c.source.detail for c in server.connections),
        "max_clients": server.config.max_clients,
        # The plant's Modbus faults in force and what they did (docs/plant.md).
        "faults": [row_status(f) for f in server.faults],
        "fault_counts": server.fault_counts,
    }


def describe(server: ModbusServer) -> list[str]:
    config = server.config
    units = ",".join(map(str, config.unit_ids))
    lines = []
    if server.address is not None:
        host, port = server.address
        lines.append(f"Modbus TCP on {host}:{port}, unit ids {units}, at most "
                     f"{config.max_clients} clients")
    if server.tls_address is not None:
        host, port = server.tls_address
        lines.append(f"Modbus/TCP Security (TLS) on {host}:{port}, roles "
                     f"{', '.join(config.roles) or 'none'}")
    return lines


def fault_rows(faults: list[ActiveFault]) -> list[ModbusFault]:
    """The plant's Modbus faults in force (target ``modbus``) as fault-table rows: the TCP
    server's and the RTU lines' (ncgate.gateway.rtu)."""
    from ncgate.gateway.modbus.faults import ModbusFault

    return [ModbusFault(f.kind, code=int(f.params.get("code", 6)),  # type: ignore[arg-type]
                        ms=float(f.params.get("ms", 0.0)), unit=f.params.get("unit"),
                        addresses=f.params.get("addresses"))
            for f in faults if f.target == "modbus"]


def faults(server: ModbusServer, faults: list[ActiveFault]) -> None:
    """The plant's Modbus faults in force, as the server's fault table."""
    server.set_faults(fault_rows(faults))


PLUGIN = AdapterPlugin(enabled=lambda gw: gw.config.modbus.enabled, factory=_factory,
                       status=status, describe=describe, faults=faults,
                       fault_target="modbus")
