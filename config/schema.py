"""The configuration schema (spec 4.2): frozen dataclasses, one a TOML table.

The dataclasses are the schema: each key is a field made with :func:`setting`, which carries
its bounds and its one-line doc, or its own key reader (``parse=``: a function of the
reader, the table, the dotted key and the keys read so far).  The reader
(:mod:`ncgate.config.reader`) walks the fields, so a key is spelled once -- in its dataclass
-- and the table of keys in ``docs/config.md`` is generated from the same fields
(:func:`config_markdown`; a test keeps it in sync).  What spans keys is checked after
(:mod:`ncgate.config.checks`).

Stdlib only, and the interpreter's leaf module of settings (the SND policy is defined there).
"""

from __future__ import annotations

import csv
import dataclasses
import enum
import ipaddress
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from ncgate.config.plant import FaultConfig, PlantModelConfig, read_faults, read_models
from ncgate.errors import NcgateError
from ncgate.interpreter.settings import (
    AUX_NC_CODES,
    AXES,
    BLOCK_S,
    TRAVEL_MM,
    AuxSettings,
    BlockSearchSync,
    Dialect,
    Handshake,
    SndPolicy,
)

if TYPE_CHECKING:
    from ncgate.config.reader import _Reader

MAX_PROCESSES = 16
STORAGE_DEVICES = ("MP0", "MP1", "MP2", "MP3")
DEFAULT_MODBUS_PORT = 5020
DEFAULT_TLS_PORT = 802  # mbaps, Modbus/TCP Security
DEFAULT_WEB_PORT = 8080  # the console's port when web.port is not set
MAP_REGIONS = ("sa_bits", "k_bytes", "syvars", "sa_bytes", "command", "mailbox", "overrides",
               "force")


BUILT_IN = "<built-in default>"  # the name of the built-in config in messages


class ConfigError(NcgateError, ValueError):
    """A configuration that cannot be used: the message names the file and the dotted key."""


# A custom reader of one key: (reader, the table, the dotted key, the values read so far in
# this table) -> the value.
Parse = Callable[["_Reader", dict[str, Any], str, dict[str, Any]], Any]


def setting(default: Any = None, doc: str = "", *, lo: float | None = None,
            hi: float | None = None, positive: bool = False, parse: Parse | None = None,
            factory: Callable[[], Any] | None = None) -> Any:
    """A config key: its default, its doc line, its bounds (or a parser of its own)."""
    metadata = {"doc": doc, "lo": lo, "hi": hi, "positive": positive, "parse": parse}
    if factory is not None:
        return field(default_factory=factory, metadata=metadata)
    return field(default=default, metadata=metadata)


# ---- custom keys ---------------------------------------------------------------------------


