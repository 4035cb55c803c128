"""The configuration schema (spec 4.2) and its TOML loader.

A config loads into frozen dataclasses.  Every value is validated on load; an unknown key or a
bad value raises :class:`ConfigError` naming the file and the dotted key, e.g.
``gateway.toml: modbus.port: expected an integer 1..65535, got 70000``.  Relative storage
paths are resolved against the config file's folder.

Stdlib only.
"""

from __future__ import annotations

import enum
import ipaddress
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from ncgate.errors import NcgateError

MAX_PROCESSES = 16


class ConfigError(NcgateError, ValueError):
    """A configuration that cannot be used: the message names the file and the dotted key."""


class SndPolicy(enum.Enum):
    RENDEZVOUS = "rendezvous"  # SND completes only when the target waits for the sender
    LATCHED = "latched"  # SND never blocks; a token per sender->target pair (TwinCAT-style)


@dataclass(frozen=True, slots=True)
class ProcessConfig:
    number: int
    external: bool = False


@dataclass(frozen=True, slots=True)
class StorageConfig:
    devices: Mapping[str, Path] = field(default_factory=dict)  # MP0..MP3 -> folder
    default: str = "MP0"


@dataclass(frozen=True, slots=True)
class NcConfig:
    processes: int = 5
    lookahead: int = 16
    snd: SndPolicy = SndPolicy.RENDEZVOUS
    sync_reads: bool = False
    time_scale: float = 1.0
    wait_timeout_s: float = 0.0
    rapid_mm_min: float = 10000.0
    tool_change_s: float = 2.0
    main: str = "PROG91"
    autostart: bool = False
    e_params: int = 1000
    stall_s: float = 60.0
    optional_skip: bool = False
    lazy_parse: bool = False  # start programs before they are parsed whole (spec 1.6: off)
    storage: StorageConfig = field(default_factory=StorageConfig)
    process: tuple[ProcessConfig, ...] = ()

    @property
    def external(self) -> frozenset[int]:
        return frozenset(p.number for p in self.process if p.external)


@dataclass(frozen=True, slots=True)
class PlcConfig:
    sa_bits: int = 1024
    k_bytes: int = 512
    syvars: int = 256
    scan_ms: int = 10


MAP_REGIONS = ("sa_bits", "k_bytes", "syvars", "sa_bytes", "command", "mailbox")


@dataclass(frozen=True, slots=True)
class ModbusMapConfig:
    """Where the movable regions of the map start, and which are read-only (spec 3.2)."""

    k_bytes: int = 0  # holding registers
    syvars: int = 1000
    sa_bytes: int = 1500
    command: int = 2000  # the SND mailbox follows at command+1, command+2
    status: int = 100  # input registers: the per-process status blocks
    read_only: frozenset[str] = frozenset()


@dataclass(frozen=True, slots=True)
class ModbusConfig:
    enabled: bool = True
    host: str = "127.0.0.1"
    port: int = 5020
    unit_ids: tuple[int, ...] = (1,)
    max_clients: int = 16
    idle_timeout_s: float = 60.0
    read_only: bool = False
    allow: tuple[str, ...] = ()  # client IP allow-list; empty: everyone
    map: ModbusMapConfig = field(default_factory=ModbusMapConfig)


@dataclass(frozen=True, slots=True)
class CanopenConfig:
    enabled: bool = True
    interface: str = "virtual"
    channel: str = "ncgate"
    bitrate: int = 500000
    node_id: int = 16
    nmt_autostart: bool = False
    heartbeat_ms: int = 1000
    # A python-can-remote hub on loopback, so that a master in another process can reach the
    # node on a machine without SocketCAN (`interface = "remote"`, channel ws://host:port/).
    hub: bool = False
    hub_host: str = "127.0.0.1"
    hub_port: int = 54701


@dataclass(frozen=True, slots=True)
class Config:
    nc: NcConfig = field(default_factory=NcConfig)
    plc: PlcConfig = field(default_factory=PlcConfig)
    modbus: ModbusConfig = field(default_factory=ModbusConfig)
    canopen: CanopenConfig = field(default_factory=CanopenConfig)
    source: Path | None = None  # the file it came from (None: built-in default)


def default_config_path() -> Path:
    return Path(str(resources.files("ncgate.config").joinpath("default.toml")))


def default_script_path() -> Path:
    """The PLC script of the built-in default (the manual's SA10 for PROG92's N40)."""
    return Path(str(resources.files("ncgate.config").joinpath("default_script.toml")))


