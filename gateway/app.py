"""The gateway in a Python program or a test (spec 4.5): the soft PLC's image, the processes
on the wall clock, and the adapters that serve it (the Modbus server, the CANopen node, the
console: ``ncgate.gateway.adapters``).

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
import contextlib
import logging
import secrets
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from ncgate.config import Config, load_config
from ncgate.errors import InputRefused, Reason
from ncgate.gateway.adapters import ADAPTERS, plugin
from ncgate.gateway.door import Door, command_kind
from ncgate.gateway.errors import GatewayError, ProcessAlarmError, WaitIdleTimeout
from ncgate.gateway.lifecycle import Adapter, tune_interpreter
from ncgate.gateway.modbus.map import ModbusMap
from ncgate.gateway.plc import (
    OnlineChange,
    ReloadOutcome,
    ScanDriver,
    prepare_logic,
    start_plant_logic,
    start_plc,
    warn_shared_writes,
)
from ncgate.gateway.programs import CheckedFile
from ncgate.gateway.ratelimit import RateLimitedLog
from ncgate.gateway.record import SessionRecorder
from ncgate.gateway.tracefile import TraceFile
from ncgate.gateway.view import CellView, ViewPublisher
from ncgate.gateway.wallclock import WallClockDriver
from ncgate.gateway.wiring import Runtime, build_runtime, start_plant
from ncgate.inputs import (
    API,
    ClearFault,
    Command,
    CommandKind,
    Fault,
    Force,
    Input,
    Snd,
    Source,
    SourceKind,
    Start,
    Write,
    Writes,
)
from ncgate.inputs import var_name as variable_name
from ncgate.interpreter.engine import Engine, Process, ProcessState, ProcessStatus
from ncgate.interpreter.engine.events import Event
from ncgate.interpreter.engine.trace import EventDict, Trace
from ncgate.plc.image import ImageAddressError, IOImage
from ncgate.plc.scan import PlcRuntime, PlcStatus

if TYPE_CHECKING:
    from ncgate.gateway.canopen.clock import Clock
    from ncgate.gateway.canopen.node import CanopenNode
    from ncgate.gateway.modbus.server import ModbusServer
    from ncgate.gateway.plant import Plant
    from ncgate.gateway.web.port import ConsolePort


class Gateway:
    """Soft PLC + processes + plant + the adapters that serve them, as an async context."""

    def __init__(self, config: Config | None = None,
                 listeners: Sequence[Callable[[Event], None]] = (),
                 canopen_clock: Clock | None = None, cold: bool = False,
                 console: bool = False, web_default_port: int = 0,
                 record: str | Path | None = None,
                 overrides: Mapping[str, Any] | None = None,
                 checked: Iterable[CheckedFile] = ()) -> None:
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
        config overrides the session ran with, for its header).
        ``checked``: program files checked already with no error (``run``'s start-up check):
        the program store does not check those versions again."""
        self.config = config if config is not None else load_config(None)
        self.session = secrets.token_hex(6)  # names this run to the console's pages
        self.console_wanted = console  # (the web adapter's enabled() asks)
        self.web_default_port = web_default_port
        self.canopen_clock = canopen_clock  # (the CANopen adapter takes it)
        self._record_path = record
        self._overrides = dict(overrides or {})
        self._checked = tuple(checked)
        self.recorder: SessionRecorder | None = None
        self._record_detach: Callable[[], None] = lambda: None
        self._listeners = tuple(listeners)
        self.map = ModbusMap(self.config)
        self._runtime: Runtime | None = None
        self._driver: WallClockDriver | None = None
        # The adapters serving now, by their name in ncgate.gateway.adapters.ADAPTERS.
        self.adapters: dict[str, Any] = {}
        self._trace_file: TraceFile | None = None
        self._cold = cold
        self._plc: tuple[PlcRuntime, ScanDriver] | None = None
        self._stack: contextlib.AsyncExitStack | None = None
        self._loading: set[asyncio.Task[None]] = set()  # starts waiting for their program
        self._reload_lock = asyncio.Lock()  # one online change of the PLC logic at a time
        # The reload waiting for its turn (one at most: a later ask joins it).
        self._reload_next: asyncio.Future[ReloadOutcome | None] | None = None
        self._load_waits: set[asyncio.Future[None]] = set()  # programs being read
        self._refusals = RateLimitedLog(logging.getLogger("ncgate"))
        self.door: Door  # set on entry: the one way in (:meth:`apply`)
        self._views: ViewPublisher | None = None  # once an adapter reads the view

    async def __aenter__(self) -> Gateway:
        loop = asyncio.get_running_loop()
        # Every adapter is started in order and its close pushed on one stack: whatever
        # fails, what was started is closed (in reverse order), and one failing close does
        # not skip the others (contextlib.AsyncExitStack).
        stack = self._stack = contextlib.AsyncExitStack()
        try:
            await self._open(stack, loop)
        except BaseException:
            self._stack = None
            await stack.aclose()
            raise
        return self

    async def _open(self, stack: contextlib.AsyncExitStack,
                    loop: asyncio.AbstractEventLoop) -> None:
        # The young generation's size (lifecycle.GC_YOUNG_OBJECTS) while this gateway is
        # open, restored on exit.  The switch interval is the process's (lifecycle's
        # tune_interpreter says why): `ncgate run` sets 0.2 ms for its whole process
        # (cli/main.py), a program embedding a gateway calls tune_interpreter() for the same.
        stack.callback(tune_interpreter(switch_interval=False))
        # A gateway runs for a shift: memory keeps a window of the trace, a file (if asked
        # for) every event.
        trace = Trace(keep=self.config.trace.ring)
        t = self.config.trace
        if t.file is not None:
            trace_file = TraceFile(t.file, int(t.max_mb * 1_000_000), t.backups, loop=loop)
            stack.callback(trace_file.close)
            trace.subscribe(trace_file.write)
        runtime = build_runtime(self.config, closed=False, trace=trace)
        runtime.store.add_checked(self._checked)  # (before an autostart reads the main)
        driver = WallClockDriver(runtime.engine, self.config.nc.time_scale, loop,
                                 stall_s=self.config.nc.stall_s)
        self._runtime, self._driver = runtime, driver
        stack.callback(self._stop_clock)
        stack.callback(self._stop_loading)
        # The clock is brought to now before each input acts: what was due before it happens
        # first, at its own time (jumping the clock past due timers would start what follows
        # them late, and a write storm would slow the machine down).
        self.door = Door(runtime, lambda: runtime.plc, sync=driver.catch_up)
        runtime.engine.state_listeners.append(self._on_state)
        for listener in self._listeners:
            runtime.trace.subscribe(listener)
        stack.callback(self.stop_record)
        if self._record_path is not None:
            self.start_record(self._record_path, staged=True)
        # The logic read and compiled before anything serves: an error in it stops the
        # gateway before a PLC connected sees the CANopen node boot (and go again).
        prepared = {section: prepare_logic(self.config, section) for section in ("plc", "plant")}
        warn_shared_writes(self.config, *(None if p is None else p.logic
                                          for p in prepared.values()))
        # Each enabled adapter of the registry, in its order: its module is imported only
        # now, and only if it is enabled (a cell without a console never loads aiohttp).
        for name in ADAPTERS:
            entry = plugin(name)
            if not entry.enabled(self):
                continue
            adapter: Adapter = entry.factory(self)
            self.adapters[name] = adapter
            await adapter.start()
            stack.push_async_callback(adapter.close)
        console = self.adapters.get("web")
        if console is not None and console.address is None:
            del self.adapters["web"]  # an unset port that was taken: run goes on without it
        # The PLC scans from here: its first scan is due once the fieldbus is up, not while
        # the adapters start (which would make the next scans late from the start).
        plc = start_plc(self.config, runtime, self.door, closed=False, wall=driver.now,
                        cold=self._cold, prepared=prepared["plc"])
        if plc is not None:
            self._plc = plc
            plc[1].on_skip = self._skipped("plc")
            stack.callback(self._stop_plc, plc)
            if self.recorder is not None and isinstance(self.door.reload_plc, OnlineChange):
                self.door.reload_plc.record_to(self.recorder.logic)  # (run --record)
        # The plant answers from here on, beside the PLC: its models at rest, their outputs
        # written, the config's faults armed (docs/plant.md).
        from ncgate.config.script import Script
        from ncgate.gateway.sim import ScriptPlayer, plant_faults

        served = frozenset(found.fault_target for found in map(plugin, self.adapters)
                           if found.faults is not None and found.fault_target is not None)
        plant = start_plant(runtime, self.door.apply_on_time, closed=False, served=served,
                            server="this gateway")
        stack.callback(plant.close)
        plant.fieldbus_listeners.append(self._fieldbus_faults)
        plant.on_decision = self._plant_decided
        plant_logic = start_plant_logic(self.config, runtime, self.door, closed=False,
                                        wall=driver.now, prepared=prepared["plant"])
        if plant_logic is not None:
            plant_logic[1].on_skip = self._skipped("plant")
            stack.callback(plant_logic[1].close)
        ScriptPlayer(runtime, Script("<config>", ()), self.door, plant_faults(self.config)).arm()
        self._driver.settle()
        if self.config.nc.autostart:
            await self.start(source=Source(SourceKind.API, "nc.autostart"))
        if self.recorder is not None:
            self.recorder.commit()  # it serves: the record is the session's

    def _skipped(self, who: str) -> Callable[[int, int], None]:
        """The scans ``who``'s logic did not run, into the record being written (if any): a
        replay skips them too."""
        def note(k: int, n: int) -> None:
            if self.recorder is not None:
                self.recorder.skipped(who, k, n, self.engine.now)
        return note

    def _plant_decided(self, kind: str, t: float, n: int) -> None:
        """The plant's tick budget decided (a tick cut, the period stretched): into the
        record being written (if any), which the replay follows instead of its own budget."""
        if self.recorder is not None:
            self.recorder.plant(kind, t, n)

    def _fieldbus_faults(self, faults: list[Any]) -> None:
        """The plant's fieldbus faults in force, to each adapter that takes them (a fault
        of a fieldbus not served the plant said to have no effect as it came)."""
        for name, adapter in self.adapters.items():
            found = plugin(name)
            if found.faults is not None:
                found.faults(adapter, faults)

    def _stop_loading(self) -> None:
        self.runtime.store.cancel()  # a child checking a big program is killed
        for task in list(self._loading):
            task.cancel()  # its reading thread is a daemon: it ends with the process
        for waiting in list(self._load_waits):
            waiting.cancel()

    def _stop_clock(self) -> None:
        if self._driver is not None:
            self._driver.close()
        if self._views is not None:
            self._views.close()
            self._views = None

    def _stop_plc(self, plc: tuple[PlcRuntime, ScanDriver]) -> None:
        runtime, scans = plc
        scans.close()
        if runtime.retain is not None:
            runtime.retain.close()
        self._plc = None

    def start_record(self, path: str | Path, *, staged: bool = False) -> Path:
        """Write the session from now on to ``path`` (``run --record``, or the console's
        Record): the header, then every input and event (docs/console.md).  One record at a
        time: GatewayError while one is written.  ``staged``: beside ``path`` until the
        gateway serves (SessionRecorder)."""
        if self.recorder is not None:
            raise GatewayError(f"a record is being written already ({self.recorder.path})")
        runtime = self.runtime
        recorder = SessionRecorder(path, self.config, self._overrides,
                                   asyncio.get_running_loop(), staged=staged)
        self.recorder = recorder
        unsubscribe = runtime.trace.subscribe(recorder.event)
        runtime.store.loaded.append(recorder.program)
        self.door.recorder = recorder.input
        online = self.door.reload_plc
        if isinstance(online, OnlineChange):  # the PLC runs: its logic's sources, from now
            online.record_to(recorder.logic)

        def detach() -> None:
            unsubscribe()
            runtime.store.loaded.remove(recorder.program)
            self.door.recorder = None
            if isinstance(self.door.reload_plc, OnlineChange):
                self.door.reload_plc.record_to(None)
        self._record_detach = detach
        return recorder.path

    @property
    def record_folder(self) -> Path:
        """Where a record started from the console goes: beside ``run --record``'s file,
        or in the folder ``run`` was started in."""
        return Path(self._record_path).parent if self._record_path is not None else Path.cwd()

    def stop_record(self) -> Path | None:
        """Close the record being written with its stop line (a whole record, to replay);
        its path, or None when none was written."""
        recorder, self.recorder = self.recorder, None
        if recorder is None:
            return None
        self._record_detach()
        stop_t = self._driver.now() if self._driver is not None else 0.0
        recorder.close(max(stop_t, self.engine.now))
        return recorder.path

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        stack, self._stack = self._stack, None
        self._stop_loading()  # first: a console request waiting for a program ends now
        try:
            if stack is not None:
                await stack.aclose()
        finally:
            self.adapters = {}
            self._driver = None

    @property
    def modbus_address(self) -> tuple[str, int]:
        """(host, port) the Modbus server listens on (port 0 in the config: a free one)."""
        server = self.modbus_server
        address = server.address if server is not None else None
        if address is None:
            raise GatewayError("the Modbus server is not running (modbus.enabled = false? "
                               "modbus.tls.plain = false?)")
        return address

    @property
    def modbus_tls_address(self) -> tuple[str, int]:
        """(host, port) of Modbus/TCP Security (``[modbus.tls]``)."""
        server = self.modbus_server
        address = server.tls_address if server is not None else None
        if address is None:
            raise GatewayError("Modbus/TCP Security is not on (modbus.tls.cert unset?)")
        return address

    @property
    def web_address(self) -> tuple[str, int]:
        """(host, port) of the web console (``Gateway(..., console=True)``)."""
        console = self.web_console
        if console is None or console.address is None:
            raise GatewayError("the web console is not running (Gateway(config, console=True),"
                               " web.enabled = true?)")
        return console.address

    @property
    def opcua_endpoint(self) -> str:
        """The OPC UA server's endpoint URL, ``opc.tcp://host:port/`` (``[opcua]``)."""
        server = self.adapters.get("opcua")
        if server is None or server.endpoint is None:
            raise GatewayError("the OPC UA server is not running (opcua.enabled = false?)")
        endpoint: str = server.endpoint
        return endpoint

    @property
    def web_console(self) -> ConsolePort | None:
        console: ConsolePort | None = self.adapters.get("web")
        return console

    @property
    def modbus_server(self) -> ModbusServer | None:
        server: ModbusServer | None = self.adapters.get("modbus")
        return server

    @property
    def canopen_node(self) -> CanopenNode | None:
        node: CanopenNode | None = self.adapters.get("canopen")
        return node

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

    @property
    def view(self) -> CellView:
        """The cell as the adapters read it (:mod:`ncgate.gateway.view`), on the loop: built
        when the cell changed since the last one was, and only once something reads it."""
        return self.views.current()

    @property
    def views(self) -> ViewPublisher:
        """What builds :attr:`view` (on the loop), and gives one process's view or the last
        SND alone to a reader inside the engine's turn; made when first asked for."""
        views = self._views
        if views is None:
            driver = self._driver
            if driver is None:
                raise GatewayError("the gateway is not running (use 'async with Gateway(...)')")
            views = self._views = ViewPublisher(self, lambda: driver.turns)
        return views

    def status(self, process: int) -> ProcessStatus:
        return self.engine.status(process)

    @property
    def plc(self) -> PlcRuntime:
        """The PLC logic: ``gw.plc.read("main.t1.ET")``, ``gw.plc.status``."""
        if self._plc is None:
            raise GatewayError("the PLC runs no logic (set [plc] logic in the config)")
        return self._plc[0]

    @property
    def lag_s(self) -> float:
        """How far (machine seconds) the engine is behind the wall clock: 0 while it keeps
        ``nc.time_scale``; more when the loop has no time for what is due (a write storm)."""
        return self._driver.lag_s if self._driver is not None else 0.0

    @property
    def behind(self) -> bool:
        """The engine is far enough behind the wall clock that what is not on time gives way
        (WallClockDriver.behind)."""
        return self._driver is not None and self._driver.behind

    @property
    def max_lag_s(self) -> float:
        """The most the engine fell behind the wall clock since the start (machine s)."""
        return self._driver.max_lag_s if self._driver is not None else 0.0

    @property
    def plc_status(self) -> PlcStatus | None:
        """The PLC's status (None: no logic), for the fieldbus status objects."""
        return self._plc[0].status if self._plc is not None else None

    # -- acting as the operator and as a PLC -----------------------------------------------

    def settle(self) -> None:
        """Run what an outside input made runnable, at the input's time: :meth:`apply` does
        it after each input; a caller that applies inputs through :attr:`door` itself (the
        scenario's inputs at its t = 0, ``run --script``) calls it after them."""
        assert self._driver is not None
        self._driver.settle()

    def apply(self, item: Input) -> None:
        """The one way into the cell (:mod:`ncgate.inputs`): validate ``item``, record it,
        apply it at the wall clock's now and run what it made runnable.  Raises
        :class:`~ncgate.errors.InputRefused` (nothing applied) with a reason.

        A start (or a cycle start) of a program not read yet is read and checked off the
        loop first (the fieldbus is served meanwhile); then the input acts, and a refusal
        of it then is logged.  :meth:`apply_async` waits for that and raises it."""
        driver = self._driver
        if driver is None:
            raise GatewayError("the gateway is not running (use 'async with Gateway(...)')")
        kind = type(item)
        if kind is Writes or kind is Write:  # the fieldbus's every request: straight through
            self.door.apply(item)
            driver.settle()
            return
        if kind is Command and item.kind is CommandKind.RELOAD_PLC:  # type: ignore[union-attr]
            self._reload_soon(item)  # type: ignore[arg-type]
            return
        self.door.precheck(item)  # what can be refused without the program: at once
        load = self._load_needed(item)
        if load is not None:
            task = asyncio.get_running_loop().create_task(self._load_then_apply(item, *load))
            self._loading.add(task)
            task.add_done_callback(self._loaded)
            return
        starts = self._program_of(item) if type(item) is Start or type(item) is Command else None
        self.door.apply(item)
        self.settle()
        self._read_ahead(starts)

    def _loaded(self, task: asyncio.Task[None]) -> None:
        self._loading.discard(task)
        if self._driver is not None:
            self._driver.changed.set()  # a waiter on "every process idle" looks again

    async def apply_async(self, item: Input) -> None:
        """:meth:`apply`, after reading a program it starts off the loop: a refusal is
        raised here (the console's and :meth:`start`'s way)."""
        if type(item) is Command and item.kind is CommandKind.RELOAD_PLC:
            await self._reload(item)
            return
        self.door.precheck(item)
        load = self._load_needed(item)
        if load is not None:
            await self._load(*load)  # and reads ahead of its EXEs
        starts = self._program_of(item) if load is None else None
        self.door.apply(item)
        self.settle()
        self._read_ahead(starts)

    async def prepare(self, item: Input) -> None:
        """Read and check, off the loop, the program ``item`` would start (and, in a thread,
        what its EXEs start), so that applying it later acts at once: ``run --script``
        starts its programs from an engine timer, at a scan's instant."""
        self.door.precheck(item)
        load = self._load_needed(item)
        if load is not None:
            await self._load(*load)
        else:
            self._read_ahead(self._program_of(item))

    def _program_of(self, item: Input) -> tuple[str, int] | None:
        """(program, process) when ``item`` would start a program now."""
        if isinstance(item, Start):
            name, process = item.program or self.config.nc.main, item.process
        elif isinstance(item, Command) and item.kind is CommandKind.CYCLE_START:
            number = 1 if item.process is None else item.process
            if number not in self.engine.processes:
                return None  # refused by the door
            main = self.engine.cycle_start_program(item.process)
            if main is None:
                return None  # resumes a hold, or starts nothing
            name, process = main, number
        else:
            return None
        return (name, process) if name else None

    def _load_needed(self, item: Input) -> tuple[str, int] | None:
        """(program, process) when ``item`` starts a program the store has not read yet."""
        kind = type(item)
        if kind is Writes or kind is Write:
            return None  # the fieldbus's every request: at once
        program = self._program_of(item)
        if program is None or self.runtime.store.ready(*program):
            return None
        return program

    async def _load(self, name: str, process: int) -> None:
        """Read and check a program in a thread of its own (a daemon: a SIGTERM does not
        wait for it); its outcome, a failure too, is kept for the start that follows."""
        store = self.runtime.store
        await self._in_thread(f"ncgate load {name}", lambda: store.preload(name, process),
                              # then what its EXEs will start, meanwhile
                              then=lambda: store.read_ahead(name, process))

    async def _in_thread(self, name: str, work: Callable[[], object],
                         then: Callable[[], object] | None = None) -> None:
        """Run ``work`` in a daemon thread of its own (a SIGTERM does not wait for it) and
        wait until it is done; ``then`` goes on in that thread after.  The wait is one of
        ``_load_waits``, which a close cancels."""
        done = asyncio.get_running_loop().create_future()
        self._load_waits.add(done)
        done.add_done_callback(self._load_waits.discard)

        def finish() -> None:
            if not done.done():
                done.set_result(None)

        def run() -> None:
            work()
            with contextlib.suppress(RuntimeError):  # the loop is gone: nobody waits
                done.get_loop().call_soon_threadsafe(finish)
            if then is not None and not done.cancelled():  # (a close cancels what follows)
                then()

        threading.Thread(target=run, name=name, daemon=True).start()
        await done

    def _read_ahead(self, program: tuple[str, int] | None) -> None:
        """After a start of a program that was read already: read what its EXEs start, in
        a thread of its own (an EXE on the loop then finds its program read)."""
        if program is None:
            return
        threading.Thread(target=self.runtime.store.read_ahead, args=program,
                         name=f"ncgate read-ahead {program[0]}", daemon=True).start()

    async def _load_then_apply(self, item: Input, name: str, process: int) -> None:
        await self._load(name, process)
        try:
            self.door.apply(item)
        except InputRefused as exc:
            self._refusals.note(f"{item.source}: {type(item).__name__.lower()} refused: {exc}")
        self.settle()

    # -- online change of the PLC logic --------------------------------------------------------

    async def reload_plc(self, source: Source = API) -> ReloadOutcome:
        """Online change (``reload_plc``): ``[plc] logic`` is read and compiled off the loop,
        then swapped in between two scans, keeping every variable whose path and type are
        unchanged.  A load error leaves the old logic running: the outcome says why (``ok``
        False).  InputRefused (NOT_CONFIGURED) without PLC logic."""
        outcome = await self._reload(Command(CommandKind.RELOAD_PLC, None, source))
        assert outcome is not None
        return outcome

    def _reload_soon(self, item: Command) -> None:
        """A reload from a fieldbus: refused at once, or done in a task (the fieldbus is
        answered now; the outcome is in the log and the trace)."""
        if self.door.reload_plc is None or item.process is not None:
            self.door.apply(item)  # refused: no PLC logic, or of one process
        task = asyncio.get_running_loop().create_task(self._reload_logged(item))
        self._loading.add(task)
        task.add_done_callback(self._loaded)

    async def _reload_logged(self, item: Command) -> None:
        try:
            await self._reload(item)
        except InputRefused as exc:
            self._refusals.note(f"{item.source}: reload_plc refused: {exc}")

    async def _reload(self, item: Command) -> ReloadOutcome | None:
        """Compile in a thread of its own (a big program must not stall the scan: the
        figures are in docs/decisions.md), then swap it in through the door, one reload at
        a time.  A reload asked for while another waits for its turn is that one: it has
        not read the files yet, so it loads what this one would (reloads asked for faster
        than they compile -- 100 a second on Modbus word 16 -- queued up without end)."""
        online = self.door.reload_plc
        if not isinstance(online, OnlineChange) or item.process is not None:
            self.door.apply(item)  # refused: no PLC logic, or of one process
            return None
        waiting = self._reload_next
        if waiting is not None:
            return await asyncio.shield(waiting)
        self._reload_next = turn = asyncio.get_running_loop().create_future()
        try:
            outcome = await self._reload_now(item, online)
        except BaseException as exc:
            if self._reload_next is turn:
                self._reload_next = None
            if not turn.done():
                turn.set_exception(exc)
                turn.exception()  # (retrieved: those that joined it, if any, get it)
            raise
        turn.set_result(outcome)
        return outcome

    async def _reload_now(self, item: Command, online: OnlineChange) -> ReloadOutcome | None:
        async with self._reload_lock:
            self._reload_next = None  # the files are read from now on: a later ask waits
            await self._in_thread("ncgate reload_plc", online.prepare)
            self.door.apply(item)
            self.settle()
        return online.last

    async def start(self, name: str | None = None, process: int = 1,
                    source: Source = API, at: str | None = None,
                    with_calc: bool = False) -> None:
        """The operator's SPG: start NAME (default: the config's main) in a process; ``at``
        a label or an N number: a block search (``with_calc``: E parameters too)."""
        await self.apply_async(Start(name, process, source, at, with_calc))

    def write(self, var: str, value: int, source: Source = API) -> None:
        """Write one image variable (``"SA10"``, ``"SK2.IN"``, ``"SYVAR1"``, or an I/O name
        of ``[symbols]``)."""
        self.apply(Write(self.runtime.var(var), value, source))

    def force(self, var: str, value: int | float | None, source: Source = API) -> None:
        """Force a variable (``"SA10"``, an I/O name of ``[symbols]``, or a PLC variable's
        path, ``"main.n"``) to ``value``; ``None`` releases it (docs/decisions.md)."""
        self.apply(Force(self.runtime.force_target(var), value, source))

    def fault(self, target: str, kind: str, *, for_s: float | None = None,
              source: Source = API, **params: object) -> None:
        """Inject a fault (docs/plant.md): ``gw.fault("clamp", "never")``,
        ``gw.fault("SA30", "stuck", value=0, for_s=2)``, ``gw.fault("modbus", "exception",
        code=6, addresses=[0, 99])``."""
        self.apply(Fault.of(target, kind, for_s=for_s, source=source, **params))

    def clear_fault(self, target: str | None = None, source: Source = API) -> None:
        """Clear the faults of ``target`` (a model, an output, a variable, ``modbus``), or
        every fault (None)."""
        self.apply(ClearFault(target, source))

    @property
    def running(self) -> bool:
        """Between the ``async with``'s start and its end (what it ran stays readable after)."""
        return self._driver is not None

    @property
    def plant(self) -> Plant:
        """The plant: ``gw.plant.status()``, ``gw.plant.models``."""
        plant = self.runtime.plant
        if plant is None:
            raise GatewayError("the gateway is not running")
        return plant

    def read(self, var: str) -> int:
        v = self.runtime.var(var)
        try:
            return self.runtime.image.read(v.area, v.index, v.view)
        except ImageAddressError as exc:
            raise InputRefused(Reason.OUTSIDE_IMAGE, str(exc)) from None

    def send(self, sender: int, target: int, source: Source = API) -> None:
        """An SND in the name of external process ``sender``."""
        self.apply(Snd(sender, target, source))

    def command(self, word: int | CommandKind, source: Source = API,
                process: int | None = None) -> None:
        """The command word of spec 3.2: 1 cycle start, 2 feed hold, 3 reset -- of the cell,
        or of one ``process``."""
        self.apply(Command(command_kind(word), process, source))

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
            return engine.all_idle and not engine.has_runnable and not self._loading

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