def _storage_devices(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    base = key.rsplit(".", 1)[0]
    devices: dict[str, Path] = {}
    for name in STORAGE_DEVICES:
        if name in t:
            devices[name] = r.folder(f"{base}.{name}", t[name])
    return devices or {"MP0": r.base.resolve()}


def _storage_default(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> str:
    devices = done["devices"]
    default = r.str_(t.get("default", next(iter(devices))), key)
    if default.upper() not in devices:
        raise r.fail(key, f"names {default!r}, which is not one of {', '.join(devices)}")
    return default.upper()


def _processes(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw, count = t.get("process"), done["processes"]
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise r.fail(key, "expected an array of tables ([[nc.process]])")
    out: dict[int, ProcessConfig] = {}
    for i, entry in enumerate(raw):
        item = f"{key}[{i}]"
        if isinstance(entry, dict) and "number" not in entry:
            raise r.fail(f"{item}.number", "missing")
        process = r.section(ProcessConfig, entry, item, hi={"number": count})
        if process.number in out:
            raise r.fail(f"{item}.number", f"process {process.number} is configured twice")
        if process.number == 1 and process.external:
            raise r.fail(f"{item}.external", "process 1 runs the main program: it cannot be "
                         "external")
        if process.external and process.main:
            raise r.fail(f"{item}.main", "an external process runs no part program")
        if process.number == 1 and process.main:
            raise r.fail(f"{item}.main", "process 1's is nc.main")
        out[process.number] = process
    return tuple(out[n] for n in sorted(out))


def _image_input(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> str:
    """An image variable named by a key (SA100, SK3, SYVAR5, SA2.BY): '' when not given."""
    name = key.rpartition(".")[2]
    if name not in t:
        return ""
    text = r.str_(t[name], key)
    if _VE_MAP.match(text) is None:
        raise r.fail(key, f"expected SA<n>, SA<n>.BY, SK<n>, SK<n>.IN or SYVAR<n>, got {text!r}")
    return text.upper()


_SYMBOL = re.compile(r"[A-Za-z_][A-Za-z0-9_]*$")


def _symbols_file(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    if "symbols_file" not in t:
        return None
    return r.existing_file(key, r.path_name(t["symbols_file"], key))


def _io_list(r: _Reader, path: Path, key: str) -> list[tuple[str, str, Any]]:
    """The rows of a CSV I/O list (docs/decisions.md): a header naming the columns ``name``,
    ``var`` and optionally ``comment``, comma- or semicolon-separated, as PLC tools export
    them; as (what names the row in an error, the name, {var})."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise r.fail(key, f"{path}: {exc}") from None
    lines = text.splitlines()
    header = lines[0] if lines else ""
    delimiter = ";" if header.count(";") > header.count(",") else ","
    rows = csv.reader(lines, delimiter=delimiter)
    columns = [c.strip().lower() for c in next(rows, [])]
    if "name" not in columns or "var" not in columns or not set(columns) <= {
            "name", "var", "comment"}:
        raise r.fail(key, f"{path}:1: expected a header of name, var and (optionally) comment, "
                     f"got {header!r}")
    twice = sorted({c for c in columns if columns.count(c) > 1})
    if twice:  # which of the two would a row mean?
        raise r.fail(key, f"{path}:1: the header names {twice[0]} twice: {header!r}")
    out = []
    for number, row in enumerate(rows, 2):
        if not any(cell.strip() for cell in row):
            continue
        if len(row) != len(columns):
            raise r.fail(key, f"{path}:{number}: expected {len(columns)} columns, got "
                         f"{len(row)}")
        cells = dict(zip(columns, (cell.strip() for cell in row), strict=True))
        out.append((f"{key} ({path.name}:{number}) {cells['name']}", cells["name"],
                    {"var": cells["var"], "comment": cells.get("comment", "")}))
    return out


class Symbols(dict[str, str]):
    """The I/O names (``[symbols]`` and ``symbols_file``): name -> image variable, with each
    name's comment, if it has one, in ``comments`` (``ncgate map`` shows them)."""

    def __init__(self) -> None:
        super().__init__()
        self.comments: dict[str, str] = {}


def _symbols(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw = t.get("symbols", {})
    if not isinstance(raw, dict):
        raise r.fail(key, "expected a table of NAME = \"SA10\"")
    out = Symbols()
    seen: dict[str, str] = {}
    entries: list[tuple[str, str, Any]] = []
    if done.get("symbols_file") is not None:
        entries += _io_list(r, done["symbols_file"], "symbols_file")
    entries += [(f"{key}.{name}", name, entry) for name, entry in raw.items()]
    for item, name, entry in entries:
        if isinstance(entry, dict):
            unknown = set(entry) - {"var", "comment"}
            if unknown:
                raise r.fail(f"{item}.{sorted(unknown)[0]}", "unknown key (var, comment)")
            comment = entry.get("comment", "")
            if not isinstance(comment, str):
                raise r.fail(f"{item}.comment", f"expected a text, got {comment!r}")
            if comment.strip():
                out.comments[name] = comment.strip()
            entry = entry.get("var")
        if not isinstance(entry, str) or _VE_MAP.match(entry) is None:
            raise r.fail(item, f"expected an image variable (SA10, SA2.BY, SK3, SK4.IN, "
                         f"SYVAR5), got {entry!r}")
        if not _SYMBOL.match(name) or _VE_MAP.match(name) or re.fullmatch(
                r"(SA|SK|K|SYVAR|E)\d.*", name, re.IGNORECASE):
            raise r.fail(item, "a name is letters, digits and _, and not an image variable's "
                         "own (SA10, K3, SYVAR5, E1)")
        if name.upper() in seen:
            raise r.fail(item, f"{name!r} is {seen[name.upper()]!r} already (names are not "
                         "case-sensitive)")
        if _outside_image(entry, done["plc"]):
            raise r.fail(item, f"{entry} is outside the image (plc.sa_bits, plc.k_bytes, "
                         "plc.syvars)")
        seen[name.upper()] = name
        out[name] = entry.upper()
    return out


def _process_main(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> str:
    return r.str_(t["main"], key) if "main" in t else ""


def _port(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> int:
    value = t.get("port", DEFAULT_TLS_PORT if key.endswith(".tls.port") else DEFAULT_MODBUS_PORT)
    return _port_number(r, value, key)


def _port_number(r: _Reader, value: Any, key: str) -> int:
    if value == 0 and not isinstance(value, bool):
        return 0  # 0 asks the system for a free port (tests, the Python API)
    return r.int_(value, key, 1, 65535)


def _roles(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw = t.get("roles", {})
    if not isinstance(raw, dict):
        raise r.fail(key, f"expected a table of role = [regions], got {raw!r}")
    roles: dict[str, frozenset[str]] = {}
    for role, regions in raw.items():
        if not isinstance(regions, list):
            raise r.fail(f"{key}.{role}", f"expected a list of regions, got {regions!r}")
        for i, region in enumerate(regions):
            if region not in MAP_REGIONS:
                raise r.fail(f"{key}.{role}[{i}]", f"expected one of {', '.join(MAP_REGIONS)}, "
                             f"got {region!r}")
        roles[role] = frozenset(regions)
    return roles


def _web_port(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> int | None:
    # Unset (None): 8080, and a taken 8080 is not fatal for `run`; set: exactly this port.
    return _port_number(r, t["port"], key) if "port" in t else None


def _watchdog(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> int:
    return r.int_(t.get("watchdog_ms", 5 * done["scan_ms"]), key, 0, 3_600_000)


def _optional_str(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    name = key.rsplit(".", 1)[1]
    return r.str_(t[name], key) if name in t else None


def _unit_ids(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    unit_ids = t.get("unit_ids", [1])
    if not isinstance(unit_ids, list) or not unit_ids or not all(
        isinstance(u, int) and not isinstance(u, bool) and 0 <= u <= 255 for u in unit_ids
    ):
        raise r.fail(key, f"expected a non-empty list of integers 0..255, got {unit_ids!r}")
    return tuple(unit_ids)


def _allow(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    allow = t.get("allow", [])
    if not isinstance(allow, list) or not all(isinstance(a, str) for a in allow):
        raise r.fail(key, f"expected a list of IP addresses, got {allow!r}")
    for i, entry in enumerate(allow):
        try:
            ipaddress.ip_network(entry, strict=False)
        except ValueError:
            raise r.fail(f"{key}[{i}]", f"expected an IP address or network, got "
                         f"{entry!r}") from None
    return tuple(allow)


def _regions(r: _Reader, t: dict[str, Any], key: str, known: tuple[str, ...]) -> Any:
    """A list of region names (``modbus.map.read_only``, ``opcua.writable``), as a set."""
    raw = t.get(key.rsplit(".", 1)[1], [])
    if not isinstance(raw, list) or any(x not in known for x in raw):
        raise r.fail(key, f"expected a list of {', '.join(known)}, got {raw!r}")
    return frozenset(raw)


def _read_only_regions(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    return _regions(r, t, key, MAP_REGIONS)


def _travel(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    name = key.rsplit(".", 1)[1]
    value = t.get(name, list(TRAVEL_MM))
    if not (isinstance(value, list) and len(value) == 2 and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in value)
            and value[0] < value[1]):
        raise r.fail(key, f"expected [min, max] with min < max (inf for no limit), got {value!r}")
    return (float(value[0]), float(value[1]))


def _map_base(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> int | None:
    name = key.rsplit(".", 1)[1]  # unset: laid out for nc.processes (input_bases)
    return r.int_(t[name], key, 0, 65535) if name in t else None


def _optional_path(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    name = key.rsplit(".", 1)[1]
    if name not in t:
        return None
    return r.path(key, r.path_name(t[name], key))


def _logic(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw = t.get("logic", [])
    items = [raw] if isinstance(raw, str) else raw
    if not isinstance(items, list) or not all(isinstance(x, str) for x in items):
        raise r.fail(key, f"expected a file name or a list of them, got {raw!r}")
    paths: list[Path] = []
    for i, item in enumerate(items):
        where = key if isinstance(raw, str) else f"{key}[{i}]"
        path = r.existing_file(key, item, where)
        if path in paths:  # (resolved: the same file by another name, or through a link)
            raise r.fail(where, f"{path} is listed twice (also {key}[{paths.index(path)}]): "
                         "list each file once")
        paths.append(path)
    return tuple(paths)


def _programs(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw = t.get("programs", [])
    if not isinstance(raw, list) or not all(isinstance(x, str) and x for x in raw):
        raise r.fail(key, f"expected a list of PROGRAM names, got {raw!r}")
    if raw and not done.get("logic"):
        raise r.fail(key, f"names programs, but {key.rsplit('.', 1)[0]}.logic names no file")
    seen = [name.upper() for name in raw]  # (ST's names know no case)
    for i, name in enumerate(seen):
        if name in seen[:i]:
            raise r.fail(f"{key}[{i}]", f"{raw[i]} is listed twice (also {key}"
                         f"[{seen.index(name)}]): a PROGRAM runs once a scan")
    return tuple(raw)


_VE_MAP = re.compile(r"(SYVAR|SA|SK|K)(\d+)(?:\.(BY|IN))?$", re.IGNORECASE)


def _external(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw = t.get("ve", {})
    if not isinstance(raw, dict):
        raise r.fail(key, "expected a table of NAME = { map = \"SYVAR5\", sync = true }")
    out: dict[str, VeConfig] = {}
    for name, entry in raw.items():
        item = f"{key}.{name}"
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise r.fail(item, "a V.E. name is letters, digits and _")
        if isinstance(entry, str):  # NAME = "SYVAR5": synchronous, the ISG default
            entry = {"map": entry}
        if not isinstance(entry, dict) or "map" not in entry:
            raise r.fail(f"{item}.map", "missing (e.g. map = \"SYVAR5\")")
        ve = r.section(VeConfig, entry, item)
        m = _VE_MAP.match(ve.map)
        if m is None:
            raise r.fail(f"{item}.map", f"expected SYVAR<n>, SA<n>, SA<n>.BY, SA<n>.IN, K<n>, "
                         f"SK<n> or SK<n>.IN, got {ve.map!r}")
        out[name.upper()] = ve
    return out


_AUX_CODE = re.compile(r"([MSTH])(\d*)$", re.IGNORECASE)
_AUX_VALUE = re.compile(r"(SYVAR)(\d+)$|(S?K)(\d+)\.IN$", re.IGNORECASE)
_SA_BIT = re.compile(r"SA(\d+)$", re.IGNORECASE)


def _aux(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    """[nc.aux]: None when the table is absent (no auxiliary function is output)."""
    return r.section(AuxConfig, t["aux"], key) if "aux" in t else None


def _aux_codes(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw = t.get("codes", {})
    if not isinstance(raw, dict):
        raise r.fail(key, 'expected a table of CODE = "none" | "before_motion" | '
                     '"after_motion" (M8 = "after_motion", T = "before_motion")')
    out: dict[str, Handshake] = {}
    names = " or ".join(f'"{h.value}"' for h in Handshake)
    for name, value in raw.items():
        item = f"{key}.{name}"
        found = _AUX_CODE.match(name)
        if found is None:
            raise r.fail(item, "expected a code (M8, S1000, T5, H2) or a letter for all its "
                         "codes (M, S, T, H)")
        letter, digits = found.group(1).upper(), found.group(2)
        code = f"{letter}{int(digits)}" if digits else letter
        if letter == "M" and digits and int(digits) in AUX_NC_CODES:
            raise r.fail(item, f"{name} keeps the NC's meaning (a stop or the program's end): "
                         "it is not output to the PLC")
        if code in out:
            raise r.fail(item, f"{code} is given twice")
        try:
            out[code] = Handshake(value)
        except ValueError:
            raise r.fail(item, f"expected {names}, got {value!r}") from None
    return out


def _aux_value(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> str:
    name = key.rpartition(".")[2]
    text = r.str_(t.get(name, "SYVAR192"), key)
    found = _AUX_VALUE.match(text)
    if found is None:
        raise r.fail(key, f"expected SYVAR<n> or SK<n>.IN (a 16-bit word), got {text!r}")
    return f"SYVAR{int(found.group(2))}" if found.group(1) else f"SK{int(found.group(4))}.IN"


def _aux_bits(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> int:
    value = t.get("value_bits", 16)
    if value not in (16, 32) or isinstance(value, bool):
        raise r.fail(key, f"expected 16 or 32, got {value!r}")
    return int(value)


def _aux_bit(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> str:
    name = key.rpartition(".")[2]
    text = r.str_(t.get(name, "SA896" if name == "strobe" else "SA960"), key)
    found = _SA_BIT.match(text)
    if found is None:
        raise r.fail(key, f"expected an SA bit (SA<n>), got {text!r}")
    return f"SA{int(found.group(1))}"


# ---- the schema ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ProcessConfig:
    number: int = setting(0, "the process (1..nc.processes)", lo=1)
    external: bool = setting(False, "runs no part program: a PLC plays it over the fieldbus")
    main: str = setting("", "the program a cycle start of this process starts (none by "
                        "default; process 1's is nc.main)", parse=_process_main)


@dataclass(frozen=True, slots=True)
class StorageConfig:
    devices: Mapping[str, Path] = setting(
        doc="MP0..MP3: the folder of each storage device, relative to the config file "
        "(default: MP0 = the config file's folder)", parse=_storage_devices, factory=dict)
    default: str = setting("MP0", "the device of a program named without /MPx",
                           parse=_storage_default)

    KEYS = (*STORAGE_DEVICES, "default")  # what [nc.storage] may hold


@dataclass(frozen=True, slots=True)
class IsgConfig:
    max_events: int = setting(150, "ISG: signals stored at once; one more is an alarm of the "
                              "sender (AL170)", lo=1, hi=1_000_000)
    signal_params: int = setting(10, "ISG: parameters a signal carries (P[0] ..)", lo=1,
                                 hi=1000)


@dataclass(frozen=True, slots=True)
class AuxConfig:
    """[nc.aux]: the auxiliary functions (M, S, T, H) and their handshake with the PLC
    (docs/interfacing-a-plc.md).  Process k's letter i (M 0, S 1, T 2, H 3) is at each
    base + 4(k-1) + i (an SK word: + 2 bytes each)."""

    handshake: Handshake = setting(
        Handshake.NONE, 'every code\'s handshake: "none" (the value is output, nothing '
        'waits), "before_motion" (value and strobe; the block\'s motion waits for the '
        'acknowledge) or "after_motion" (output when the block\'s motion ends; the next '
        'block waits)')
    codes: Mapping[str, Handshake] = setting(
        doc='the handshake of a code or of every code of a letter, over `handshake`: '
        '{ M8 = "after_motion", T = "before_motion" } (a code wins over its letter)',
        parse=_aux_codes, factory=dict)
    timeout_s: float = setting(0.0, "an acknowledge that has not come (and gone) this long "
                               "after the strobe is an alarm, AL145 (0: no timeout)", lo=0)
    value: str = setting("SYVAR192", "where P1's M value goes: SYVAR<n> or SK<n>.IN (P1's S, "
                         "T, H at +1, +2, +3, P2's M at +4, ...)", parse=_aux_value)
    strobe: str = setting("SA896", "the SA bit of P1's M strobe (the NC sets it; P1's S, T, "
                          "H at +1, +2, +3, P2's M at +4, ...)", parse=_aux_bit)
    ack: str = setting("SA960", "the SA bit of P1's M acknowledge (the PLC sets it; laid "
                       "out as the strobes)", parse=_aux_bit)
    value_bits: int = setting(16, "16: a value is one word; 32: two words, the high one first "
                              "(a pair of SYVARs, or two SK words), each value's place twice as "
                              "wide", parse=_aux_bits)

    def settings(self) -> AuxSettings:
        found = _AUX_VALUE.match(self.value)
        assert found is not None
        value = (("SYVAR", int(found.group(2)), "IN") if found.group(1)
                 else ("SK", int(found.group(4)), "IN"))
        return AuxSettings(self.handshake, tuple(self.codes.items()), self.timeout_s, value,
                           int(self.strobe[2:]), int(self.ack[2:]), self.value_bits // 16)


@dataclass(frozen=True, slots=True)
class VeConfig:
    map: str = setting("SYVAR0", "the image variable: SYVAR<n>, SA<n> (bit), SA<n>.BY, "
                       "SA<n>.IN, K<n> / SK<n> (byte), SK<n>.IN")
    sync: bool = setting(True, "synchronous: a read waits for the interpolator (an implicit "
                         "#FLUSH WAIT), a write acts in motion order; false: both at decode "
                         "time")


def _limit(axis: str) -> Any:
    unit = "degrees" if axis in "ABC" else "mm"
    return setting(TRAVEL_MM, f"soft travel limits of {axis}, [min, max] in {unit}: a block "
                   "that would move past one is an alarm at decode (AL131)", parse=_travel)


@dataclass(frozen=True, slots=True)
class LimitsConfig:
    """Soft limits a block is checked against where it is decoded (docs/runtime.md)."""

    X: tuple[float, float] = _limit("X")
    Y: tuple[float, float] = _limit("Y")
    Z: tuple[float, float] = _limit("Z")
    U: tuple[float, float] = _limit("U")
    V: tuple[float, float] = _limit("V")
    W: tuple[float, float] = _limit("W")
    A: tuple[float, float] = _limit("A")
    B: tuple[float, float] = _limit("B")
    C: tuple[float, float] = _limit("C")
    block_s: float = setting(BLOCK_S, "the longest one block's motion, dwell or tool change "
                             "may take, in seconds: longer is an alarm at decode (AL132)",
                             lo=0, positive=True)


@dataclass(frozen=True, slots=True)
class NcConfig:
    processes: int = setting(5, "how many processes (channels)", lo=1, hi=MAX_PROCESSES)
    dialect: Dialect = setting(Dialect.NC110, 'the part programs\' language: "nc110" '
                               '(NC-110/NC-200) or "isg" (TwinCAT CNC: #SIGNAL, #WAIT)')
    lookahead: int = setting(16, "motion-queue items the decoder may run ahead (0: none)",
                             lo=0, hi=100_000)
    snd: SndPolicy = setting(SndPolicy.RENDEZVOUS, "an SND waits for its target to wait "
                             "(rendezvous) or leaves a token (latched)")
    sync_reads: bool = setting(False, "a read of SA/SK/SYVAR waits for the motion queue to empty")
    block_search_sync: BlockSearchSync = setting(
        BlockSearchSync.REFUSE, 'a block search in a program with EXE, WAI or SND: "refuse" '
        '(seed 000: impossible) or "skipped" (refused only when the skipped blocks hold one)')
    time_scale: float = setting(1.0, "run: simulated seconds per wall-clock second", lo=0,
                                positive=True)
    wait_timeout_s: float = setting(0.0, "a wait longer than this is an alarm (0: off)", lo=0)
    stall_s: float = setting(60.0, "run: report a stall when every process with a program has "
                             "been blocked this long with the image unchanged; sim with "
                             "PLC logic: end the run as a stall then (a held process counts "
                             "as blocked in sim)", lo=0,
                             positive=True)
    runaway_blocks: int = setting(100_000, "a process that decodes this many blocks without "
                                  "time passing is a runaway: alarm AL144 (0: no limit)",
                                  lo=0, hi=1_000_000_000)
    block_time_ms: float = setting(0.0, "processing time of each block in ms, as a real "
                                   "control has (0: blocks take no time)", lo=0, hi=60_000)
    rapid_mm_min: float = setting(10000.0, "G0 feed", lo=0, positive=True)
    tool_change_s: float = setting(2.0, "duration of M6", lo=0)
    main: str = setting("PROG91", "the main program of process 1 (the operator's SPG)")
    cell: str = setting("ncgate cell", "the cell's name, as fieldbus masters see it (Modbus "
                        "device identification: UserApplicationName)")
    autostart: bool = setting(False, "run: start main at once (else on cycle start)")
    feed_override: int = setting(100, "the feed override at start, percent (0..200): every "
                                 "process's, until a door changes it", lo=0, hi=200)
    feed_hold_input: str = setting(
        "", "a PLC interlock as a level (e.g. \"SA100\", door open): while it is set, motion "
        "holds and a cycle start is refused (empty: none)", parse=_image_input)
    cycle_start_inhibit_input: str = setting(
        "", "while this image variable is set, a cycle start is refused (empty: none)",
        parse=_image_input)
    e_params: int = setting(1000, "E parameters per process (E0..)", lo=1, hi=100_000)
    optional_skip: bool = setting(False, "skip blocks that start with /")
    lazy_parse: bool = setting(False, "start a program before it is parsed whole; a bad block "
                               "is an alarm when reached")
    storage: StorageConfig = setting(doc="[nc.storage]", factory=StorageConfig)
    process: tuple[ProcessConfig, ...] = setting((), "[[nc.process]]: per-process settings",
                                                 parse=_processes)
    limits: LimitsConfig = setting(doc="[nc.limits]", factory=LimitsConfig)
    isg: IsgConfig = setting(doc="[nc.isg]", factory=IsgConfig)
    ve: Mapping[str, VeConfig] = setting(
        doc="[nc.ve]: ISG V.E. variables, NAME = { map = \"SYVAR5\", sync = true }",
        parse=_external, factory=dict)
    aux: AuxConfig | None = setting(
        None, "[nc.aux]: the auxiliary functions' interface; without this table no M, S, T "
        "or H word is output to the PLC", parse=_aux)

    @property
    def aux_interface(self) -> AuxSettings | None:
        """[nc.aux] as the engine takes it (None: no auxiliary function is output)."""
        return self.aux.settings() if self.aux is not None else None

    @property
    def external(self) -> frozenset[int]:
        return frozenset(p.number for p in self.process if p.external)

    @property
    def mains(self) -> tuple[tuple[int, str], ...]:
        """(process, program) for each process's own main (process 2 up; 1's is nc.main)."""
        return tuple((p.number, p.main) for p in self.process if p.main)

    # The engine's names for [nc.limits] (RuntimeSettings takes [nc]'s keys by name).
    @property
    def travel_limits(self) -> tuple[tuple[float, float], ...]:
        return tuple(getattr(self.limits, axis) for axis in AXES)

    @property
    def block_limit_s(self) -> float:
        return self.limits.block_s


@dataclass(frozen=True, slots=True)
class PlcConfig:
    sa_bits: int = setting(1024, "bits of the SA packet (a multiple of 8)", lo=8, hi=65536)
    k_bytes: int = setting(512, "bytes of the K packet", lo=2, hi=65536)
    syvars: int = setting(256, "SYVARs (16-bit signed)", lo=1, hi=32768)
    logic: tuple[Path, ...] = setting((), "PLC logic: a Structured Text .st or PLCopen XML "
                                      ".xml file, or a list of them in scan order (none: the "
                                      "PLC runs no logic)", parse=_logic)
    programs: tuple[str, ...] = setting((), "the PROGRAMs each scan runs, in this order "
                                        "(default: every PROGRAM, in file order)",
                                        parse=_programs)
    scan_ms: int = setting(10, "the scan period of PLC logic, in ms of machine time (virtual "
                           "in sim, nc.time_scale on the wall clock in run)", lo=1, hi=60_000)
    loop_limit: int = setting(100_000, "loop iterations one scan may run before the PLC "
                              "faults (the iteration guard)", lo=1, hi=100_000_000)
    watchdog_ms: int = setting(50, "a scan that runs longer (wall-clock ms) is stopped and the "
                               "PLC goes to FAULT naming the line it was executing (default "
                               "5 x scan_ms; 0: off)", parse=_watchdog)
    retain_file: Path | None = setting(
        None, "where VAR RETAIN values are kept (default: ncgate-plc-retain.sqlite next to "
        "the config; for the built-in config or one inside an installed package, in "
        "~/.local/state/ncgate/: docs/decisions.md)", parse=_optional_path)
    strict: bool = setting(True, "Structured Text as IEC 61131-3 writes it; false: CODESYS-"
                           "compatible -- implicit narrowing and CODESYS's extensions load, "
                           "each with an SW warning giving the IEC spelling (docs/plc.md)")


@dataclass(frozen=True, slots=True)
class ModbusMapConfig:
    """Where the movable regions of the map start, and which are read-only (spec 3.2)."""

    k_bytes: int = setting(0, "holding base of the K bytes", lo=0, hi=65535)
    syvars: int = setting(1000, "holding base of the SYVARs", lo=0, hi=65535)
    sa_bytes: int = setting(1500, "holding base of the SA bytes", lo=0, hi=65535)
    command: int = setting(2000, "holding address of the command word; the SND mailbox "
                           "follows at +1, +2", lo=0, hi=65535)
    overrides: int = setting(2010, "holding base of the overrides in percent: feed (0..200) "
                             "and rapid (0..100) of process k at +2(k-1), +2(k-1)+1",
                             lo=0, hi=65535)
    force: int = setting(2100, "holding base of the force table: a force request at +0..+3 "
                         "(action, kind, index, value in one FC16), the number of forced "
                         "variables at +4, the first 32 forces at +5.. (3 registers each)",
                         lo=0, hi=65535)
    status: int = setting(100, "input base of the per-process status blocks (20 registers "
                          "each)", lo=0, hi=65535)
    snd_log: int | None = setting(None, "input base of the SND log (the last 16 SNDs, 98 "
                                  "registers; default: 200 for up to 5 processes, 300 for 6..10, "
                                  "400 for 11..15, 500 for 16: past the status blocks)",
                                  parse=_map_base)
    plc_status: int | None = setting(None, "input base of the PLC status (14 registers; "
                                     "default: the SND log's default + 100, so 300 for up to "
                                     "5 processes)", parse=_map_base)
    read_only: frozenset[str] = setting(frozenset(), "regions clients may not write: "
                                        + ", ".join(MAP_REGIONS), parse=_read_only_regions)

    def input_bases(self, processes: int) -> tuple[int, int]:
        """Where the SND log and the PLC status start for this many processes: as set, or
        laid out after the status blocks at the next hundred.  Up to five processes that is
        200 and 300, the addresses dashboards have always read; each five processes more
        (another 100 registers of status) move both by 100, so 16 processes fit."""
        snd_log = 100 + 100 * -(-processes // 5)
        return (snd_log if self.snd_log is None else self.snd_log,
                snd_log + 100 if self.plc_status is None else self.plc_status)


@dataclass(frozen=True, slots=True)
class ModbusTlsConfig:
    """Modbus/TCP Security (TLS with mutual authentication): on when ``cert`` is set."""

    port: int = setting(DEFAULT_TLS_PORT, "the Modbus/TCP Security (mbaps) port; below 1024 "
                        "it needs root or CAP_NET_BIND_SERVICE (0: a free one)", parse=_port)
    cert: Path | None = setting(None, "the server's certificate chain (PEM); setting it turns "
                                "TLS on", parse=_optional_path)
    key: Path | None = setting(None, "the server's private key (PEM)", parse=_optional_path)
    ca: Path | None = setting(None, "clients must present a certificate signed by this CA "
                              "(PEM)", parse=_optional_path)
    plain: bool = setting(True, "also serve plain Modbus/TCP on modbus.port (false: TLS only)")

    @property
    def enabled(self) -> bool:
        return self.cert is not None


class Parity(enum.Enum):
    """``modbus.rtu.parity``: the serial line's parity bit (Modbus over Serial Line 2.5.1)."""

    EVEN = "E"  # the spec's default, and mbpoll's
    ODD = "O"
    NONE = "N"  # the spec asks for two stop bits then


def _serial_device(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    return r.str_(t["port"], key) if "port" in t else None


def _bytesize(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    value = t.get("bytesize", 8)
    if value != 8 or isinstance(value, bool):
        raise r.fail(key, f"expected 8, got {value!r}: an RTU frame is of 8-bit bytes (7 data "
                     "bits are Modbus ASCII's, which ncgate does not serve)")
    return 8


def _rtu_unit_ids(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    if "unit_ids" not in t:
        return ()
    unit_ids = t["unit_ids"]
    if not isinstance(unit_ids, list) or not unit_ids or not all(
        isinstance(u, int) and not isinstance(u, bool) and 1 <= u <= 247 for u in unit_ids
    ):
        raise r.fail(key, f"expected a non-empty list of serial addresses 1..247 (0 is the "
                     f"broadcast), got {unit_ids!r}")
    return tuple(unit_ids)


def _optional_port(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    return _port_number(r, t["port"], key) if "port" in t else None


@dataclass(frozen=True, slots=True)
class ModbusRtuConfig:
    """Modbus RTU on a serial line (Modbus over Serial Line V1.02): on when ``port`` is set."""

    port: str | None = setting(None, "the serial device (/dev/ttyUSB0, /dev/ttyS1, a pty); "
                               "setting it turns Modbus RTU on", parse=_serial_device)
    baudrate: int = setting(19200, "bit/s; it also sets the 3.5-character silence that ends a "
                            "frame (1.75 ms above 19200)", lo=300, hi=4_000_000)
    parity: Parity = setting(Parity.EVEN, '"E" (even, the spec\'s default), "O" (odd) or "N" '
                             "(none: the spec asks for stopbits = 2 then)")
    stopbits: int = setting(1, "stop bits, 1 or 2", lo=1, hi=2)
    bytesize: int = setting(8, "data bits: 8, as RTU has them", parse=_bytesize)
    unit_ids: tuple[int, ...] = setting((), "the addresses answered, 1..247 (default: "
                                        "modbus.unit_ids' of them); 0, the broadcast, is "
                                        "applied and not answered; others are not answered",
                                        parse=_rtu_unit_ids)


@dataclass(frozen=True, slots=True)
class ModbusRtuTcpConfig:
    """RTU frames (with their CRC, no MBAP header) on a TCP listener, as a serial device
    server delivers them: on when ``port`` is set."""

    host: str = setting("127.0.0.1", "the address to listen on")
    port: int | None = setting(None, "the port; setting it turns RTU over TCP on (0: a free "
                               "one, for tests)", parse=_optional_port)
    gap_ms: float = setting(20.0, "the silence that ends a frame whose length its function "
                            "code does not give, and drops a frame begun and not finished "
                            "(a serial line's 3.5 characters, stretched for TCP's segments)",
                            lo=1, positive=True)


class Evict(enum.Enum):
    """``modbus.evict``: who makes room when a client connects at ``max_clients``."""

    IDLEST = "idlest"  # a connection that never completed a request (or TLS handshake)
    REFUSE = "refuse"  # nobody: the newcomer is refused


@dataclass(frozen=True, slots=True)
class ModbusConfig:
    enabled: bool = setting(True, "serve Modbus TCP")
    host: str = setting("127.0.0.1", "the address to listen on")
    port: int = setting(DEFAULT_MODBUS_PORT, "the port (0: a free one, for tests)", parse=_port)
    unit_ids: tuple[int, ...] = setting((1,), "unit ids answered (and always 0xFF, the server "
                                        "itself; 0 too unless strict_unit_id)",
                                        parse=_unit_ids)
    strict_unit_id: bool = setting(False, "answer unit id 0 with exception 0x0B unless it is "
                                   "listed in unit_ids")
    max_clients: int = setting(16, "connections at once", lo=1, hi=10_000)
    evict: Evict = setting(Evict.IDLEST, 'at max_clients: "idlest" closes the connection '
                           "that never completed a request (or TLS handshake), longest "
                           'connected, to make room (none such: the newcomer is refused); '
                           '"refuse" always refuses the newcomer')
    idle_timeout_s: float = setting(60.0, "close a connection silent this long", lo=0,
                                    positive=True)
    read_only: bool = setting(False, "refuse every write")
    allow: tuple[str, ...] = setting((), "client addresses or networks allowed (empty: all)",
                                     parse=_allow)
    map: ModbusMapConfig = setting(doc="[modbus.map]", factory=ModbusMapConfig)
    tls: ModbusTlsConfig = setting(doc="[modbus.tls]", factory=ModbusTlsConfig)
    rtu: ModbusRtuConfig = setting(doc="[modbus.rtu]", factory=ModbusRtuConfig)
    rtu_tcp: ModbusRtuTcpConfig = setting(doc="[modbus.rtu_tcp]", factory=ModbusRtuTcpConfig)
    roles: Mapping[str, frozenset[str]] = setting(
        doc="[modbus.roles]: role = [regions it may write] (of the map's read_only names); "
        "a TLS client's role comes from its certificate; any role reads, an unlisted one (or "
        "none) only reads", parse=_roles, factory=dict)

    @property
    def rtu_unit_ids(self) -> tuple[int, ...]:
        """The addresses Modbus RTU answers: ``rtu.unit_ids``, or the serial addresses
        (1..247) among ``unit_ids`` (the checks refuse RTU with none)."""
        return self.rtu.unit_ids or tuple(u for u in self.unit_ids if 1 <= u <= 247)


class MasterLost(enum.Enum):
    """``canopen.on_master_lost``: what the node does when the master's heartbeat stops."""

    NONE = "none"
    HOLD = "hold"
    RESET = "reset"


@dataclass(frozen=True, slots=True)
class CanopenConfig:
    enabled: bool = setting(True, "run the CANopen node")
    interface: str = setting("virtual", "python-can interface (virtual, socketcan, ...)")
    channel: str = setting("ncgate", "python-can channel")
    bitrate: int = setting(500000, "bit/s", lo=10_000, hi=1_000_000)
    node_id: int = setting(16, "the node id", lo=1, hi=127)
    nmt_autostart: bool = setting(False, "go OPERATIONAL after boot-up without an NMT start")
    heartbeat_ms: int = setting(1000, "heartbeat producer period (0: off)", lo=0, hi=65535)
    # A python-can-remote hub on loopback, so that a master in another process can reach the
    # node on a machine without SocketCAN (`interface = "remote"`, channel ws://host:port/).
    hub: bool = setting(False, "host a python-can-remote hub for masters in other processes")
    hub_host: str = setting("127.0.0.1", "the hub's address")
    hub_port: int = setting(54701, "the hub's port", lo=0, hi=65535)
    on_master_lost: MasterLost = setting(
        MasterLost.HOLD, "when the heartbeat the master set in 0x1016 stops: alarm and EMCY, "
        "and \"hold\" (feed hold), \"reset\" (reset the processes) or \"none\"")
    store_file: Path | None = setting(
        None, "where 0x1010 keeps the communication parameters (default: "
        "ncgate-canopen-node<id>.json next to the config; for the built-in config or one "
        "inside an installed package, in ~/.local/state/ncgate/: docs/decisions.md)",
        parse=_optional_path)


def _plant_models(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    return read_models(t.get("model"), key, r.fail)


def _plant_faults(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    return read_faults(t.get("fault"), key, r.fail)


@dataclass(frozen=True, slots=True)
class PlantConfig:
    """The machine around the cell (docs/plant.md): models that answer the PLC's outputs,
    an optional ST plant logic, and the faults to inject."""

    model: tuple[PlantModelConfig, ...] = setting(
        (), "[[plant.model]]: name, kind (delay, cylinder, motor, lag, generator, switch) and "
        "the kind's keys (docs/plant.md)", parse=_plant_models)
    logic: tuple[Path, ...] = setting((), "the plant's own Structured Text (or PLCopen XML): "
                                      "a second ST task beside [plc] logic, scanned every "
                                      "plant.scan_ms, its writes attributed to plant "
                                      "(docs/plant.md)", parse=_logic)
    programs: tuple[str, ...] = setting((), "the plant logic's PROGRAMs each scan runs, in "
                                        "this order (empty: each in file order)",
                                        parse=_programs)
    scan_ms: int = setting(10, "the plant's step: the plant logic's scan period, and how often "
                           "what moves continuously (a position, a speed, a lag, a sine) is "
                           "written while it moves (switch points are exact), ms of machine "
                           "time", lo=1, hi=60_000)
    fault: tuple[FaultConfig, ...] = setting(
        (), "[[plant.fault]]: target, kind, at / when, for_s and the kind's keys "
        "(docs/plant.md)", parse=_plant_faults)


@dataclass(frozen=True, slots=True)
class SimConfig:
    """How ``ncgate sim`` times its script's inputs: the PLC's answers slower, faster or
    jittered, as keys that ``--set`` and ``ncgate sweep`` vary (docs/sweep.md)."""

    input_delay_scale: float = setting(1.0, "sim: every scripted input's time (its `at`, or "
                                       "its `after` past its `when`) multiplied by this: the "
                                       "PLC answering slower (> 1) or faster", lo=0, hi=1000)
    input_jitter_ms: float = setting(0.0, "sim: and each scripted input later by a random "
                                     "0..this many ms, drawn in the script's order from "
                                     "sim.seed", lo=0, hi=3_600_000)
    seed: int = setting(0, "sim: the seed of sim.input_jitter_ms's draws", lo=0,
                        hi=2**63 - 1)


@dataclass(frozen=True, slots=True)
class TraceConfig:
    """What ``ncgate run`` keeps of the trace: memory stays flat however long it runs."""

    ring: int = setting(10_000, "run: events kept in memory (Gateway.trace)", lo=0,
                        hi=10_000_000)
    file: Path | None = setting(None, "run: write every event here as JSON Lines "
                                "(also --trace FILE)", parse=_optional_path)
    max_mb: float = setting(100.0, "rotate the file when it reaches this size", lo=0,
                            positive=True)
    backups: int = setting(3, "rotated files kept (FILE.1 .. FILE.n; 0: none)", lo=0, hi=1000)


@dataclass(frozen=True, slots=True)
class WebTlsConfig:
    """HTTPS for the console: on when ``cert`` is set."""

    cert: Path | None = setting(None, "the console's certificate chain (PEM); setting it serves "
                                "the console over HTTPS only", parse=_optional_path)
    key: Path | None = setting(None, "its private key (PEM)", parse=_optional_path)

    @property
    def enabled(self) -> bool:
        return self.cert is not None


@dataclass(frozen=True, slots=True)
class WebConfig:
    """The commissioning console (``ncgate run``): a page and an HTTP API on one port."""

    enabled: bool = setting(True, "serve the console with `ncgate run` (also --no-web)")
    host: str = setting("127.0.0.1", "the address to listen on; any but loopback needs a token")
    port: int | None = setting(None, "the port (default 8080: when it is taken `run` goes on "
                               "without the console; a port set here must be free; 0: a free "
                               "one)", parse=_web_port)
    token: str | None = setting(None, "every write and command needs `Authorization: Bearer "
                                "<token>`", parse=_optional_str)
    read_only: bool = setting(False, "refuse every write and command (a view only)")
    max_streams: int = setting(32, "live streams (browser tabs) at once", lo=1, hi=1000)
    tls: WebTlsConfig = setting(doc="[web.tls]", factory=WebTlsConfig)


OPCUA_REGIONS = ("sa_bits", "k_bytes", "syvars")  # the image regions a UA client may write


class UaSecurity(enum.Enum):
    """``opcua.security``: the message security mode of the endpoint (Basic256Sha256)."""

    NONE = "none"
    SIGN = "sign"
    SIGN_ENCRYPT = "sign_encrypt"


def _opcua_security(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw = t.get("security", "none")
    try:
        security = UaSecurity(raw)
    except ValueError:
        names = " or ".join(f'"{c.value}"' for c in UaSecurity)
        raise r.fail(key, f"expected {names}, got {raw!r}") from None
    host = done["host"]
    if security is UaSecurity.NONE and not _loopback(host):
        # Anyone on the network could read the cell and write what `writable` lists.
        raise r.fail(key, f'"none" serves only loopback; opcua.host = {host!r} needs '
                     '"sign" or "sign_encrypt" (and a certificate)')
    if security is not UaSecurity.NONE and not ("certificate" in t and "private_key" in t):
        raise r.fail(key, f'"{security.value}" needs opcua.certificate and opcua.private_key')
    return security


def _loopback(host: str) -> bool:
    return host in ("localhost", "::1") or host.startswith("127.")


UA_TRUSTED_SUFFIXES = (".pem", ".der", ".crt", ".cer")  # what a trusted folder's files are


def x509_certificate(data: bytes) -> Any:
    """A certificate's bytes, PEM (by its armour) or DER, as a cryptography Certificate;
    ValueError when they are neither."""
    from cryptography import x509

    if data.lstrip().startswith(b"-----"):
        return x509.load_pem_x509_certificate(data)
    return x509.load_der_x509_certificate(data)


def _ua_certificates(r: _Reader, path: Path, where: str) -> None:
    """A trusted file, or every certificate of a trusted folder, loads (PEM or DER); a
    folder holds one at least -- asyncua refused an empty one at start with "can't create
    an empty store", naming nothing (a dashboard builder's try)."""
    files = [path] if path.is_file() else sorted(
        f for f in path.iterdir() if f.suffix.lower() in UA_TRUSTED_SUFFIXES)
    if not files:
        raise r.fail(where, f"the folder {path} holds no certificate "
                     f"({', '.join('*' + s for s in UA_TRUSTED_SUFFIXES)}); an empty list "
                     "trusts any client on loopback")
    for f in files:
        try:
            x509_certificate(f.read_bytes())
        except ValueError:
            raise r.fail(where, f"{f} is not a certificate (PEM or DER)") from None


def _opcua_trusted(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw = t.get("trusted", [])
    items = [raw] if isinstance(raw, str) else raw
    if not isinstance(items, list) or not all(isinstance(x, str) for x in items):
        raise r.fail(key, f"expected a certificate file or folder, or a list of them, got {raw!r}")
    paths = []
    for i, item in enumerate(items):
        where = key if isinstance(raw, str) else f"{key}[{i}]"
        # (asyncua reads a file as one certificate and a folder's *.pem, *.der, *.crt, *.cer:
        # gateway/opcua/space.py; "" would be the config's folder, /dev/null neither)
        text = r.path_name(item, where, "a certificate file or a folder of them")
        paths.append(r.file_or_folder(where, r.path(key, text, where)))
    for i, path in enumerate(paths):  # (once every name is one: a bad name is said first)
        _ua_certificates(r, path, key if isinstance(raw, str) else f"{key}[{i}]")
    security, host = done["security"], done["host"]
    if paths and security is UaSecurity.NONE:
        raise r.fail(key, 'client certificates are exchanged only with security "sign" or '
                     '"sign_encrypt"')
    if not paths and security is not UaSecurity.NONE and not _loopback(host):
        # Beyond loopback, a server that accepts any client certificate lets anyone who can
        # make one in: docs/decisions.md, OPC UA, "Which client certificates are trusted".
        raise r.fail(key, f"opcua.host = {host!r} serves beyond loopback: list the client "
                     "certificates (or folders of them) it trusts")
    return tuple(paths)


def _opcua_writable(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    return _regions(r, t, key, OPCUA_REGIONS)


def _opcua_users(r: _Reader, t: dict[str, Any], key: str, done: dict[str, Any]) -> Any:
    raw = t.get("users", {})
    if not isinstance(raw, dict):
        raise r.fail(key, f"expected a table of name = \"pbkdf2_sha256$...\", got {raw!r}")
    users: dict[str, str | Path] = {}
    for name, given in raw.items():
        if isinstance(given, dict) and set(given) == {"certificate"}:
            # A certificate user: the client presents this certificate as its identity.
            users[name] = r.path(key, r.path_name(given["certificate"],
                                                  f"{key}.{name}.certificate"))
            continue
        parts = given.split("$") if isinstance(given, str) else []
        if len(parts) != 4 or parts[0] != "pbkdf2_sha256" or not parts[1].isdigit():
            raise r.fail(f"{key}.{name}", "expected \"pbkdf2_sha256$<iterations>$<salt>$<hex>\" "
                         "(docs/opcua.md has the one-liner that makes it) or "
                         "{ certificate = \"user.crt\" }")
        users[name] = given
    return users


@dataclass(frozen=True, slots=True)
class OpcuaConfig:
    """The OPC UA server (docs/opcua.md): the cell as a machine tool for dashboards."""

    enabled: bool = setting(False, "serve OPC UA (also `ncgate run --opcua PORT`)")
    host: str = setting("127.0.0.1", "the address to listen on; any but loopback needs "
                        "security")
    port: int = setting(4840, "the port (0: a free one, for tests)", lo=0, hi=65535)
    certificate: Path | None = setting(None, "the server's certificate (PEM or DER)",
                                       parse=_optional_path)
    private_key: Path | None = setting(None, "its private key (PEM)", parse=_optional_path)
    security: UaSecurity = setting(UaSecurity.NONE, '"none" (loopback only), "sign" or '
                                   '"sign_encrypt" (Basic256Sha256; needs certificate and '
                                   "private_key)", parse=_opcua_security)
    writable: frozenset[str] = setting(frozenset(), "image regions clients may write: "
                                       + ", ".join(OPCUA_REGIONS) + " (empty: read-only)",
                                       parse=_opcua_writable)
    users: Mapping[str, str | Path] = setting(
        doc="[opcua.users]: name = \"pbkdf2_sha256$<iterations>$<salt>$<hex>\" (a password) "
        "or { certificate = \"user.crt\" } (an X.509 identity, with sign or sign_encrypt); when "
        "any is set, writes need one of them (anonymous sessions only read)",
        parse=_opcua_users, factory=dict)
    trusted: tuple[Path, ...] = setting(
        (), "the client certificates a secure channel accepts: files (PEM or DER) or folders "
        "of them (*.pem, *.der, *.crt, *.cer), beside the config; a client's own certificate "
        "or its CA's. Empty: any client certificate on loopback, and refused at start with any "
        "other host", parse=_opcua_trusted)
    # A client's resources (docs/opcua.md, "Limits"): without a cap per session one client could
    # hold asyncua's 1,000 subscriptions of the whole server, and keep them, killed, until
    # its session times out.
    max_sessions: int = setting(32, "the sessions the server holds at once (a client killed "
                                "holds its own until max_session_timeout_s)", lo=1, hi=1000)
    max_subscriptions_per_session: int = setting(
        16, "the subscriptions one session may hold", lo=1, hi=1000)
    max_monitored_items_per_subscription: int = setting(
        10000, "the monitored items one subscription may hold", lo=1, hi=100000)
    max_session_timeout_s: float = setting(
        60.0, "the longest session timeout a client is granted (a longer request is revised "
        "down to it): how long a client gone without closing holds its session", lo=5,
        hi=3600)


@dataclass(frozen=True, slots=True)
class Config:
    nc: NcConfig = setting(doc="[nc]", factory=NcConfig)
    plc: PlcConfig = setting(doc="[plc]", factory=PlcConfig)
    modbus: ModbusConfig = setting(doc="[modbus]", factory=ModbusConfig)
    canopen: CanopenConfig = setting(doc="[canopen]", factory=CanopenConfig)
    trace: TraceConfig = setting(doc="[trace]", factory=TraceConfig)
    plant: PlantConfig = setting(doc="[plant]", factory=PlantConfig)
    sim: SimConfig = setting(doc="[sim]", factory=SimConfig)
    web: WebConfig = setting(doc="[web]", factory=WebConfig)
    opcua: OpcuaConfig = setting(doc="[opcua]", factory=OpcuaConfig)
    symbols_file: Path | None = setting(
        None, "a CSV I/O list of more I/O names: a header of name, var and (optionally) "
        "comment, comma- or semicolon-separated (as PLC tools export them); its names join "
        "[symbols]'s", parse=_symbols_file)
    symbols: Symbols = setting(
        doc="[symbols]: I/O names, NAME = \"SA10\" (or { var = \"SA10\", comment = \"...\" }): "
        "usable wherever a variable is named (API, sim script) and shown beside it",
        parse=_symbols, factory=Symbols)
    source: Path | None = None  # the file it came from (None: built-in default); not a key


def default_config_path() -> Path:
    return Path(str(resources.files("ncgate.config").joinpath("default.toml")))


def default_script_path() -> Path:
    """The PLC script of the built-in default (the manual's SA10 for PROG92's N40)."""
    return Path(str(resources.files("ncgate.config").joinpath("default_script.toml")))






_TOML_AT: Final = re.compile(r"^(?P<what>.*) \(at line (?P<line>\d+), column \d+\)$")




def keys(cls: type, prefix: str = "") -> list[tuple[str, Any, str]]:
    """Every key of a section and its sub-sections: (dotted key, default, doc)."""
    out: list[tuple[str, Any, str]] = []
    for f in _fields(cls):
        dotted = f"{prefix}.{f.name}" if prefix else f.name
        nested = _section_type(f)
        if nested is not None:
            out.extend(keys(nested, dotted))
            continue
        if cls is NcConfig and f.name == "process":
            out.extend(keys(ProcessConfig, f"{dotted}[]"))
            continue
        if cls is NcConfig and f.name == "ve":
            out.extend(keys(VeConfig, f"{dotted}.NAME"))
            continue
        if cls is NcConfig and f.name == "aux":
            out.extend(keys(AuxConfig, dotted))
            continue
        if cls is StorageConfig and f.name == "devices":
            dotted = f"{prefix}.MP0 .. MP3"
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
        out.append((dotted, default, f.metadata.get("doc", "")))
    return out








def _fields(cls: type) -> list[dataclasses.Field[Any]]:
    return [f for f in dataclasses.fields(cls) if f.name != "source"]


_SECTIONS: dict[str, type] = {}  # field type name -> section dataclass (filled below)


def _section_type(f: dataclasses.Field[Any]) -> type | None:
    return _SECTIONS.get(str(f.type))




def _outside_image(text: str, plc: PlcConfig) -> bool:
    """Whether an image variable as the config names it (SA10, SK3.IN) lies past the image."""
    found = _VE_MAP.match(text)
    assert found is not None
    area, index, view = found.group(1).upper(), int(found.group(2)), found.group(3)
    size = {"SYVAR": plc.syvars, "SA": plc.sa_bits, "SK": plc.k_bytes, "K": plc.k_bytes}[area]
    if area == "SA" and view:
        size = plc.sa_bits // 8
    if view and view.upper() == "IN":
        size -= 1  # two bytes
    return index >= size


# ---- checks across keys ----------------------------------------------------------------------


    # The Modbus map's regions are checked against each other where Modbus is served
    # (ModbusMap), so that `check` and `sim` take a config whose map would not fit.












_SECTIONS.update({cls.__name__: cls for cls in (
    StorageConfig, NcConfig, LimitsConfig, IsgConfig, PlcConfig, ModbusMapConfig,
    ModbusTlsConfig, ModbusRtuConfig, ModbusRtuTcpConfig, ModbusConfig, CanopenConfig,
    TraceConfig, PlantConfig, WebTlsConfig, WebConfig, SimConfig)})
_SECTIONS["OpcuaConfig"] = OpcuaConfig


def config_markdown() -> str:
    """docs/config.md: every key, its default and what it does, from the schema itself."""
    lines = ["# Configuration keys", "",
             "Generated from `config/schema.py` (the dataclasses are the schema; "
             "`tests/unit/config/test_loader.py` keeps this page in sync). A config file "
             f"sets any of these in TOML tables ({_tables()}); an unknown key or a bad value "
             "is an error naming the file and the dotted key. Paths are relative to the config "
             "file.", "",
             "| key | default | what |", "|---|---|---|"]
    for dotted, default, doc in keys(Config):
        lines.append(f"| `{dotted}` | {_shown(default)} | {doc} |")
    return "\n".join(lines) + "\n" + _SERIAL_SECTION


def _tables() -> str:
    """The TOML tables of the keys, in the schema's order (a table's array as [[...]]), so that
    the list is never short of one (it lacked [plant] and [opcua] for two issues)."""
    names: list[str] = []
    for dotted, _, _ in keys(Config):
        table = dotted.rsplit(".", 1)[0] if "." in dotted else None
        if table is None or " " in table:
            continue  # (a top-level key; nc.storage's devices, named by the user)
        table = table.removesuffix(".NAME")  # (nc.ve's variables, named by the user)
        shown = f"[[{table[:-2]}]]" if table.endswith("[]") else f"[{table}]"
        if shown not in names:
            names.append(shown)
    names[names.index("[plant]") + 1:names.index("[plant]") + 1] = [
        "[[plant.model]]", "[[plant.fault]]"]  # (arrays of tables the schema keeps as one key)
    names += ["[modbus.roles]", "[opcua.users]", "[symbols]"]  # (tables of the user's names)
    return ", ".join(f"`{name}`" for name in names)


# docs/config.md's section on the serial line: what the keys above do not say on their own.
_SERIAL_SECTION = """
## Modbus RTU on a serial line

`[modbus.rtu] port` (or `ncgate run --rtu DEVICE`) serves the Modbus map of `[modbus.map]` on
a serial port, framed as Modbus over Serial Line V1.02 has it; `[modbus.rtu_tcp] port` (or
`--rtu-tcp PORT`) serves the same frames on a TCP port, as a serial device server carries
them. Either works with or without Modbus TCP (`modbus.enabled`), and with the other.

```toml
[modbus.rtu]
port = "/dev/ttyUSB0"   # an RS-485 adapter; /dev/ttyS1; a pty
baudrate = 19200        # the spec's default, and mbpoll's
parity = "E"            # "E", "O" or "N" (then stopbits = 2, as the spec asks)
stopbits = 1
unit_ids = [1]          # default: modbus.unit_ids (those in 1..247)

[modbus.rtu_tcp]
port = 5021
host = "127.0.0.1"
```

- A frame is answered as soon as it is whole -- its function code gives its length -- and its
  CRC is right; a frame whose code does not give its length ends at the line's silence of 3.5
  characters (2 ms at 19,200 bit/s 8E1; 1.75 ms above 19,200; `gap_ms` over TCP). What was
  begun and is not whole at a silence is dropped and counted as `partial`; a bad CRC is
  dropped, not answered, and counted as a `crc_error`. The silence is timed from when the
  gateway reads the bytes: what lies between the wire and the gateway (a USB adapter's
  latency timer, a pty and a `socat` relay) can shorten or stretch a pause by milliseconds,
  so on such a line a frame cut by a few milliseconds may be taken whole (on a bare pty, a
  pause of 3 ms or more at 19,200 bit/s was dropped in most of ten tries, one of 2 ms or
  less never).
- Unit 0 is the broadcast: a write is applied and not answered. A frame for an address that
  is not in `unit_ids` is not answered (counted as `other_units`); 0xFF, Modbus TCP's "the
  server itself", is not an RTU address.
- The exception codes, the refusals and the attribution are Modbus TCP's; writes are
  attributed `modbus-rtu <device>` (serial) or `modbus-rtu <client address>` (RTU over TCP).
- `GET /api/status` has `fieldbus.modbus_rtu`: totals of `frames`, `answered`,
  `crc_errors`, `partial`, `exceptions`, `broadcasts`, `other_units` and `silenced`, and
  the same per port under `ports` (the serial port with its settings and whether it is
  open); the console's fieldbus panel shows them per port.
- The plant's Modbus faults ([plant.md](plant.md)) apply to RTU too: `exception` answers that
  code and stores nothing, `delay` answers late, `no_reply` silences the line until the
  fault table changes.
- RTU over TCP keeps Modbus TCP's guards: `modbus.allow`, at most `modbus.max_clients`
  connections (a newcomer past it is refused), a connection silent `modbus.idle_timeout_s`
  closed, and a client that does not read its answers (or pipelines more than a backlog) is
  not read from until it does. A serial master that stops reading its answers is not
  buffered for either: past 64 KiB of unsent answers the line's requests are not read until
  they have gone (`unsent` and `reading` in the port's status).
- A serial port that cannot be opened at start stops `ncgate run` with the key to change
  (`ncgate run: [Errno 2] modbus.rtu.port: cannot open /dev/ttyUSB0: No such file or
  directory`; one another program holds: `... another program has it open`; one that refuses
  the line's settings: `... it refuses the line's settings (19200 8E1): Invalid argument`);
  one that goes away while serving (a USB adapter pulled) is logged and looked for again
  every second, whatever opening it again says. A pseudo-terminal that refuses parity (Linux
  6.x refuses even or odd parity on a pty that had it set once: a `socat` pair served by an
  earlier `ncgate run`) is opened without it, and the log says so once: a pty carries no
  parity bit.
- A `socat` pair stalls when its gateway side is not read: past 64 KiB of answers a master
  left unread, the gateway stops reading the line (above), socat then blocks writing the
  master's bytes to it, and the answers are never drained; start the pair again. A real
  UART drains.
  With RTU on, `modbus.unit_ids` must hold a serial address (1..247), or
  `modbus.rtu.unit_ids` name them.
- Without a cable: a `socat` pty pair is a serial line (`socat pty,raw,echo=0,link=/tmp/gw
  pty,raw,echo=0,link=/tmp/plc`); in a pytest suite, the `ncgate_rtu_line` and `rtu_plc`
  fixtures ([testing.md](testing.md)) need nothing installed.
"""


def _shown(value: Any) -> str:
    if isinstance(value, enum.Enum):
        value = value.value
    if isinstance(value, bool):
        return f"`{str(value).lower()}`"
    if isinstance(value, str):
        return f'`"{value}"`'
    if isinstance(value, tuple | frozenset | list):
        return f"`[{', '.join(_shown(v).strip('`') for v in sorted(value))}]`"
    if value is None or value == {}:
        return "—"
    return f"`{value:g}`" if isinstance(value, float) else f"`{value}`"
