"""The gateway in a Python program or a test (spec 4.5): the soft PLC's image, the processes
on the wall clock, and (in later issues) the Modbus server and the CANopen node.

    from ncgate.gateway import Gateway, load_config
    async with Gateway(load_config(None)) as gw:
        await gw.start("PROG91")
        await gw.wait_state(2, "WAIT_COND")
        gw.write("SA10", 1)                    # as a PLC would
        await gw.wait_idle(timeout_s=30)
        events = gw.trace

The engine is driven by :class:`~ncgate.gateway.wallclock.WallClockDriver` on the loop's
clock.
"""

from __future__ import annotations

import asyncio
import secrets
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from ncgate.config import Config, load_config
from ncgate.gateway.canopen.clock import Clock
from ncgate.gateway.canopen.node import CanopenNode
from ncgate.gateway.errors import GatewayError, ProcessAlarmError, WaitIdleTimeout
from ncgate.gateway.modbus.map import ModbusMap
from ncgate.gateway.modbus.server import ModbusServer
from ncgate.gateway.plc import ScanDriver, start_plc
from ncgate.gateway.record import SessionRecorder
from ncgate.gateway.tracefile import TraceFile
from ncgate.gateway.wallclock import WallClockDriver
from ncgate.gateway.wiring import (
    Runtime,
    apply_command,
    build_runtime,
    parse_assignment,
    variable_name,
)
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import Engine, Process, ProcessState, ProcessStatus
from ncgate.interpreter.engine.events import Event
from ncgate.interpreter.engine.trace import EventDict, Trace
from ncgate.plc.image import IOImage
from ncgate.plc.scan import PlcRuntime, PlcStatus

if TYPE_CHECKING:
    from ncgate.gateway.web.console import WebConsole


