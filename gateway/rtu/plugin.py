"""Modbus RTU as a gateway adapter (``ncgate.gateway.adapters``): on when ``[modbus.rtu]
port`` or ``[modbus.rtu_tcp] port`` is set.  Light: pyserial and the server are imported only
when it is built."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ncgate.gateway.adapters import AdapterPlugin

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.plant import ActiveFault
    from ncgate.gateway.rtu.server import RtuServer


def _enabled(gw: Gateway) -> bool:
    modbus = gw.config.modbus
    return modbus.rtu.port is not None or modbus.rtu_tcp.port is not None


def _factory(gw: Gateway) -> RtuServer:
    from ncgate.gateway.rtu.server import RtuServer

    return RtuServer(gw.config.modbus, gw.map, gw)


def status(server: RtuServer) -> dict[str, Any]:
    return server.status()


def describe(server: RtuServer) -> list[str]:
    units = ",".join(map(str, sorted(server.unit_ids)))
    lines = []
    if server.serial is not None:
        rtu = server.config.rtu
        lines.append(f"Modbus RTU on {server.serial.device} ({rtu.baudrate} bit/s, "
                     f"{rtu.bytesize}{rtu.parity.value}{rtu.stopbits}), unit ids {units}")
    if server.tcp is not None and server.tcp.address is not None:
        host, port = server.tcp.address
        lines.append(f"Modbus RTU over TCP on {host}:{port}, unit ids {units}")
    return lines


def faults(server: RtuServer, faults: list[ActiveFault]) -> None:
    """The plant's Modbus faults (target ``modbus``) apply to the RTU lines too."""
    from ncgate.gateway.modbus.plugin import fault_rows

    server.set_faults(fault_rows(faults))


PLUGIN = AdapterPlugin(enabled=_enabled, factory=_factory, status=status, describe=describe,
                       faults=faults,
                       fault_target="modbus")
