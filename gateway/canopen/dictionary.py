"""The CANopen object dictionary of the gateway node (spec 3.3), built from the config.

CiA 301 communication area: 0x1000 device type, 0x1001 error register, 0x1017 producer
heartbeat time, 0x1018 identity, the PDO communication (0x1400/0x1401, 0x1800/0x1801) and
mapping (0x1600/0x1601, 0x1A00/0x1A01) entries.  Manufacturer area: the image (0x2000 SA
bytes, 0x2100+j K bytes, 0x2200+j SYVARs), the command record (0x2400), the process status
records (0x2500+k-1) and the last SND (0x2600).  Sizes follow the image.

The manufacturer objects hold no data of their own: the node reads and writes the live image
and process status through callbacks (``ncgate.gateway.canopen.node``).
"""

from __future__ import annotations

from canopen.objectdictionary import (
    ObjectDictionary,
    ODArray,
    ODRecord,
    ODVariable,
    export_od,
)
from canopen.objectdictionary.datatypes import (
    INTEGER16,
    UNSIGNED8,
    UNSIGNED16,
    UNSIGNED32,
    VISIBLE_STRING,
)

from ncgate import __version__
from ncgate.config import Config
from ncgate.gateway.identity import (
    PRODUCT_CODE,
    PRODUCT_NAME,
    REVISION,
    VENDOR_ID,
    VENDOR_NAME,
)

CHUNK = 128  # K bytes and SYVARs per object (0x2100+j, 0x2200+j)
MAX_PROCESS_STATES_IN_TPDO1 = 8

SA_BYTES, K_BASE, SYVAR_BASE = 0x2000, 0x2100, 0x2200
COMMAND, STATUS_BASE, LAST_SND = 0x2400, 0x2500, 0x2600

_RANGE = {UNSIGNED8: (0, 0xFF), UNSIGNED16: (0, 0xFFFF), UNSIGNED32: (0, 0xFFFFFFFF),
          INTEGER16: (-0x8000, 0x7FFF)}


def _var(name: str, index: int, sub: int, data_type: int, access: str,
         default: int | None = None, pdo: bool = False) -> ODVariable:
    v = ODVariable(name, index, sub)
    v.data_type = data_type
    v.access_type = access
    v.min, v.max = _RANGE[data_type]
    if default is not None:
        v.default = default
    v.pdo_mappable = pdo
    return v


def _string(name: str, index: int, text: str) -> ODVariable:
    """A constant VISIBLE_STRING (read by segmented upload when longer than 4 bytes)."""
    v = ODVariable(name, index, 0)
    v.data_type = VISIBLE_STRING
    v.access_type = "const"
    v.default = text  # type: ignore[assignment]  # canopen's annotation says int; it takes str
    return v


def _record(name: str, index: int, members: list[tuple[str, int, str, int | None]]
            ) -> ODRecord:
    record = ODRecord(name, index)
    record.add_member(_var("Highest sub-index supported", index, 0, UNSIGNED8, "const",
                           len(members)))
    for sub, (member, data_type, access, default) in enumerate(members, start=1):
        record.add_member(_var(member, index, sub, data_type, access, default,
                               pdo=access in ("ro", "rw")))
    return record


def _array(name: str, index: int, count: int, member: str, data_type: int, access: str
           ) -> ODArray:
    array = ODArray(name, index)
    array.add_member(_var("Number of entries", index, 0, UNSIGNED8, "const", count))
    for sub in range(1, count + 1):
        array.add_member(_var(f"{member} {sub - 1}", index, sub, data_type, access, 0,
                              pdo=True))
    return array


def _mapping(name: str, index: int, entries: list[int]) -> ODRecord:
    record = ODRecord(name, index)
    record.add_member(_var("Number of mapped objects", index, 0, UNSIGNED8, "const",
                           len(entries)))
    for sub, entry in enumerate(entries, start=1):
        record.add_member(_var(f"Mapped object {sub}", index, sub, UNSIGNED32, "const", entry))
    return record


