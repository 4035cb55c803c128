"""The Modbus map (spec 3.2): which address is what, and reading and writing it.

Protocol-free: it works on the four Modbus tables with 0-based addresses and returns values or
a Modbus exception code; ``ncgate.gateway.modbus.server`` does the wire.  Every write of one request
is validated whole and then applied with one image write (spec 3.1: atomic, named writer).

Decisions where the spec is silent (docs/decisions.md): a process's block of discrete inputs
is 16 wide and of input registers 20 wide; the addresses a block does not use read 0, so a
dashboard can read all processes in one request.  The command word and the SND mailbox read 0.
"""

from __future__ import annotations

import csv
import enum
import io
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass

from ncgate import commands
from ncgate.config import Config, ConfigError
from ncgate.gateway.door import search_inputs
from ncgate.gateway.errors import ModbusError
from ncgate.gateway.modbus.codes import ILLEGAL_ADDRESS, ILLEGAL_VALUE, command_word
from ncgate.gateway.plc import PLC_REGISTERS
from ncgate.gateway.view import FLAGS as PROCESS_FLAGS
from ncgate.gateway.view import RECORD, CellStatus, ViewPublisher, status_registers
from ncgate.gateway.wiring import Backend
from ncgate.inputs import (
    FEED_OVERRIDE_MAX,
    RAPID_OVERRIDE_MAX,
    Command,
    Force,
    Override,
    Snd,
    Source,
    Var,
    Writes,
)
from ncgate.interpreter.engine.sync import SND_LOG

MAP_VERSION = 1



class Table(enum.Enum):
    COILS = "coils"
    DISCRETE_INPUTS = "discrete inputs"
    HOLDING = "holding registers"
    INPUT = "input registers"

    # A member is its one instance: hashed by identity, in C (Enum's own hashes the name in
    # Python, on the path of every register read: ModbusMap.read's cache key).
    __hash__ = object.__hash__

    @property
    def prefix(self) -> int:
        """The leading digit of the 1-based numbers people type into HMIs."""
        return {Table.COILS: 0, Table.DISCRETE_INPUTS: 1, Table.INPUT: 3, Table.HOLDING: 4}[self]


class Kind(enum.Enum):
    SA_BITS = "SA bits"
    PROCESS_FLAGS = "process flags"
    K_BYTES = "K bytes"
    SYVARS = "SYVARs"
    SA_BYTES = "SA bytes"
    COMMAND = "command"
    MAILBOX = "SND mailbox"
    INFO = "gateway info"
    PROCESS_STATUS = "process status"
    SND_LOG = "SND log"
    PLC_STATUS = "PLC status"
    OVERRIDES = "overrides"
    SEARCH = "search"
    FORCE_REQUEST = "force request"
    FORCE_LIST = "force list"


@dataclass(frozen=True, slots=True)
class Region:
    table: Table
    start: int
    count: int
    kind: Kind
    access: str  # "rw", "r", "w"
    type: str  # "bit", "uint8", "int16", "uint16", "u32+i32 record", …
    content: str

    @property
    def end(self) -> int:
        return self.start + self.count

    @property
    def name(self) -> str:
        """Its name in the config (modbus.map.read_only, modbus.roles); "" if not writable."""
        return REGION_NAMES.get(self.kind, "")

    def hmi(self, address: int) -> str:
        """The 1-based 5/6-digit number of an address (e.g. holding 0 -> 400001)."""
        number = address + 1
        width = 5 if number <= 9999 else 6
        return f"{self.table.prefix}{number:0{width - 1}d}"


REGION_NAMES = {Kind.SA_BITS: "sa_bits", Kind.K_BYTES: "k_bytes", Kind.SYVARS: "syvars",
                Kind.SA_BYTES: "sa_bytes", Kind.COMMAND: "command", Kind.MAILBOX: "mailbox",
                Kind.OVERRIDES: "overrides", Kind.SEARCH: "command",
                Kind.FORCE_REQUEST: "force", Kind.FORCE_LIST: "force"}
# The status block: the view's record, a 32-bit entry as two registers, high word first.
PROCESS_REGISTERS = tuple(name for entry, bits in RECORD for name in (
    (f"{entry} (hi)", f"{entry} (lo)") if bits == 32 else (entry,)))
