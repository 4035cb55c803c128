"""The CANopen object dictionary of the gateway node (spec 3.3), built from the config.

CiA 301 communication area: 0x1000 device type, 0x1001 error register, 0x1003 error
history, 0x1005..0x1007 and 0x1019 SYNC, 0x1008..0x100A names, 0x1010/0x1011 store and
restore, 0x1014/0x1015 EMCY, 0x1016/0x1017 heartbeats, 0x1018 identity, 0x1029 error
behaviour, 0x1200/0x1201 SDO servers, and the PDO communication (0x1400.., 0x1800..) and
mapping (0x1600.., 0x1A00..) entries of RPDO1..4 and TPDO1..4.  Manufacturer area: the
image (0x2000 SA bytes, 0x2100+j K bytes, 0x2200+j SYVARs), the command record (0x2400), the
process status records (0x2500+k-1), the last SND (0x2600) and the PLC status (0x2700).
Sizes follow the image.

The manufacturer objects hold no data of their own: the node reads and writes the live image
and process status through callbacks (``ncgate.gateway.canopen.node``).
"""

from __future__ import annotations

import io
import os
from datetime import UTC, datetime
from typing import TextIO

from canopen.objectdictionary import (
    ObjectDictionary,
    ODArray,
    ODRecord,
    ODVariable,
)
from canopen.objectdictionary.datatypes import (
    INTEGER16,
    UNSIGNED8,
    UNSIGNED16,
    UNSIGNED32,
    VISIBLE_STRING,
)
from canopen.objectdictionary.eds import export_eds

from ncgate import __version__
from ncgate.config import Config
from ncgate.gateway.identity import (
    PRODUCT_CODE,
    PRODUCT_NAME,
    REVISION,
    VENDOR_ID,
    VENDOR_NAME,
)
from ncgate.inputs import FEED_OVERRIDE_MAX, RAPID_OVERRIDE_MAX

CHUNK = 128  # K bytes and SYVARs per object (0x2100+j, 0x2200+j)
MAX_PROCESS_STATES_IN_TPDO1 = 8
PDO_COUNT = 4  # RPDO1..4, TPDO1..4
MAX_MAPPED = 8  # objects per PDO (granularity 8: whole bytes, at most 8 of them)
CONSUMER_ENTRIES = 4  # 0x1016: nodes whose heartbeat the node watches

SYNC_COB_ID, STORE, RESTORE, CONSUMER_HEARTBEAT = 0x1005, 0x1010, 0x1011, 0x1016
ERROR_BEHAVIOUR = 0x1029
ERROR_HISTORY, EMCY_INHIBIT = 0x1003, 0x1015
SDO_SERVER, SECOND_SDO_SERVER = 0x1200, 0x1201
HISTORY_ENTRIES = 8  # 0x1003: the newest errors kept
# SYNC consumer: communication cycle period (us), synchronous window length (us), SYNC
# counter overflow value (CiA 301 7.5.2.6/7/21).
CYCLE_PERIOD, SYNC_WINDOW, SYNC_OVERFLOW = 0x1006, 0x1007, 0x1019
# 0x1029:1, what a communication error (the master's heartbeat lost) does to the NMT state
# (CiA 301 7.5.2.32): 0 pre-operational (from OPERATIONAL only), 1 no change, 2 stopped.
TO_PRE_OPERATIONAL, NO_STATE_CHANGE, TO_STOPPED = 0, 1, 2
RPDO_COMMUNICATION, RPDO_MAPPING = 0x1400, 0x1600
TPDO_COMMUNICATION, TPDO_MAPPING = 0x1800, 0x1A00

SA_BYTES, K_BASE, SYVAR_BASE = 0x2000, 0x2100, 0x2200
COMMAND, STATUS_BASE, LAST_SND, PLC_STATUS = 0x2400, 0x2500, 0x2600, 0x2700
# The overrides in percent, sub k for process k: feed 0..200, rapid 0..100.
FEED_OVERRIDE, RAPID_OVERRIDE = 0x2410, 0x2411
OVERRIDE_TOP = {FEED_OVERRIDE: FEED_OVERRIDE_MAX, RAPID_OVERRIDE: RAPID_OVERRIDE_MAX}

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