def load_config(
    path: str | Path | None = None, overrides: Mapping[str, Any] | None = None
) -> Config:
    """Load a config file (None: the built-in default), then apply dotted-key overrides."""
    source = Path(path) if path is not None else default_config_path()
    raw = read_toml(source)
    for dotted, value in (overrides or {}).items():
        _set_dotted(raw, dotted, value)
    reader = _Reader(str(source) if path is not None else "<built-in default>", source.parent)
    return reader.config(raw, source if path is not None else None)


def read_toml(source: Path) -> dict[str, Any]:
    """A TOML file as a table; a missing or malformed file is a ConfigError naming it."""
    try:
        return tomllib.loads(source.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{source}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: {exc}") from exc


def _set_dotted(raw: dict[str, Any], dotted: str, value: Any) -> None:
    *parents, last = dotted.split(".")
    table = raw
    for name in parents:
        table = table.setdefault(name, {})
    table[last] = value


class _Reader:
    """Reads one table at a time, naming the dotted key of anything wrong."""

    def __init__(self, file: str, base: Path) -> None:
        self.file = file
        self.base = base

    def fail(self, key: str, message: str) -> ConfigError:
        return ConfigError(f"{self.file}: {key}: {message}")

    def table(self, raw: Any, key: str, known: set[str]) -> dict[str, Any]:
        if raw is None:
            return {}
        if not isinstance(raw, dict):
            raise self.fail(key, f"expected a table, got {raw!r}")
        for name in raw:
            if name not in known:
                raise self.fail(f"{key}.{name}" if key else name, "unknown key")
        return raw

    def int_(self, t: dict[str, Any], key: str, dotted: str, default: int, lo: int,
             hi: int | None = None) -> int:
        value = t.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < lo or (
            hi is not None and value > hi
        ):
            bounds = f"{lo}..{hi}" if hi is not None else f">= {lo}"
            raise self.fail(dotted, f"expected an integer {bounds}, got {value!r}")
        return value

    def float_(self, t: dict[str, Any], key: str, dotted: str, default: float, lo: float,
               positive: bool = False) -> float:
        value = t.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float) or value < lo or (
            positive and value <= 0
        ):
            what = "a number > 0" if positive else f"a number >= {lo:g}"
            raise self.fail(dotted, f"expected {what}, got {value!r}")
        return float(value)

    def bool_(self, t: dict[str, Any], key: str, dotted: str, default: bool) -> bool:
        value = t.get(key, default)
        if not isinstance(value, bool):
            raise self.fail(dotted, f"expected true or false, got {value!r}")
        return value

    def str_(self, t: dict[str, Any], key: str, dotted: str, default: str) -> str:
        value = t.get(key, default)
        if not isinstance(value, str) or not value:
            raise self.fail(dotted, f"expected a non-empty string, got {value!r}")
        return value

    # -- sections -----------------------------------------------------------------------------

    def config(self, raw: dict[str, Any], source: Path | None) -> Config:
        top = self.table(raw, "", {"nc", "plc", "modbus", "canopen"})
        nc, plc = self.nc(top.get("nc")), self.plc(top.get("plc"))
        canopen = self.canopen(top.get("canopen"))
        if canopen.enabled:
            # The dictionary's shape (spec 3.3): 0x2000 is one ARRAY of at most 254 entries,
            # 0x2100+j (128 K bytes each) must stay below 0x2200.
            if plc.sa_bits > 254 * 8:
                raise self.fail("plc.sa_bits", f"the CANopen object 0x2000 holds at most 254 "
                                f"SA bytes (2032 bits), got {plc.sa_bits} bits; lower it or "
                                "set canopen.enabled = false")
            if plc.k_bytes > 128 * 256:
                raise self.fail("plc.k_bytes", "the CANopen objects 0x2100..0x21FF hold at "
                                f"most 32768 K bytes, got {plc.k_bytes}")
        return Config(
            nc=nc,
            plc=plc,
            modbus=self.modbus(top.get("modbus"), nc, plc),
            canopen=canopen,
            source=source,
        )

    def nc(self, raw: Any) -> NcConfig:
        d = NcConfig()
        t = self.table(raw, "nc", {
            "processes", "lookahead", "snd", "sync_reads", "time_scale", "wait_timeout_s",
            "rapid_mm_min", "tool_change_s", "main", "autostart", "e_params", "stall_s",
            "optional_skip", "lazy_parse", "storage", "process",
        })
        processes = self.int_(t, "processes", "nc.processes", d.processes, 1, MAX_PROCESSES)
        snd_raw = t.get("snd", d.snd.value)
        try:
            snd = SndPolicy(snd_raw)
        except ValueError:
            raise self.fail(
                "nc.snd", f'expected "rendezvous" or "latched", got {snd_raw!r}'
            ) from None
        return NcConfig(
            processes=processes,
            lookahead=self.int_(t, "lookahead", "nc.lookahead", d.lookahead, 0, 100_000),
            snd=snd,
            sync_reads=self.bool_(t, "sync_reads", "nc.sync_reads", d.sync_reads),
            time_scale=self.float_(t, "time_scale", "nc.time_scale", d.time_scale, 0,
                                   positive=True),
            wait_timeout_s=self.float_(t, "wait_timeout_s", "nc.wait_timeout_s",
                                       d.wait_timeout_s, 0),
            rapid_mm_min=self.float_(t, "rapid_mm_min", "nc.rapid_mm_min", d.rapid_mm_min, 0,
                                     positive=True),
            tool_change_s=self.float_(t, "tool_change_s", "nc.tool_change_s",
                                      d.tool_change_s, 0),
            main=self.str_(t, "main", "nc.main", d.main),
            autostart=self.bool_(t, "autostart", "nc.autostart", d.autostart),
            e_params=self.int_(t, "e_params", "nc.e_params", d.e_params, 1, 100_000),
            stall_s=self.float_(t, "stall_s", "nc.stall_s", d.stall_s, 0, positive=True),
            optional_skip=self.bool_(t, "optional_skip", "nc.optional_skip", d.optional_skip),
            lazy_parse=self.bool_(t, "lazy_parse", "nc.lazy_parse", d.lazy_parse),
            storage=self.storage(t.get("storage")),
            process=self.processes(t.get("process"), processes),
        )

    def storage(self, raw: Any) -> StorageConfig:
        t = self.table(raw, "nc.storage", {"MP0", "MP1", "MP2", "MP3", "default"})
        devices: dict[str, Path] = {}
        for name in ("MP0", "MP1", "MP2", "MP3"):
            if name in t:
                folder = self.str_(t, name, f"nc.storage.{name}", "")
                devices[name] = (self.base / folder).resolve()
        if not devices:
            devices["MP0"] = self.base.resolve()
        default = self.str_(t, "default", "nc.storage.default", next(iter(devices)))
        if default.upper() not in devices:
            raise self.fail("nc.storage.default",
                            f"names {default!r}, which is not one of {', '.join(devices)}")
        return StorageConfig(devices=devices, default=default.upper())

    def processes(self, raw: Any, count: int) -> tuple[ProcessConfig, ...]:
        if raw is None:
            return ()
        if not isinstance(raw, list):
            raise self.fail("nc.process", "expected an array of tables ([[nc.process]])")
        out: dict[int, ProcessConfig] = {}
        for i, entry in enumerate(raw):
            key = f"nc.process[{i}]"
            t = self.table(entry, key, {"number", "external"})
            if "number" not in t:
                raise self.fail(f"{key}.number", "missing")
            number = self.int_(t, "number", f"{key}.number", 0, 1, count)
            if number in out:
                raise self.fail(f"{key}.number", f"process {number} is configured twice")
            if number == 1 and t.get("external"):
                raise self.fail(f"{key}.external", "process 1 runs the main program: "
                                "it cannot be external")
            out[number] = ProcessConfig(number, self.bool_(t, "external", f"{key}.external",
                                                           False))
        return tuple(out[n] for n in sorted(out))

    def plc(self, raw: Any) -> PlcConfig:
        d = PlcConfig()
        t = self.table(raw, "plc", {"sa_bits", "k_bytes", "syvars", "scan_ms"})
        sa_bits = self.int_(t, "sa_bits", "plc.sa_bits", d.sa_bits, 8, 65536)
        if sa_bits % 8:
            raise self.fail("plc.sa_bits", f"expected a multiple of 8, got {sa_bits}")
        return PlcConfig(
            sa_bits=sa_bits,
            k_bytes=self.int_(t, "k_bytes", "plc.k_bytes", d.k_bytes, 2, 65536),
            syvars=self.int_(t, "syvars", "plc.syvars", d.syvars, 1, 32768),
            scan_ms=self.int_(t, "scan_ms", "plc.scan_ms", d.scan_ms, 1, 60_000),
        )

    def modbus_map(self, raw: Any, nc: NcConfig, plc: PlcConfig) -> ModbusMapConfig:
        d = ModbusMapConfig()
        t = self.table(raw, "modbus.map", {"k_bytes", "syvars", "sa_bytes", "command",
                                           "status", "read_only"})
        bases = {name: self.int_(t, name, f"modbus.map.{name}", getattr(d, name), 0, 65535)
                 for name in ("k_bytes", "syvars", "sa_bytes", "command", "status")}
        read_only = t.get("read_only", [])
        if not isinstance(read_only, list) or any(r not in MAP_REGIONS for r in read_only):
            raise self.fail("modbus.map.read_only",
                            f"expected a list of {', '.join(MAP_REGIONS)}, got {read_only!r}")
        holding = [("k_bytes", bases["k_bytes"], plc.k_bytes),
                   ("syvars", bases["syvars"], plc.syvars),
                   ("sa_bytes", bases["sa_bytes"], plc.sa_bits // 8),
                   ("command", bases["command"], 3)]
        status = [("status", bases["status"], 20 * nc.processes), ("info", 0, 8)]
        for regions in (holding, status):
            for i, (name, start, count) in enumerate(regions):
                if start + count > 65536:
                    raise self.fail(f"modbus.map.{name}", f"{start}..{start + count - 1} runs "
                                    "past address 65535")
                for other, o_start, o_count in regions[i + 1:]:
                    if start < o_start + o_count and o_start < start + count:
                        raise self.fail(f"modbus.map.{name}",
                                        f"{name} ({start}..{start + count - 1}) overlaps "
                                        f"{other} ({o_start}..{o_start + o_count - 1})")
        return ModbusMapConfig(**bases, read_only=frozenset(read_only))

    def modbus(self, raw: Any, nc: NcConfig, plc: PlcConfig) -> ModbusConfig:
        d = ModbusConfig()
        t = self.table(raw, "modbus", {"enabled", "host", "port", "unit_ids", "max_clients",
                                       "idle_timeout_s", "read_only", "allow", "map"})
        unit_ids = t.get("unit_ids", list(d.unit_ids))
        if not isinstance(unit_ids, list) or not unit_ids or not all(
            isinstance(u, int) and not isinstance(u, bool) and 0 <= u <= 255 for u in unit_ids
        ):
            raise self.fail("modbus.unit_ids",
                            f"expected a non-empty list of integers 0..255, got {unit_ids!r}")
        allow = t.get("allow", [])
        if not isinstance(allow, list) or not all(isinstance(a, str) for a in allow):
            raise self.fail("modbus.allow", f"expected a list of IP addresses, got {allow!r}")
        for i, entry in enumerate(allow):
            try:
                ipaddress.ip_network(entry, strict=False)
            except ValueError:
                raise self.fail(f"modbus.allow[{i}]",
                                f"expected an IP address or network, got {entry!r}") from None
        return ModbusConfig(
            enabled=self.bool_(t, "enabled", "modbus.enabled", d.enabled),
            host=self.str_(t, "host", "modbus.host", d.host),
            # 0 asks the system for a free port (tests, the Python API); not shown as a bound.
            port=0 if t.get("port") == 0 and not isinstance(t.get("port"), bool)
            else self.int_(t, "port", "modbus.port", d.port, 1, 65535),
            unit_ids=tuple(unit_ids),
            max_clients=self.int_(t, "max_clients", "modbus.max_clients", d.max_clients, 1,
                                  10_000),
            idle_timeout_s=self.float_(t, "idle_timeout_s", "modbus.idle_timeout_s",
                                       d.idle_timeout_s, 0, positive=True),
            read_only=self.bool_(t, "read_only", "modbus.read_only", d.read_only),
            allow=tuple(allow),
            map=self.modbus_map(t.get("map"), nc, plc),
        )

    def canopen(self, raw: Any) -> CanopenConfig:
        d = CanopenConfig()
        t = self.table(raw, "canopen", {"enabled", "interface", "channel", "bitrate",
                                        "node_id", "nmt_autostart", "heartbeat_ms", "hub",
                                        "hub_host", "hub_port"})
        return CanopenConfig(
            enabled=self.bool_(t, "enabled", "canopen.enabled", d.enabled),
            interface=self.str_(t, "interface", "canopen.interface", d.interface),
            channel=self.str_(t, "channel", "canopen.channel", d.channel),
            bitrate=self.int_(t, "bitrate", "canopen.bitrate", d.bitrate, 10_000, 1_000_000),
            node_id=self.int_(t, "node_id", "canopen.node_id", d.node_id, 1, 127),
            nmt_autostart=self.bool_(t, "nmt_autostart", "canopen.nmt_autostart",
                                     d.nmt_autostart),
            heartbeat_ms=self.int_(t, "heartbeat_ms", "canopen.heartbeat_ms", d.heartbeat_ms, 0,
                                   65535),
            hub=self.bool_(t, "hub", "canopen.hub", d.hub),
            hub_host=self.str_(t, "hub_host", "canopen.hub_host", d.hub_host),
            hub_port=self.int_(t, "hub_port", "canopen.hub_port", d.hub_port, 0, 65535),
        )