# The config key that places each movable region (modbus.map.*), in the order a clash is
# reported; "info" (input 0..8) does not move.
_LAYOUT_KEYS = {Kind.K_BYTES: "k_bytes", Kind.SYVARS: "syvars", Kind.SA_BYTES: "sa_bytes",
                Kind.COMMAND: "command", Kind.MAILBOX: "command",
                Kind.PROCESS_STATUS: "status", Kind.SND_LOG: "snd_log",
                Kind.PLC_STATUS: "plc_status", Kind.INFO: "info", Kind.OVERRIDES: "overrides",
                Kind.SEARCH: "command", Kind.FORCE_REQUEST: "force", Kind.FORCE_LIST: "force"}
# The force table (docs/decisions.md): a request's action, and the kinds of variable a
# request or a listed force names, by their register value.
FORCE_ACTIONS = {1: "force", 2: "release", 3: "release every one"}
FORCE_KINDS = {1: ("SA", "bit"), 2: ("SA", "BY"), 3: ("SA", "IN"), 4: ("SK", "BY"),
               5: ("SK", "IN"), 6: ("SYVAR", "IN")}
_FORCE_KIND_OF = {place: kind for kind, place in FORCE_KINDS.items()}
FORCE_LISTED = 32  # the forces the table shows (the count at +4 says how many there are)
# The register regions whose values are the image's, or always 0: what they read changes only
# with the image's generation (ModbusMap.read).  The search N and the status regions (the
# view's) are not among them.
_IMAGE_ALONE = frozenset({Kind.K_BYTES, Kind.SA_BYTES, Kind.SYVARS, Kind.COMMAND, Kind.MAILBOX,
                          Kind.FORCE_REQUEST})