def _record(name: str, index: int, members: list[tuple[str, int, str, int | None]],
            pdo: bool = False) -> ODRecord:
    record = ODRecord(name, index)
    record.add_member(_var("Highest sub-index supported", index, 0, UNSIGNED8, "const",
                           len(members)))
    for sub, (member, data_type, access, default) in enumerate(members, start=1):
        record.add_member(_var(member, index, sub, data_type, access, default, pdo=pdo))
    return record


def _array(name: str, index: int, count: int, member: str, data_type: int, access: str,
           default: int = 0, pdo: bool = True, names: tuple[str, ...] = ()) -> ODArray:
    array = ODArray(name, index)
    array.add_member(_var("Number of entries", index, 0, UNSIGNED8, "const", count))
    for sub in range(1, count + 1):
        label = names[sub - 1] if names else f"{member} {sub - 1}"
        array.add_member(_var(label, index, sub, data_type, access, default, pdo=pdo))
    return array


def _cob_id(name: str, index: int, flags: int, base: int, node_id: int) -> ODVariable:
    """A COB-ID whose default follows the node id: ``$NODEID+0x...`` in the EDS (CiA 306)."""
    v = _var(name, index, 1, UNSIGNED32, "rw", flags | base + node_id)
    _relative(v, flags | base)
    return v


def _relative(v: ODVariable, offset: int) -> None:
    """canopen writes ``default_raw`` to the EDS as it is (its ODVariable sets it on import)."""
    v.default_raw = f"$NODEID+0x{offset:X}"  # type: ignore[attr-defined]
    v.relative = True


def _communication(name: str, index: int, cob: ODVariable, transmit: bool) -> ODRecord:
    """PDO communication parameter (CiA 301 7.5.2.35/36): an RPDO has COB-ID, type and
    event timer (its deadline monitoring), a TPDO also inhibit time and SYNC start value
    (sub 4 is reserved; an RPDO has no sub 3 either)."""
    record = ODRecord(name, index)
    record.add_member(_var("Highest sub-index supported", index, 0, UNSIGNED8, "const",
                           6 if transmit else 5))
    record.add_member(cob)
    record.add_member(_var("Transmission type", index, 2, UNSIGNED8, "rw", 255))
    if transmit:
        record.add_member(_var("Inhibit time", index, 3, UNSIGNED16, "rw", 0))
    record.add_member(_var("Event timer", index, 5, UNSIGNED16, "rw", 0))
    if transmit:
        record.add_member(_var("SYNC start value", index, 6, UNSIGNED8, "rw", 0))
    return record


def _mapping(name: str, index: int, entries: list[int]) -> ODRecord:
    """PDO mapping parameter: sub 0 the number of mapped objects (0..8), subs 1..8 the
    entries (index << 16 | sub-index << 8 | bits); writable while the PDO is disabled."""
    record = ODRecord(name, index)
    count = _var("Number of mapped objects", index, 0, UNSIGNED8, "rw", len(entries))
    count.max = MAX_MAPPED
    record.add_member(count)
    for sub in range(1, MAX_MAPPED + 1):
        entry = entries[sub - 1] if sub <= len(entries) else 0
        record.add_member(_var(f"Mapped object {sub}", index, sub, UNSIGNED32, "rw", entry))
    return record


def map_entry(index: int, sub: int, bits: int) -> int:
    return index << 16 | sub << 8 | bits