class Gateway:
    """Soft PLC + processes (+ fieldbus servers in later issues), as an async context."""

    def __init__(self, config: Config | None = None,
                 listeners: Sequence[Callable[[Event], None]] = (),
                 canopen_clock: Clock | None = None, cold: bool = False,
                 console: bool = False, web_default_port: int = 0,
                 record: str | Path | None = None,
                 overrides: Mapping[str, Any] | None = None) -> None:
        """``listeners`` hear every trace event from the start (before an autostart).
        ``canopen_clock`` drives the CANopen node's timers (inhibit, event timer, heartbeat
        consumer, SDO timeout): a test passes a
        :class:`~ncgate.gateway.canopen.clock.ManualClock` and moves time itself.
        ``cold``: the PLC logic starts without its stored RETAIN values (``run --cold``).
        ``console``: serve the web console as ``[web]`` says (an unset ``web.port`` is a
        free port here, or ``web_default_port``, which ``run`` sets to 8080 and which when
        taken leaves the console off; see :attr:`web_address`); off by default in the API
        and the tests.
        ``record``: write the session to this file (``run --record``; ``overrides``: the
        config overrides the session ran with, for its header)."""
        self.config = config if config is not None else load_config(None)
        self.session = secrets.token_hex(6)  # names this run to the console's pages
        self._console_wanted = console
        self._web_default_port = web_default_port
        self._console: WebConsole | None = None
        self._record_path = record
        self._overrides = dict(overrides or {})
        self.recorder: SessionRecorder | None = None
        self._listeners = tuple(listeners)
        self._canopen_clock = canopen_clock
        self.map = ModbusMap(self.config)
        self._runtime: Runtime | None = None
        self._driver: WallClockDriver | None = None
        self._modbus: ModbusServer | None = None
        self._canopen: CanopenNode | None = None
        self._trace_file: TraceFile | None = None
        self._cold = cold
        self._plc: tuple[PlcRuntime, ScanDriver] | None = None

    async def __aenter__(self) -> Gateway:
        loop = asyncio.get_running_loop()
        # A gateway runs for a shift: memory keeps a window of the trace, a file (if asked
        # for) every event.
        trace = Trace(keep=self.config.trace.ring)
        t = self.config.trace
        if t.file is not None:
            self._trace_file = TraceFile(t.file, int(t.max_mb * 1_000_000), t.backups,
                                         loop=loop)
            trace.subscribe(self._trace_file.write)
        runtime = build_runtime(self.config, closed=False, trace=trace)
        driver = WallClockDriver(runtime.engine, self.config.nc.time_scale, loop,
                                 stall_s=self.config.nc.stall_s)
        runtime.engine.state_listeners.append(self._on_state)
        for listener in self._listeners:
            runtime.trace.subscribe(listener)
        self._runtime, self._driver = runtime, driver
        try:
            if self._record_path is not None:
                self.recorder = SessionRecorder(self._record_path, self.config,
                                                self._overrides, loop)
                trace.subscribe(self.recorder.event)
            self._plc = start_plc(self.config, runtime.engine, runtime.image, closed=False,
                                  wall=driver.now, cold=self._cold)
            if self.config.modbus.enabled:
                self._modbus = ModbusServer(self.config.modbus, self.map, self)
                await self._modbus.start()
            if self.config.canopen.enabled:
                self._canopen = CanopenNode(self.config, self, self._canopen_clock)
                self._canopen.start()
            if self._console_wanted and self.config.web.enabled:
                from ncgate.gateway.web.console import WebConsole  # aiohttp: only if served
                console = WebConsole(self, self.config.web, self._web_default_port)
                if await console.start():
                    self._console = console
            if self.config.nc.autostart:
                await self.start()
        except BaseException:
            await self.__aexit__(None, None, None)
            raise
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        if self._console is not None:
            await self._console.close()
            self._console = None
        if self._modbus is not None:
            await self._modbus.close()
            self._modbus = None
        if self._canopen is not None:
            self._canopen.close()
            self._canopen = None
        if self._plc is not None:
            runtime, scans = self._plc
            scans.close()
            if runtime.retain is not None:
                runtime.retain.close()
            self._plc = None
        stop_t = self._driver.now() if self._driver is not None else 0.0
        if self._driver is not None:
            self._driver.close()
        self._driver = None
        if self._trace_file is not None:
            self._trace_file.close()
            self._trace_file = None
        if self.recorder is not None:
            self.recorder.close(max(stop_t, self.engine.now))
            self.recorder = None

    @property
    def modbus_address(self) -> tuple[str, int]:
        """(host, port) the Modbus server listens on (port 0 in the config: a free one)."""
        address = self._modbus.address if self._modbus is not None else None
        if address is None:
            raise GatewayError("the Modbus server is not running (modbus.enabled = false? "
                               "modbus.tls.plain = false?)")
        return address

    @property
    def modbus_tls_address(self) -> tuple[str, int]:
        """(host, port) of Modbus/TCP Security (``[modbus.tls]``)."""
        address = self._modbus.tls_address if self._modbus is not None else None
        if address is None:
            raise GatewayError("Modbus/TCP Security is not on (modbus.tls.cert unset?)")
        return address

    @property
    def web_address(self) -> tuple[str, int]:
        """(host, port) of the web console (``Gateway(..., console=True)``)."""
        if self._console is None or self._console.address is None:
            raise GatewayError("the web console is not running (Gateway(config, console=True),"
                               " web.enabled = true?)")
        return self._console.address

    @property
    def web_console(self) -> WebConsole | None:
        return self._console

    @property
    def modbus_server(self) -> ModbusServer | None:
        return self._modbus

    @property
    def canopen_node(self) -> CanopenNode | None:
        return self._canopen

    # -- what is inside -------------------------------------------------------------------

    @property
    def runtime(self) -> Runtime:
        if self._runtime is None:
            raise GatewayError("the gateway is not running (use 'async with Gateway(...)')")
        return self._runtime

    @property
    def engine(self) -> Engine:
        return self.runtime.engine

    @property
    def image(self) -> IOImage:
        return self.runtime.image

    @property
    def trace(self) -> list[EventDict]:
        """The latest events of spec 4.4 (at most ``trace.ring`` of them), as dicts."""
        return self.runtime.trace.events

    def status(self, process: int) -> ProcessStatus:
        return self.engine.status(process)

    @property
    def plc(self) -> PlcRuntime:
        """The PLC logic: ``gw.plc.read("main.t1.ET")``, ``gw.plc.status``."""
        if self._plc is None:
            raise GatewayError("the PLC runs no logic (set [plc] logic in the config)")
        return self._plc[0]

    @property
    def plc_status(self) -> PlcStatus | None:
        """The PLC's status (None: no logic), for the fieldbus status objects."""
        return self._plc[0].status if self._plc is not None else None

    # -- acting as the operator and as a PLC -----------------------------------------------

    def _sync_clock(self) -> None:
        assert self._driver is not None
        self.engine.set_time(self._driver.now())

    def _settle(self) -> None:
        """Run what an outside input made runnable, at the input's time."""
        assert self._driver is not None
        self._driver.settle()

    def _input(self, kind: str, **fields: Any) -> None:
        """An input from outside the cell, for the session record (``run --record``)."""
        if self.recorder is not None:
            self.recorder.input(kind, self.engine.now, **fields)

    async def start(self, name: str | None = None, process: int = 1,
                    by: str = "operator") -> None:
        """The operator's SPG: start NAME (default: the config's main) in a process."""
        name = name or self.config.nc.main
        # Load (parse and check) before reading the clock: the program starts when it is ready.
        self.runtime.store.load(name, None, process)
        self._sync_clock()
        self.engine.start(name, process, by=by)
        self._input("start", prog=name, proc=process, by=by)
        self._settle()

    def write(self, var: str, value: int, who: str = "api", peer: str | None = None) -> None:
        """Write one image variable (``"SA10"``, ``"SK2.IN"``, ``"SYVAR1"``) as ``who``."""
        (area, index, view), number = parse_assignment(f"{var}={value}")
        self.apply_writes([(area, index, view, number)], who, peer)

    def apply_writes(self, changes: Sequence[tuple[str, int, str, int]], who: str,
                     peer: str | None = None) -> None:
        """Write several image variables at once (one fieldbus request), then settle.
        ``peer``: the client's address, when ``who`` does not name it (the record has it)."""
        self._sync_clock()
        self.runtime.image.write(changes, who)
        self._input("write", who=who, peer=peer, changes=changes)
        self._settle()

    def read(self, var: str) -> int:
        (area, index, view), _ = parse_assignment(f"{var}=0")
        return self.runtime.image.read(area, index, view)

    def send(self, sender: int, target: int, who: str = "api") -> None:
        """An SND in the name of external process ``sender``."""
        self._sync_clock()
        self.engine.external_snd(sender, target)
        self._input("snd", who=who, **{"from": sender, "to": target})
        self._settle()

    def fieldbus_alarm(self, code: AlarmCode, message: str) -> None:
        """An alarm of the fieldbus side (process 0 in the trace), e.g. a lost master."""
        self._sync_clock()
        self.engine.fieldbus_alarm(code, message)
        self._input("alarm", code=code.name, message=message)
        self._settle()

    def command(self, word: int, who: str = "api") -> None:
        """The command word of spec 3.2: 1 cycle start, 2 feed hold, 3 reset."""
        self._sync_clock()
        apply_command(self.engine, word, self._plc[0] if self._plc is not None else None)
        self._input("command", who=who, word=word)
        self._settle()

    # -- waiting ------------------------------------------------------------------------------

    def _on_state(self, process: Process, old: ProcessState) -> None:
        if self._driver is not None:
            self._driver.changed.set()

    async def _until(self, done: Any, timeout_s: float, what: str) -> None:
        assert self._driver is not None
        changed = self._driver.changed
        try:
            async with asyncio.timeout(timeout_s):
                while not done():
                    changed.clear()
                    await changed.wait()
        except TimeoutError:
            raise WaitIdleTimeout(f"{what} not reached in {timeout_s:g} s\n"
                                  + self.describe_blocked()) from None

    async def wait_idle(self, timeout_s: float = 30.0) -> None:
        """Until every process is IDLE; raises with the why-records or the alarms."""
        engine = self.engine

        def idle() -> bool:
            alarms = [p for p in engine.processes.values() if p.alarm is not None]
            if alarms and all(p.loaded is None or p.alarm is not None
                              for p in engine.processes.values()):
                raise ProcessAlarmError("\n".join(
                    f"P{p.number} {p.alarm[1]}" for p in alarms if p.alarm))
            return engine.all_idle and not engine.has_runnable

        await self._until(idle, timeout_s, "every process IDLE")

    async def wait_state(self, process: int, state: str | ProcessState,
                         timeout_s: float = 30.0) -> None:
        """Until process ``process`` is in ``state`` (e.g. ``"WAIT_COND"``)."""
        wanted = state if isinstance(state, ProcessState) else ProcessState[state.upper()]
        await self._until(lambda: self.engine.processes[process].state is wanted, timeout_s,
                          f"P{process} {wanted.name}")

    def describe_blocked(self) -> str:
        lines = []
        for b in self.engine.blocked():
            n = f" N{b.n}" if b.n is not None else ""
            lines.append(f"P{b.proc} {b.prog}:{b.line}{n} {b.reason}")
        for p in self.engine.processes.values():
            if p.alarm is not None:
                lines.append(f"P{p.number} ALARM AL{p.alarm[0]}: {p.alarm[1]}")
        return "\n".join(lines) or "no process is blocked"


__all__ = ["Gateway", "GatewayError", "ProcessAlarmError", "WaitIdleTimeout",
           "WallClockDriver", "variable_name"]
