"""The PLC logic in the gateway: loading ``[plc] logic``, the NC port the scan acts through,
and the scan on the engine's clock.

The scan is an engine timer every ``plc.scan_ms`` of machine time: on the virtual clock in
``sim`` (deterministic: the same scans at the same instants every run) and on the wall clock
in ``run`` (the wall-clock driver fires engine timers on the asyncio loop).  Scan k is due at
``t0 + k * period``, whatever the scans before it cost, so the scan never drifts; when the
loop comes late past a whole period the missed scans are skipped and counted as overruns.

``nc.stall_s`` with PLC logic (spec 2.3): the scan is not pending work.  In ``sim`` the scan
stops rescheduling itself once every process with a program has waited ``stall_s`` with no
change (no state change, no image write) and no other timer is pending, and the run ends as
a stall; in ``run`` the wall-clock driver reports the stall on the same rule.
"""

from __future__ import annotations

import logging
import sqlite3
from collections.abc import Callable
from pathlib import Path

from ncgate.config import Config, ConfigError
from ncgate.config.state import state_folder
from ncgate.gateway.door import Door
from ncgate.gateway.wiring import Runtime
from ncgate.inputs import (
    Command,
    CommandKind,
    FieldbusAlarm,
    Override,
    Snd,
    Source,
    SourceKind,
)
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import Engine, ProcessState
from ncgate.interpreter.engine.states import WAITING_STATES
from ncgate.interpreter.engine.timers import Timer
from ncgate.plc.retain import RetainStore, default_path
from ncgate.plc.scan import NcSnapshot, PlcRuntime, PlcState, PlcStatus
from ncgate.plc.st.compiler import Context, Logic, compile_logic
from ncgate.plc.st.plcopen import read_logic_file

log = logging.getLogger("ncgate.plc")

# The PLC status block of the fieldbus maps (Modbus input registers, CANopen 0x2700).
PLC_REGISTERS = ("state (0 stopped, 1 running, 2 fault)", "scans (hi)", "scans (lo)",
                 "last scan µs (hi)", "last scan µs (lo)", "max scan µs (hi)",
                 "max scan µs (lo)", "overruns (hi)", "overruns (lo)",
                 "fault source line (0: none)", "last scan lateness µs (hi)",
                 "last scan lateness µs (lo)", "max scan lateness µs (hi)",
                 "max scan lateness µs (lo)")


def logic_context(config: Config) -> Context:
    plc, nc = config.plc, config.nc
    return Context(plc.sa_bits, plc.k_bytes, plc.syvars, nc.processes, nc.external,
                   tuple(config.symbols.items()), plc.strict)


def load_logic(files: tuple[Path, ...], config: Config) -> Logic:
    """Parse and check every file (Structured Text, or PLCopen XML by its .xml suffix);
    raises LogicError with all the diagnostics."""
    logic = compile_logic([read_logic_file(path) for path in files], logic_context(config))
    for warning in logic.warnings:  # plc.strict = false: what IEC would refuse
        log.warning("%s", warning.render())
    return logic


def program_order(logic: Logic, config: Config) -> list[str]:
    """``plc.programs`` checked against the logic (ConfigError naming the key), or every
    PROGRAM in file order."""
    if not config.plc.programs:
        if not logic.programs:
            where = config.source or "<config>"
            raise ConfigError(f"{where}: plc.logic: the files hold no PROGRAM to run")
        return list(logic.programs)
    order = []
    for i, name in enumerate(config.plc.programs):
        if name.upper() not in logic.programs:
            known = ", ".join(logic.display.values()) or "none"
            raise ConfigError(f"{config.source or '<config>'}: plc.programs[{i}]: no PROGRAM "
                              f"{name} in plc.logic (PROGRAMs: {known})")
        order.append(name)
    return order


class EngineNc:
    """The scan's view of the engine (:class:`ncgate.plc.scan.NcPort`): it reads the engine,
    and acts on it through the door, attributed ``plc FILE:LINE`` (where the logic set the
    output)."""

    def __init__(self, engine: Engine, door: Door) -> None:
        self.engine = engine
        self.door = door

    def snapshot(self) -> list[NcSnapshot]:
        out = []
        for p in self.engine.processes.values():
            state = p.state
            n = p.where[2]
            out.append((int(state), n or 0, p.where[1], state in WAITING_STATES,
                        p.alarm is not None, p.alarm[0] if p.alarm else 0,
                        state is ProcessState.IDLE, p.held))
        return out

    def events(self) -> int:
        return self.engine.trace.counter

    def last_snd(self) -> tuple[int, int, int]:
        last = self.engine.last_snd
        return (last[0], last[1], self.engine.snd_seq) if last else (0, 0, 0)

    def command(self, word: int, where: str, process: int | None = None) -> None:
        self.door.apply(Command(CommandKind(word), process, Source(SourceKind.PLC, where)))

    def override(self, feed: int, where: str, process: int | None = None) -> None:
        self.door.apply(Override(feed, None, process, Source(SourceKind.PLC, where)))

    def send(self, sender: int, target: int, where: str) -> None:
        self.door.apply(Snd(sender, target, Source(SourceKind.PLC, where)))

    def fault(self, message: str) -> None:
        self.door.apply(FieldbusAlarm(AlarmCode.PLC_FAULT, f"PLC fault: {message}",
                                      Source(SourceKind.PLC)))

    def hazard(self, message: str) -> None:
        self.engine.note_hazard(0, message)