def _map_entry(index: int, sub: int, bits: int) -> int:
    return index << 16 | sub << 8 | bits


def chunks(total: int) -> list[tuple[int, int]]:
    """(first element, count) of each object of CHUNK elements."""
    return [(first, min(CHUNK, total - first)) for first in range(0, total, CHUNK)]


def write_eds(config: Config, path: str) -> None:
    """The node's EDS (CiA 306), for CANopen configuration tools (``ncgate eds``)."""
    export_od(build_dictionary(config), path, doc_type="eds")


def build_dictionary(config: Config) -> ObjectDictionary:
    node_id = config.canopen.node_id
    plc, processes = config.plc, config.nc.processes
    od = ObjectDictionary()
    od.node_id = node_id
    od.bitrate = config.canopen.bitrate
    info = od.device_information
    info.vendor_name = VENDOR_NAME
    info.product_name = PRODUCT_NAME
    info.product_number = PRODUCT_CODE
    info.revision_number = REVISION
    info.order_code = "ncgate"
    info.vendor_number = VENDOR_ID
    info.simple_boot_up_slave = True
    info.granularity = 8
    # canopen annotates these counts as bool; the EDS wants the numbers (CiA 306).
    info.nr_of_RXPDO = 2  # type: ignore[assignment]
    info.nr_of_TXPDO = 2  # type: ignore[assignment]
    info.allowed_baudrates = {10000, 20000, 50000, 125000, 250000, 500000, 800000, 1000000}

    od.add_object(_var("Device type", 0x1000, 0, UNSIGNED32, "ro", 0))
    od.add_object(_var("Error register", 0x1001, 0, UNSIGNED8, "ro", 0))
    od.add_object(_string("Manufacturer device name", 0x1008, PRODUCT_NAME))
    od.add_object(_string("Manufacturer hardware version", 0x1009, "none (software node)"))
    od.add_object(_string("Manufacturer software version", 0x100A, __version__))
    od.add_object(_var("COB-ID EMCY", 0x1014, 0, UNSIGNED32, "ro", 0x80 + node_id))
    od.add_object(_var("Producer heartbeat time", 0x1017, 0, UNSIGNED16, "rw",
                       config.canopen.heartbeat_ms))
    od.add_object(_record("Identity object", 0x1018, [
        ("Vendor-ID", UNSIGNED32, "ro", VENDOR_ID),
        ("Product code", UNSIGNED32, "ro", PRODUCT_CODE),
        ("Revision number", UNSIGNED32, "ro", REVISION),
        ("Serial number", UNSIGNED32, "ro", node_id),
    ]))

    # PDOs (spec 3.3 defaults): RPDO1 <- SA bytes 0..7, RPDO2 <- K bytes 0..7,
    # TPDO1 -> process states 1..8 (on change), TPDO2 -> the last SND record (on every SND).
    for n, (cob, mapped) in enumerate((
        (0x200, [_map_entry(SA_BYTES, i, 8) for i in range(1, 9)]),
        (0x300, [_map_entry(K_BASE, i, 8) for i in range(1, 9)]),
    )):
        od.add_object(_record(f"RPDO{n + 1} communication parameter", 0x1400 + n, [
            ("COB-ID used by RPDO", UNSIGNED32, "rw", cob + node_id),
            ("Transmission type", UNSIGNED8, "rw", 255),
        ]))
        od.add_object(_mapping(f"RPDO{n + 1} mapping parameter", 0x1600 + n, mapped))
    states = [_map_entry(STATUS_BASE + k, 1, 8)
              for k in range(min(processes, MAX_PROCESS_STATES_IN_TPDO1))]
    last_snd = [_map_entry(LAST_SND, 1, 32), _map_entry(LAST_SND, 2, 8),
                _map_entry(LAST_SND, 3, 8), _map_entry(LAST_SND, 4, 16)]
    for n, (cob, mapped) in enumerate(((0x180, states), (0x280, last_snd))):
        od.add_object(_record(f"TPDO{n + 1} communication parameter", 0x1800 + n, [
            # bit 30: no RTR (the node does not answer remote frames)
            ("COB-ID used by TPDO", UNSIGNED32, "rw", 0x40000000 | cob + node_id),
            ("Transmission type", UNSIGNED8, "rw", 255),  # event-driven
            ("Inhibit time (100 us)", UNSIGNED16, "rw", 0),
        ]))
        od.add_object(_mapping(f"TPDO{n + 1} mapping parameter", 0x1A00 + n, mapped))

    # Manufacturer area.
    od.add_object(_array("SA bytes", SA_BYTES, plc.sa_bits // 8, "SA byte", UNSIGNED8, "rw"))
    for j, (first, count) in enumerate(chunks(plc.k_bytes)):
        od.add_object(_array(f"K bytes {first}..{first + count - 1}", K_BASE + j, count,
                             "K byte", UNSIGNED8, "rw"))
    for j, (first, count) in enumerate(chunks(plc.syvars)):
        od.add_object(_array(f"SYVAR {first}..{first + count - 1}", SYVAR_BASE + j, count,
                             "SYVAR", INTEGER16, "rw"))
    od.add_object(_record("Command", COMMAND, [
        ("Control word", UNSIGNED16, "wo", None),
        ("SND sender", UNSIGNED8, "wo", None),
        ("SND target", UNSIGNED8, "wo", None),
    ]))
    for k in range(processes):
        od.add_object(_record(f"Process {k + 1} status", STATUS_BASE + k, [
            ("State", UNSIGNED8, "ro", None),
            ("Block N", UNSIGNED16, "ro", None),
            ("Source line", UNSIGNED16, "ro", None),
            ("Wait kind", UNSIGNED8, "ro", None),
            ("Wait target", UNSIGNED8, "ro", None),
            ("Alarm code", UNSIGNED16, "ro", None),
            ("SNDs sent", UNSIGNED32, "ro", None),
            ("SNDs received", UNSIGNED32, "ro", None),
        ]))
    od.add_object(_record("Last SND", LAST_SND, [
        ("Event number", UNSIGNED32, "ro", None),
        ("Sender", UNSIGNED8, "ro", None),
        ("Target", UNSIGNED8, "ro", None),
        ("Block N", UNSIGNED16, "ro", None),
    ]))
    return od


_TYPE_NAMES = {UNSIGNED8: "UNSIGNED8", UNSIGNED16: "UNSIGNED16", UNSIGNED32: "UNSIGNED32",
               INTEGER16: "INTEGER16", VISIBLE_STRING: "VISIBLE_STRING"}


def dictionary_rows(config: Config) -> list[dict[str, object]]:
    """The dictionary for people (``ncgate map``): one row per object, arrays folded."""
    od = build_dictionary(config)
    rows: list[dict[str, object]] = []
    for index in sorted(od):
        obj = od[index]
        if isinstance(obj, ODVariable):
            members = [obj]
        elif isinstance(obj, ODArray):
            first, last = obj.subindices[1], obj.subindices[max(obj.subindices)]
            rows.append({"index": f"0x{index:04X}", "sub": f"1..{last.subindex}",
                         "name": obj.name,
                         "type": f"ARRAY of {_TYPE_NAMES.get(first.data_type or 0, '?')}",
                         "access": first.access_type, "default": first.default})
            continue
        else:
            members = [obj.subindices[s] for s in sorted(obj.subindices) if s]
        for m in members:
            rows.append({"index": f"0x{index:04X}", "sub": str(m.subindex),
                         "name": m.name if isinstance(obj, ODVariable) else f"{obj.name}: {m.name}",
                         "type": _TYPE_NAMES.get(m.data_type or 0, "?"), "access": m.access_type,
                         "default": m.default})
    return rows