def default_mappings(config: Config) -> dict[int, list[int]]:
    """The mapping each PDO has at power-on (spec 3.3), by mapping index."""
    plc, processes = config.plc, config.nc.processes
    return {
        RPDO_MAPPING: [map_entry(SA_BYTES, i, 8) for i in range(1, min(8, plc.sa_bits // 8) + 1)],
        RPDO_MAPPING + 1: [map_entry(K_BASE, i, 8) for i in range(1, min(8, plc.k_bytes) + 1)],
        RPDO_MAPPING + 2: [], RPDO_MAPPING + 3: [],
        TPDO_MAPPING: [map_entry(STATUS_BASE + k, 1, 8)
                       for k in range(min(processes, MAX_PROCESS_STATES_IN_TPDO1))],
        TPDO_MAPPING + 1: [map_entry(LAST_SND, 1, 32), map_entry(LAST_SND, 2, 8),
                           map_entry(LAST_SND, 3, 8), map_entry(LAST_SND, 4, 16)],
        TPDO_MAPPING + 2: [], TPDO_MAPPING + 3: [],
    }


def _pdos(od: ObjectDictionary, config: Config) -> None:
    """RPDO1..4 and TPDO1..4.  Defaults (spec 3.3): RPDO1 <- SA bytes 0..7, RPDO2 <- K bytes
    0..7, TPDO1 -> process states 1..8 (on change), TPDO2 -> the last SND record (on every
    SND); RPDO3/4 and TPDO3/4 are disabled and empty, for the master to map.  TPDO COB-IDs
    have bit 30 set: the node answers no RTR."""
    node_id = config.canopen.node_id
    mappings = default_mappings(config)
    for kind, comm, mapping, base, rtr in (("RPDO", RPDO_COMMUNICATION, RPDO_MAPPING, 0x200, 0),
                                           ("TPDO", TPDO_COMMUNICATION, TPDO_MAPPING, 0x180,
                                            0x40000000)):
        for n in range(PDO_COUNT):
            flags = rtr | (0 if n < 2 else 0x80000000)
            cob = _cob_id(f"COB-ID used by {kind}", comm + n, flags, base + 0x100 * n, node_id)
            od.add_object(_communication(f"{kind}{n + 1} communication parameter", comm + n,
                                         cob, transmit=kind == "TPDO"))
            od.add_object(_mapping(f"{kind}{n + 1} mapping parameter", mapping + n,
                                   mappings[mapping + n]))


def image_target(index: int, subindex: int) -> tuple[str, int, str]:
    """The image variable behind a manufacturer object's sub-index (0x2000..0x23FF):
    (area, index, view) as ``IOImage.read``/``write`` take it."""
    if index == SA_BYTES:
        return ("SA", subindex - 1, "BY")
    if index < SYVAR_BASE:
        return ("SK", (index - K_BASE) * CHUNK + subindex - 1, "BY")
    return ("SYVAR", (index - SYVAR_BASE) * CHUNK + subindex - 1, "IN")


def chunks(total: int) -> list[tuple[int, int]]:
    """(first element, count) of each object of CHUNK elements."""
    return [(first, min(CHUNK, total - first)) for first in range(0, total, CHUNK)]


def write_eds(config: Config, path: str, out: TextIO | None = None) -> None:
    """The node's EDS (CiA 306), for CANopen configuration tools (``ncgate eds``), into the
    file ``path`` -- or into ``out`` (standard output for ``-o -``), ``path`` then only its
    [FileInfo] FileName.

    [FileInfo] and [DeviceInfo] carry CiA 306's whole keyword sets; the dates are today's
    (or ``SOURCE_DATE_EPOCH``'s, for a reproducible file); COB-IDs are ``$NODEID+...``.
    """
    od = build_dictionary(config)
    info = od.device_information
    info.simple_boot_up_master = False
    info.dynamic_channels_supported = False
    info.group_messaging = False
    info.LSS_supported = False
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    when = (datetime.fromtimestamp(int(epoch), UTC) if epoch
            else datetime.now(UTC))
    date, clock = when.strftime("%m-%d-%Y"), when.strftime("%I:%M%p")
    file_info = {
        "FileName": os.path.basename(path),
        "FileVersion": 1,
        "FileRevision": 0,
        "EDSVersion": "4.0",
        "Description": f"{PRODUCT_NAME} {__version__}: Modbus/CANopen gateway of a "
                       f"multi-process CNC simulator",
        "CreationTime": clock, "CreationDate": date, "CreatedBy": f"ncgate {__version__}",
        "ModificationTime": clock, "ModificationDate": date,
        "ModifiedBy": f"ncgate {__version__}",
    }
    text = io.StringIO()
    export_eds(od, text, file_info=file_info)
    lines = _cia306(text.getvalue().splitlines(keepends=True))
    if out is not None:
        out.write("".join(lines))
        return
    with open(path, "w", encoding="utf-8") as file:
        file.writelines(lines)


# The dummy types an RPDO may map to skip bytes (pdo.py's _DUMMY_BITS): 0x0002..0x0007.
DUMMIES = range(0x0002, 0x0008)


def _cia306(lines: list[str]) -> list[str]:
    """canopen's EDS, put right where it strays from CiA 306 (eds-utils' ``eds-validate``
    checks these): ``PDOMapping`` is a boolean written ``0``/``1`` (canopen writes
    ``0x0``/``0x1``); ``[DummyUsage]`` says which dummies the RPDOs accept (canopen writes 1
    only for dummies in the dictionary, and the node has none to read); a mapping entry's
    default is a full UNSIGNED32 (``0x00000000``, not ``0x00``).  canopen's own
    ``EdsVersion`` beside CiA 306's ``EDSVersion`` goes: one is kept."""
    out, section = [], ""
    for line in lines:
        if line.startswith("EdsVersion="):
            continue
        if line.startswith("["):
            section = line.strip()[1:-1]
        key, _, value = line.rstrip("\n").partition("=")
        if key == "PDOMapping":
            line = f"PDOMapping={int(value, 0)}\n"
        elif section == "DummyUsage" and key.startswith("Dummy"):
            line = f"{key}={int(int(key[5:], 16) in DUMMIES)}\n"
        elif (key == "DefaultValue" and section[:2] in ("16", "1A")
              and section[4:7] == "sub" and int(section[7:], 16) != 0):
            line = f"DefaultValue=0x{int(value, 0):08X}\n"  # a mapping entry
        out.append(line)
    return out


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
    info.nr_of_RXPDO = PDO_COUNT  # type: ignore[assignment]
    info.nr_of_TXPDO = PDO_COUNT  # type: ignore[assignment]
    info.allowed_baudrates = {10000, 20000, 50000, 125000, 250000, 500000, 800000, 1000000}

    od.add_object(_var("Device type", 0x1000, 0, UNSIGNED32, "ro", 0))
    od.add_object(_var("Error register", 0x1001, 0, UNSIGNED8, "ro", 0))
    # Pre-defined error field (CiA 301 7.5.2.4): sub 0 the number of errors recorded (writing
    # 0 clears them), subs 1.. the errors, newest first (read by the node's callback).
    history = ODArray("Pre-defined error field", ERROR_HISTORY)
    history.add_member(_var("Number of errors", ERROR_HISTORY, 0, UNSIGNED8, "rw", 0))
    for sub in range(1, HISTORY_ENTRIES + 1):
        history.add_member(_var(f"Standard error field {sub}", ERROR_HISTORY, sub, UNSIGNED32,
                                "ro", 0))
    od.add_object(history)
    od.add_object(_string("Manufacturer device name", 0x1008, PRODUCT_NAME))
    od.add_object(_string("Manufacturer hardware version", 0x1009, "none (software node)"))
    od.add_object(_string("Manufacturer software version", 0x100A, __version__))
    emcy = _var("COB-ID EMCY", 0x1014, 0, UNSIGNED32, "ro", 0x80 + node_id)
    _relative(emcy, 0x80)
    od.add_object(emcy)
    od.add_object(_var("Inhibit time EMCY", EMCY_INHIBIT, 0, UNSIGNED16, "rw", 0))  # 100 us
    od.add_object(_var("Producer heartbeat time", 0x1017, 0, UNSIGNED16, "rw",
                       config.canopen.heartbeat_ms))
    od.add_object(_record("Identity object", 0x1018, [
        ("Vendor-ID", UNSIGNED32, "ro", VENDOR_ID),
        ("Product code", UNSIGNED32, "ro", PRODUCT_CODE),
        ("Revision number", UNSIGNED32, "ro", REVISION),
        ("Serial number", UNSIGNED32, "ro", node_id),
    ]))

    # SYNC consumer (the node produces no SYNC: bit 30 stays clear).
    od.add_object(_var("COB-ID SYNC message", SYNC_COB_ID, 0, UNSIGNED32, "rw", 0x80))
    od.add_object(_var("Communication cycle period", CYCLE_PERIOD, 0, UNSIGNED32, "rw", 0))
    od.add_object(_var("Synchronous window length", SYNC_WINDOW, 0, UNSIGNED32, "rw", 0))
    od.add_object(_var("Synchronous counter overflow value", SYNC_OVERFLOW, 0, UNSIGNED8,
                       "rw", 0))
    # Store / restore the communication parameters (CiA 301 7.5.2.13/14): sub 1 all, sub 2
    # communication; reading 1 says "saves on command".
    for index, name in ((STORE, "Store parameters"), (RESTORE, "Restore default parameters")):
        od.add_object(_array(name, index, 2, "", UNSIGNED32, "rw", default=1, pdo=False,
                             names=("all parameters", "communication parameters")))
    od.add_object(_array("Consumer heartbeat time", CONSUMER_HEARTBEAT, CONSUMER_ENTRIES,
                         "Consumer heartbeat time", UNSIGNED32, "rw", default=0, pdo=False))
    # Error behaviour: CiA 301's default reaction to a communication error, pre-operational.
    od.add_object(_array("Error behaviour", ERROR_BEHAVIOUR, 1, "", UNSIGNED8, "rw",
                         default=TO_PRE_OPERATIONAL, pdo=False,
                         names=("Communication error",)))
    # SDO server parameters (CiA 301 7.5.2.33): the default server (its COB-IDs follow the
    # node id), and a second one, off until a master gives it COB-IDs of its own.
    server = ODRecord("SDO server parameter", SDO_SERVER)
    server.add_member(_var("Highest sub-index supported", SDO_SERVER, 0, UNSIGNED8, "const",
                           2))
    for sub, (name, base) in enumerate((("COB-ID client to server", 0x600),
                                        ("COB-ID server to client", 0x580)), start=1):
        member = _var(name, SDO_SERVER, sub, UNSIGNED32, "const", base + node_id)
        _relative(member, base)
        server.add_member(member)
    od.add_object(server)
    od.add_object(_record("SDO server parameter 2", SECOND_SDO_SERVER, [
        ("COB-ID client to server", UNSIGNED32, "rw", 0x80000000),
        ("COB-ID server to client", UNSIGNED32, "rw", 0x80000000),
        ("Node-ID of the SDO client", UNSIGNED8, "rw", 0),
    ]))
    _pdos(od, config)
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
        ("Search N", UNSIGNED16, "rw", 0),
    ]))
    for index, what in ((FEED_OVERRIDE, "Feed override"), (RAPID_OVERRIDE, "Rapid override")):
        od.add_object(_array(f"{what} (percent)", index, processes, what, UNSIGNED8, "rw",
                             default=100, pdo=False,
                             names=tuple(f"{what} P{k + 1}" for k in range(processes))))
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
        ], pdo=True))
    od.add_object(_record("Last SND", LAST_SND, [
        ("Event number", UNSIGNED32, "ro", None),
        ("Sender", UNSIGNED8, "ro", None),
        ("Target", UNSIGNED8, "ro", None),
        ("Block N", UNSIGNED16, "ro", None),
    ], pdo=True))
    od.add_object(_record("PLC status", PLC_STATUS, [
        ("State", UNSIGNED8, "ro", None),
        ("Scans", UNSIGNED32, "ro", None),
        ("Last scan us", UNSIGNED32, "ro", None),
        ("Max scan us", UNSIGNED32, "ro", None),
        ("Overruns", UNSIGNED32, "ro", None),
        ("Fault line", UNSIGNED16, "ro", None),
    ], pdo=True))
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