class ScanDriver:
    """Runs the scan every ``scan_ms`` as an engine timer."""

    def __init__(self, engine: Engine, runtime: PlcRuntime, scan_ms: int, *,
                 wall: Callable[[], float] | None = None, closed: bool = False,
                 stall_s: float = 60.0, scale: float = 1.0) -> None:
        """``wall``: machine time now by the wall clock (``run``); ``scale``: the time scale
        that turns the scans' lateness back into wall-clock time."""
        self.engine = engine
        self.scale = scale
        self.runtime = runtime
        self.period = scan_ms / 1000.0
        self.wall = wall
        self.closed = closed
        self.stall_s = stall_s
        self.t0 = engine.now
        self.k = 0
        self._timer: Timer | None = engine.call_at(self.t0, self._scan)

    def _scan(self) -> None:
        engine, period = self.engine, self.period
        status = self.runtime.status
        if self.wall is not None:
            now = self.wall()
            if self.k == 0:
                # The first scan is on time whenever the gateway got round to it (starting
                # the fieldbus may take a while): the scans count from here.
                self.t0 = max(self.t0, now)
            # On the wall clock, as the scan's own time is: machine time / time scale.
            lateness = max(0, round((now - (self.t0 + self.k * period)) * 1e6 / self.scale))
            status.last_lateness_us = lateness
            status.max_lateness_us = max(status.max_lateness_us, lateness)
        due = self.t0 + self.k * period
        self.runtime.scan(round(due * 1000))
        self.k += 1
        if self.wall is not None:
            late = self.wall() - (self.t0 + self.k * period)
            if late >= period:  # the loop came a whole period late or more: skip, count
                missed = int(late // period)
                status.overruns += missed
                self.k += missed
        if self.closed and engine.stalled and engine.next_timer() is None and (
                engine.now - engine.last_change >= self.stall_s):
            self._timer = None  # nothing but the scan is left: let the run end as a stall
            return
        self._timer = engine.call_at(self.t0 + self.k * period, self._scan)

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self.runtime.stop()


def start_plc(config: Config, runtime: Runtime, door: Door, *, closed: bool,
              wall: Callable[[], float] | None = None, cold: bool = False
              ) -> tuple[PlcRuntime, ScanDriver] | None:
    """The PLC logic of ``[plc] logic`` running on the engine's clock, or None without it.

    RETAIN values are kept in ``plc.retain_file`` in ``run`` only: a simulation (``closed``)
    starts from the initial values every time, so that it stays deterministic."""
    plc = config.plc
    if not plc.logic:
        return None
    logic = load_logic(plc.logic, config)
    order = program_order(logic, config)
    store = None
    if not closed and any(v.retain for table in logic.programs.values()
                          for v in table.values()):
        path = plc.retain_file or default_path(state_folder(config.source))
        try:
            store = RetainStore(path)
            if cold:
                store.clear()
        except (sqlite3.Error, OSError) as exc:  # OSError: its folder cannot be made
            raise ConfigError(f"{config.source or '<config>'}: plc.retain_file: cannot keep "
                              f"RETAIN values in {path}: {exc}") from None
    engine = runtime.engine
    logic_runtime = PlcRuntime(logic, runtime.image, EngineNc(engine, door), order,
                               plc.loop_limit, store,
                               watchdog_ms=0 if closed else plc.watchdog_ms)
    runtime.plc = logic_runtime
    logic_runtime.on_overridden = lambda path, value: engine.note_forced(path, value, "plc")
    driver = ScanDriver(engine, logic_runtime, plc.scan_ms, wall=wall, closed=closed,
                        scale=config.nc.time_scale,
                        stall_s=config.nc.stall_s)
    log.info("PLC logic: %s, scan %d ms, programs %s", ", ".join(p.name for p in plc.logic),
             plc.scan_ms, ", ".join(order))
    return logic_runtime, driver


def plc_registers(status: PlcStatus | None) -> list[int]:
    """The PLC status block; all 0 (state 0, stopped) when the PLC runs no logic."""
    if status is None:
        return [0] * len(PLC_REGISTERS)
    regs = [int(status.state)]
    for value in (status.scans, status.last_scan_us, status.max_scan_us, status.overruns):
        value &= 0xFFFFFFFF
        regs += [value >> 16, value & 0xFFFF]
    fault = status.fault
    regs.append(fault.span.line & 0xFFFF if fault is not None and fault.span else 0)
    for late in (status.last_lateness_us, status.max_lateness_us):
        late = min(late, 0xFFFFFFFF)
        regs += [late >> 16, late & 0xFFFF]
    return regs


__all__ = ["EngineNc", "PlcState", "ScanDriver", "load_logic", "start_plc"]