class ModbusMap:
    """The map in force for a config."""

    STATUS_STRIDE, FLAGS_STRIDE = 20, 16
    STATUS_PADDING = (0,) * (STATUS_STRIDE - len(PROCESS_REGISTERS))  # +18..19 read 0
    LOG_ENTRY = 6  # registers of one SND log entry
    LOG_SIZE = 2 + SND_LOG * LOG_ENTRY

    def __init__(self, config: Config) -> None:
        self.config = config
        plc, processes = config.plc, config.nc.processes
        layout = config.modbus.map
        self.K_BASE, self.SYVAR_BASE, self.SA_BYTE_BASE = (
            layout.k_bytes, layout.syvars, layout.sa_bytes)
        self.COMMAND, self.MAILBOX = layout.command, layout.command + 1
        self.OVERRIDES = layout.overrides
        self.SEARCH = layout.command + 3
        self.FORCE = layout.force
        self.search_n = 0  # the N number command words 13/14 use
        self.STATUS_BASE = layout.status
        self.SND_LOG_BASE, self.PLC_BASE = layout.input_bases(processes)
        sa_bytes = plc.sa_bits // 8
        every = config.modbus.read_only

        def access(name: str, normal: str) -> str:
            return "r" if every or name in layout.read_only else normal

        self.regions = [
            Region(Table.COILS, 0, plc.sa_bits, Kind.SA_BITS, access("sa_bits", "rw"), "bit",
                   "SA bit n"),
            Region(Table.DISCRETE_INPUTS, 0, self.FLAGS_STRIDE * processes,
                   Kind.PROCESS_FLAGS, "r", "bit",
                   "process k at 16(k-1)+0..5: " + ", ".join(PROCESS_FLAGS)
                   + "; +6..15 read 0"),
            Region(Table.HOLDING, self.K_BASE, plc.k_bytes, Kind.K_BYTES,
                   access("k_bytes", "rw"), "uint8", "K byte n (0..255)"),
            Region(Table.HOLDING, self.SYVAR_BASE, plc.syvars, Kind.SYVARS,
                   access("syvars", "rw"), "int16", "SYVAR n"),
            Region(Table.HOLDING, self.SA_BYTE_BASE, sa_bytes, Kind.SA_BYTES,
                   access("sa_bytes", "rw"), "uint8",
                   "SA byte n (bits 8n..8n+7, the same bits as the coils)"),
            Region(Table.HOLDING, self.COMMAND, 1, Kind.COMMAND, access("command", "w"),
                   "uint16", f"command: {commands.summary()}; high byte: the process, 0 "
                   f"the cell (reads 0)"),
            Region(Table.HOLDING, self.MAILBOX, 2, Kind.MAILBOX, access("mailbox", "w"),
                   "uint16", "SND mailbox: sender, target in one FC16 (reads 0)"),
            Region(Table.HOLDING, self.SEARCH, 1, Kind.SEARCH, access("command", "rw"),
                          "uint16", "the N number of command words " + ", ".join(
                       f"{c.word} ({c.title})" for c in commands.COMMANDS if c.with_n)),
            Region(Table.HOLDING, self.OVERRIDES, 2 * processes, Kind.OVERRIDES,
                   access("overrides", "rw"), "uint16",
                   f"process k at {self.OVERRIDES}+2(k-1): feed override (0..200 %), rapid "
                   "override (0..100 %); in force from the next interpolation step"),
            Region(Table.HOLDING, self.FORCE, 4, Kind.FORCE_REQUEST, access("force", "w"),
                   "uint16", "force request, one FC16 of 4: action (1 force, 2 release, 3 "
                   "release every one), kind (1 SA bit, 2 SA byte, 3 SA word, 4 K byte, 5 K "
                   "word, 6 SYVAR), index, value (words as int16) (reads 0)"),
            Region(Table.HOLDING, self.FORCE + 4, 1 + 3 * FORCE_LISTED, Kind.FORCE_LIST, "r",
                   "uint16", f"the force list: how many variables are forced, then the first "
                   f"{FORCE_LISTED} in address order (SA, SK, SYVAR), 3 registers each: kind, "
                   "index, value; unused entries read 0"),
            Region(Table.INPUT, 0, 9, Kind.INFO, "r", "uint16",
                   "0 map version, 1 process count, 2-3 event counter (u32), "
                   "4-7 last SND: sender, target, block N, event number (low 16 bits), "
                   "8 how far the engine is behind the clock (ms of machine time; 0: on time)"),
            Region(Table.INPUT, self.STATUS_BASE, self.STATUS_STRIDE * processes,
                   Kind.PROCESS_STATUS, "r", "record",
                   f"process k at {self.STATUS_BASE}+20(k-1)+0..17: "
                   + ", ".join(PROCESS_REGISTERS)
                   + "; +18..19 read 0"),
            Region(Table.INPUT, self.SND_LOG_BASE, self.LOG_SIZE, Kind.SND_LOG, "r", "record",
                   f"SND log: {self.SND_LOG_BASE}-{self.SND_LOG_BASE + 1} sequence number of "
                   f"the newest SND (u32, 0: none yet), then the last {SND_LOG} SNDs, newest "
                   f"first, {self.LOG_ENTRY} registers each: sequence (u32), sender, target, "
                   "block N, id (0 for an SND); unused entries read 0"),
            Region(Table.INPUT, self.PLC_BASE, len(PLC_REGISTERS), Kind.PLC_STATUS, "r",
                   "record", f"PLC status at {self.PLC_BASE}+0..{len(PLC_REGISTERS) - 1}: "
                   + ", ".join(PLC_REGISTERS)),
        ]
        # (table, address, count) -> its segments and whether they read the image alone (read):
        # a bounded cache of the ranges clients read.
        self._pieces: dict[tuple[Table, int, int],
                           tuple[list[tuple[Region, int, int]], bool]] = {}
        self._check_layout()

    def _check_layout(self) -> None:
        """Refuse regions that overlap or run past 65535, naming the key that moves one.

        Here and not in the config loader: only a served map must fit, so ``check`` and
        ``sim`` take a config (16 processes, a moved region) whose map would not."""
        source = str(self.config.source) if self.config.source else "<built-in default>"
        for table in Table:
            # Each region under the key that moves it (the mailbox moves with the command);
            # the info block is fixed, so it is named last and never blamed.
            placed: dict[str, tuple[int, int]] = {}
            for r in self.regions:
                if r.table is table and r.kind in _LAYOUT_KEYS:
                    key = _LAYOUT_KEYS[r.kind]
                    start, end = placed.get(key, (r.start, r.end))
                    placed[key] = (min(start, r.start), max(end, r.end))
            order = sorted(placed, key=list(_LAYOUT_KEYS.values()).index)
            for i, name in enumerate(order):
                start, end = placed[name]
                if end > 65536:
                    raise ConfigError(f"{source}: modbus.map.{name}: {start}..{end - 1} runs "
                                      "past address 65535")
                for other in order[i + 1:]:
                    o_start, o_end = placed[other]
                    if start < o_end and o_start < end:
                        raise ConfigError(
                            f"{source}: modbus.map.{name}: {name} ({start}..{end - 1}) "
                            f"overlaps {other} ({o_start}..{o_end - 1})")

    def region(self, table: Table, address: int, count: int) -> Region:
        """The one region holding the whole range, or ModbusError(02)."""
        for r in self.regions:
            if r.table is table and r.start <= address and address + count <= r.end:
                return r
        raise ModbusError(ILLEGAL_ADDRESS, f"{table.value} {address}..{address + count - 1} "
                          "is not wholly mapped")

    def segments(self, table: Table, address: int, count: int) -> list[tuple[Region, int, int]]:
        """The range cut at region borders: (region, address, count) pieces; ModbusError(02)
        unless every address is mapped.  Adjacent regions may be read (or written) together."""
        out = []
        end = address + count
        while address < end:
            for r in self.regions:
                if r.table is table and r.start <= address < r.end:
                    n = min(end, r.end) - address
                    out.append((r, address, n))
                    address += n
                    break
            else:
                raise ModbusError(ILLEGAL_ADDRESS, f"{table.value} address {address} is not "
                                  "mapped")
        return out

    # -- reading ------------------------------------------------------------------------------

    def read_bits(self, backend: Backend, table: Table, address: int, count: int) -> list[bool]:
        region = self.region(table, address, count)
        if region.kind is Kind.SA_BITS:
            sa = backend.image.sa
            return [bool(sa[i >> 3] >> (i & 7) & 1) for i in range(address, address + count)]
        views = backend.views
        out = []
        for a in range(address, address + count):
            k, bit = divmod(a, self.FLAGS_STRIDE)
            out.append(bit < len(PROCESS_FLAGS) and views.process(k + 1).flags[bit])
        return out

    def read_registers(self, backend: Backend, table: Table, address: int,
                       count: int) -> list[int]:
        return self.read(backend, table, address, count)[0]

    def read(self, backend: Backend, table: Table, address: int,
             count: int) -> tuple[list[int], bool]:
        """The registers of a range, and whether they read the image alone (K bytes, SA
        bytes, SYVARs and the registers that read 0): then they stay the same while the
        image's generation does (``IOImage.generation``, +1 on every write that changed a
        value, whoever wrote it), and the server may answer the same read with the same
        bytes until it moves."""
        key = (table, address, count)
        pieces = self._pieces.get(key)
        if pieces is None:  # pollers read the same ranges again and again: remember them
            segments = self.segments(table, address, count)
            pieces = (segments, all(r.kind in _IMAGE_ALONE for r, _, _ in segments))
            if len(self._pieces) >= 4096:
                self._pieces.clear()
            self._pieces[key] = pieces
        segments, steady = pieces
        if len(segments) == 1:
            return self._read_region(backend, *segments[0]), steady
        out: list[int] = []
        for piece in segments:
            out += self._read_region(backend, *piece)
        return out, steady

    def _read_region(self, backend: Backend, region: Region, address: int,
                     count: int) -> list[int]:
        image = backend.image
        first = address - region.start
        kind = region.kind
        if kind is Kind.K_BYTES:
            return list(image.k[first:first + count])
        if kind is Kind.SA_BYTES:
            return list(image.sa[first:first + count])
        if kind is Kind.SYVARS:
            return [v & 0xFFFF for v in image.syvar[first:first + count]]
        if kind in (Kind.COMMAND, Kind.MAILBOX, Kind.FORCE_REQUEST):
            return [0] * count
        if kind is Kind.SEARCH:
            return [self.search_n]
        # The rest is the cell's status: the parts of its view a region shows, each built
        # once for however many reads (a poller of the PLC block builds no process's view).
        views = backend.views
        if kind is Kind.FORCE_LIST:
            return force_list_registers(views.status().forced)[first:first + count]
        if kind is Kind.INFO:
            return _info(views.status(), self.config.nc.processes)[first:first + count]
        if kind is Kind.SND_LOG:
            return snd_log_registers(views.status())[first:first + count]
        if kind is Kind.PLC_STATUS:
            return list(views.status().plc_registers[first:first + count])
        if kind is Kind.OVERRIDES:
            values = [v for k in range(1, self.config.nc.processes + 1)
                      for v in (views.process(k).feed_override, views.process(k).rapid_override)]
            return values[first:first + count]
        return self._status_registers(views, address, count)

    def _status_registers(self, views: ViewPublisher, address: int, count: int) -> list[int]:
        """The status blocks of the processes the range covers, whole, then cut."""
        stride = self.STATUS_STRIDE
        first = address - self.STATUS_BASE
        k, offset = divmod(first, stride)
        out: list[int] = []
        while len(out) < offset + count:
            k += 1
            out += process_registers(views, k)
            out += self.STATUS_PADDING
        return out[offset:offset + count]

    # -- writing ------------------------------------------------------------------------------

    def write_bits(self, backend: Backend, address: int, values: Sequence[bool],
                   source: Source) -> None:
        region = self.region(Table.COILS, address, len(values))  # one region: the coils
        if "w" not in region.access:
            raise ModbusError(ILLEGAL_ADDRESS, "read-only")
        at = Var.at
        backend.apply(Writes(tuple((at("SA", address + i, "bit"), int(v))
                                   for i, v in enumerate(values)), source))

    def _image_changes(self, address: int, values: Sequence[int]
                       ) -> list[tuple[Var, int]] | tuple[Region, int]:
        """The image writes of a holding-register write, validated whole; or the one action
        region (command, mailbox) it addresses with the offset into it."""
        pieces = self.segments(Table.HOLDING, address, len(values))
        changes: list[tuple[Var, int]] = []
        for region, start, count in pieces:
            if "w" not in region.access:
                raise ModbusError(ILLEGAL_ADDRESS, f"{region.kind.value} is read-only")
            kind = region.kind
            if kind in (Kind.COMMAND, Kind.MAILBOX, Kind.OVERRIDES, Kind.SEARCH,
                        Kind.FORCE_REQUEST):
                if len(pieces) > 1:
                    raise ModbusError(ILLEGAL_ADDRESS, f"the {kind.value} must be written on "
                                      "its own")
                return region, start - region.start
            first = start - region.start
            chunk = values[start - address:start - address + count]
            if kind is Kind.SYVARS:
                changes += [(Var.at("SYVAR", first + i, "IN"),
                             v - 0x10000 if v & 0x8000 else v) for i, v in enumerate(chunk)]
                continue
            if any(v > 255 for v in chunk):
                raise ModbusError(ILLEGAL_VALUE, f"{kind.value} hold 0..255")
            area = "SK" if kind is Kind.K_BYTES else "SA"
            changes += [(Var.at(area, first + i, "BY"), v) for i, v in enumerate(chunk)]
        return changes

    def _overrides(self, backend: Backend, offset: int, values: Sequence[int],
                   source: Source) -> None:
        """Feed and rapid of each process the write covers, checked whole first (nothing of
        a bad write is applied), then one Override input per process."""
        per_process: dict[int, dict[str, int]] = {}
        views = backend.views
        for i, value in enumerate(values):
            k, which = divmod(offset + i, 2)
            if views.process(k + 1).external:
                raise ModbusError(ILLEGAL_VALUE, f"process {k + 1} is external: it has no "
                                  "motion to override")
            name, top = (("feed", FEED_OVERRIDE_MAX) if which == 0 else
                         ("rapid", RAPID_OVERRIDE_MAX))
            if value > top:
                raise ModbusError(ILLEGAL_VALUE, f"{name} override of process {k + 1}: "
                                  f"0..{top} %")
            per_process.setdefault(k + 1, {})[name] = value
        for k, given in per_process.items():
            backend.apply(Override(given.get("feed"), given.get("rapid"), k, source))

    def write_registers(self, backend: Backend, address: int, values: Sequence[int],
                        source: Source) -> None:
        count = len(values)
        planned = self._image_changes(address, values)
        if isinstance(planned, list):
            backend.apply(Writes(tuple(planned), source))
            return
        region, offset = planned
        kind = region.kind
        if kind is Kind.OVERRIDES:
            self._overrides(backend, offset, values, source)
        elif kind is Kind.SEARCH:
            (self.search_n,) = values
        elif kind is Kind.FORCE_REQUEST:
            backend.apply(self._force_request(offset, values, source))
        elif kind is Kind.COMMAND:
            (word,) = values
            searched = search_inputs(word, self.search_n, backend.runtime, source)
            if searched is not None:
                for item in searched:
                    backend.apply(item)
                return
            command = command_word(word)
            if command is None:
                raise ModbusError(ILLEGAL_VALUE, f"command: {commands.summary()} (high byte: "
                                  "the process, 0 for the cell)")
            backend.apply(Command(command[0], command[1], source))  # refusals: REFUSAL
        else:  # the mailbox: sender and target in one write
            if count != 2 or offset != 0:
                raise ModbusError(ILLEGAL_ADDRESS, "the mailbox takes sender and target in one "
                                  f"FC16 at {self.MAILBOX}..{self.MAILBOX + 1}")
            sender, target = values
            backend.apply(Snd(sender, target, source))  # refusals: codes.REFUSAL

    def _force_request(self, offset: int, values: Sequence[int], source: Source) -> Force:
        """The Force input a force request asks for (the door checks the variable)."""
        if len(values) != 4 or offset != 0:
            raise ModbusError(ILLEGAL_ADDRESS, "a force request is action, kind, index, value "
                              f"in one FC16 at {self.FORCE}..{self.FORCE + 3}")
        action, kind, index, value = values
        if action not in FORCE_ACTIONS:
            raise ModbusError(ILLEGAL_VALUE, "force request action: 1 force, 2 release, "
                              "3 release every one")
        if action == 3:
            return Force(None, None, source)
        if kind not in FORCE_KINDS:
            raise ModbusError(ILLEGAL_VALUE, "force request kind: 1 SA bit, 2 SA byte, 3 SA "
                              "word, 4 K byte, 5 K word, 6 SYVAR")
        area, view = FORCE_KINDS[kind]
        if view == "IN" and value & 0x8000:
            value -= 0x10000  # a word is int16, as the SYVAR registers hold it
        return Force(Var.at(area, index, view), value if action == 1 else None, source)

    def check_register_values(self, address: int, values: Sequence[int]) -> None:
        """Validate a write without doing it (FC23 checks its write before anything happens;
        FC22 its computed value).  Commands and the mailbox are checked when done."""
        self._image_changes(address, values)

    # -- for people: `ncgate map` -------------------------------------------------------------

    def rows(self) -> list[dict[str, object]]:
        """The regions, then a row for each I/O name of ``[symbols]`` at its address."""
        rows: list[dict[str, object]] = [{
            "table": r.table.value, "start": r.start, "end": r.end - 1, "count": r.count,
            "hmi_start": r.hmi(r.start), "hmi_end": r.hmi(r.end - 1), "type": r.type,
            "access": {"rw": "read/write", "r": "read", "w": "write"}[r.access],
            "content": r.content, "name": "", "comment": "",
        } for r in self.regions]
        comments = self.config.symbols.comments
        for name, text in self.config.symbols.items():
            place = self._symbol_place(text)
            if place is None:
                continue
            region, address, count = place
            rows.append({
                "table": region.table.value, "start": address, "end": address + count - 1,
                "count": count, "hmi_start": region.hmi(address),
                "hmi_end": region.hmi(address + count - 1), "type": region.type,
                "access": {"rw": "read/write", "r": "read", "w": "write"}[region.access],
                "content": f"{name} ({text}): an I/O name of [symbols]", "name": name,
                "comment": comments.get(name, "")})
        return rows + self._aux_rows()

    def _aux_rows(self) -> list[dict[str, object]]:
        """A row for each process's auxiliary-function values, strobes and acknowledges
        ([nc.aux]; M, S, T, H in that order)."""
        aux = self.config.nc.aux_interface
        rows: list[dict[str, object]] = []
        if aux is None:
            return rows
        for k in range(1, self.config.nc.processes + 1):
            (area, index, _), strobe, ack = aux.place(k, "M")
            first = f"SYVAR{index}" if area == "SYVAR" else f"SK{index}.IN"
            words = aux.words
            for text, count, what in (
                    (first, 4 * words, "the values of M, S, T, H output (written by the NC)"
                     + ("; two words each, the high one first" if words == 2 else "")),
                    (f"SA{strobe}", 4, "the strobes of M, S, T, H (set by the NC)"),
                    (f"SA{ack}", 4, "the acknowledges of M, S, T, H (set by the PLC)")):
                place = self._symbol_place(text)
                if place is None:
                    continue
                region, address, width = place
                end = address + count * width - 1
                rows.append({
                    "table": region.table.value, "start": address, "end": end,
                    "count": count * width, "hmi_start": region.hmi(address),
                    "hmi_end": region.hmi(end), "type": region.type,
                    "access": {"rw": "read/write", "r": "read", "w": "write"}[region.access],
                    "content": f"P{k} auxiliary functions ([nc.aux]): {what}", "name": "",
                    "comment": ""})
        return rows

    def _symbol_place(self, text: str) -> tuple[Region, int, int] | None:
        """Where an image variable (as [symbols] names it) is on the map."""
        m = re.fullmatch(r"(SYVAR|SA|SK|K)(\d+)(?:\.(BY|IN))?", text.upper())
        if m is None:
            return None
        area, index, view = m.group(1), int(m.group(2)), m.group(3)
        kind, address, count = {
            "SYVAR": (Kind.SYVARS, self.SYVAR_BASE + index, 1),
            "SA": ((Kind.SA_BYTES, self.SA_BYTE_BASE + index, 1) if view else
                   (Kind.SA_BITS, index, 1)),
        }.get(area, (Kind.K_BYTES, self.K_BASE + index, 2 if view == "IN" else 1))
        region = next((r for r in self.regions if r.kind is kind), None)
        return None if region is None else (region, address, count)

    def render(self, fmt: str) -> str:
        rows = self.rows()
        if fmt == "json":
            return json.dumps({"map_version": MAP_VERSION, "unit_ids": list(
                self.config.modbus.unit_ids), "regions": rows}, indent=2) + "\n"
        if fmt == "csv":
            out = io.StringIO()
            writer = csv.DictWriter(out, fieldnames=list(rows[0]), lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
            return out.getvalue()
        lines = [
            f"# Modbus map (version {MAP_VERSION}), unit ids "
            f"{', '.join(map(str, self.config.modbus.unit_ids))}",
            "",
            "Addresses are 0-based protocol addresses; HMI numbers are the 1-based "
            "0xxxx/1xxxx/3xxxx/4xxxx form. 32-bit values are two registers, high word first.",
            "",
            "| table | address | HMI | type | access | content | name |",
            "|---|---|---|---|---|---|---|",
        ]
        lines += [f"| {r['table']} | {r['start']}..{r['end']} | {r['hmi_start']}..{r['hmi_end']}"
                  f" | {r['type']} | {r['access']} | {r['content']} | {r['name']}"
                  + (f" ({r['comment']})" if r['comment'] else "") + " |" for r in rows]
        return "\n".join(lines) + "\n"


def _info(cell: CellStatus, processes: int) -> list[int]:
    counter = cell.events
    sender, target, n, number = cell.last_snd
    return [MAP_VERSION, processes, counter >> 16 & 0xFFFF, counter & 0xFFFF,
            sender, target, n & 0xFFFF, number & 0xFFFF, min(round(cell.lag_s * 1000), 0xFFFF)]


def force_list_registers(forced: Sequence[tuple[tuple[str, int, str], int]]) -> list[int]:
    """The force list's registers: the count, then the first forces (``forced`` is in name
    order, as the view keeps it)."""
    regs = [min(len(forced), 0xFFFF)]
    for (area, index, view), value in forced[:FORCE_LISTED]:
        regs += [_FORCE_KIND_OF[(area, view)], index, value & 0xFFFF]
    regs += [0] * (1 + 3 * FORCE_LISTED - len(regs))
    return regs


def snd_log_registers(cell: CellStatus) -> list[int]:
    """The SND log window: the newest sequence number (u32), then the entries newest first."""
    seq = cell.snd_seq
    regs = [seq >> 16 & 0xFFFF, seq & 0xFFFF]
    for number, sender, target, n, ident in reversed(cell.snd_log):
        regs += [number >> 16 & 0xFFFF, number & 0xFFFF, sender, target, n & 0xFFFF,
                 ident & 0xFFFF]
    regs += [0] * (ModbusMap.LOG_SIZE - len(regs))
    return regs


def process_registers(views: ViewPublisher, k: int) -> list[int]:
    """Process k's status block (the view's one encoding of it)."""
    return status_registers(views.process(k))

