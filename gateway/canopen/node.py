"""The gateway's CANopen node (spec 3.3): canopen's LocalNode over python-can, and what it
does not do by itself.

canopen runs its SDO server, NMT and PDO callbacks on python-can's receive thread.  Nothing
here touches the image or the processes from that thread: writes and status reads are handed
to the asyncio loop and their result (or abort code) awaited (:meth:`CanopenNode._on_loop`);
image reads use an immutable snapshot that the loop publishes after every write, once all of
the write's values are stored (so never half a request), which keeps SDO reads of the image
prompt however busy the loop is.  A SYNC's TPDOs are built on that thread from the same
snapshot, which holds the processes' status, the last SND and the PLC status too, published
from the node's state and trace listeners (``snapshot``).  The loop takes those from the
cell's view (:attr:`ncgate.gateway.Gateway.view`, ``gateway/view.py``: the one encoding of a
process's status record), never from the engine itself.

The rooms:

- ``sdo``: the SDO server (one transfer at a time, closed by every abort; no service in
  STOPPED; 1 s timeout) and the value checks of spec 3.3;
- ``pdo``: RPDO1..4 / TPDO1..4 with dynamic mapping, the transmission types, inhibit time,
  event timer and SYNC, and the checks of CiA 301 on their parameters;
- ``heartbeat``: the heartbeat consumer (0x1016) and what the node does when the master's
  heartbeat stops (``canopen.on_master_lost``);
- ``store``: 0x1010/0x1011, the communication parameters kept next to the config;
- ``clock``: the timers, on the loop or driven by a test.

Here: NMT (boot-up, PRE-OPERATIONAL or OPERATIONAL with ``nmt_autostart``, resets that
restore the communication parameters), the manufacturer objects wired to the image and the
processes, the command word answered before it runs, EMCY on every alarm and an error reset
when they are gone (0x1001 follows; each error listed in 0x1003, each EMCY spaced by
0x1015), the reactions to a communication error (0x1029 for the NMT state,
``canopen.on_master_lost`` for the processes), and the second SDO server (0x1201).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, TypeVar

import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from ncgate.config import Config, MasterLost
from ncgate.config.state import state_folder
from ncgate.errors import InputRefused
from ncgate.gateway.canopen import pdo, store
from ncgate.gateway.canopen.clock import Clock, LoopClock, Timer, UnlessClosed
from ncgate.gateway.canopen.codes import (
    ABORT_APPLICATION_DEVICE_STATE,
    ABORT_GENERAL_ERROR,
    ABORT_INVALID_VALUE,
    ABORT_NO_DATA_AVAILABLE,
    ABORT_READ_WRITEONLY,
    ABORT_STORE_APPLICATION,
    REFUSAL,
)
from ncgate.gateway.canopen.dictionary import (
    COMMAND,
    CONSUMER_ENTRIES,
    CONSUMER_HEARTBEAT,
    CYCLE_PERIOD,
    EMCY_INHIBIT,
    ERROR_BEHAVIOUR,
    ERROR_HISTORY,
    FEED_OVERRIDE,
    HISTORY_ENTRIES,
    LAST_SND,
    NO_STATE_CHANGE,
    OVERRIDE_TOP,
    PLC_STATUS,
    RAPID_OVERRIDE,
    RESTORE,
    RPDO_COMMUNICATION,
    SECOND_SDO_SERVER,
    STATUS_BASE,
    STORE,
    SYNC_COB_ID,
    SYNC_OVERFLOW,
    TO_PRE_OPERATIONAL,
    TO_STOPPED,
    TPDO_COMMUNICATION,
    TPDO_MAPPING,
    build_dictionary,
    image_target,
)
from ncgate.gateway.canopen.heartbeat import HeartbeatConsumer, check_entries
from ncgate.gateway.canopen.hub import Hub
from ncgate.gateway.canopen.sdo import Deferred, Device, SdoService
from ncgate.gateway.canopen.snapshot import Snapshot, getter, plc_record
from ncgate.gateway.door import SEARCH_WORDS, search_inputs
from ncgate.gateway.errors import listen_error
from ncgate.gateway.ratelimit import RateLimitedLog
from ncgate.gateway.view import CANOPEN_RECORD
from ncgate.gateway.wiring import Backend
from ncgate.inputs import (
    Command,
    CommandKind,
    FieldbusAlarm,
    Override,
    Snd,
    Source,
    SourceKind,
    Var,
    Write,
    Writes,
    command_word,
)
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine import Process, ProcessState
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.events import Event

log = logging.getLogger("ncgate.canopen")

EMCY_SOFTWARE = 0x6200
EMCY_HEARTBEAT = 0x8130  # life guard or heartbeat error (CiA 301 table 21)
REGISTER_GENERIC, REGISTER_COMMUNICATION = 0x01, 0x10
EMCY_QUEUE = 64  # EMCYs waiting for 0x1015's inhibit time; older ones are dropped
# How often the hub's thread looks whether it is to stop (socketserver's poll interval, 0.5 s
# by default): a close waited up to that long for it, and the gateway's SIGTERM with it.
HUB_POLL_S = 0.02

T = TypeVar("T")


class _Handoff:
    """A callback handed to the loop (:meth:`CanopenNode.call_soon`), until it runs.

    It keeps no handle: a handle that pointed back at it made a reference cycle per call
    (Handle -> callback -> handoff -> Handle), one for every SYNC, heartbeat and RPDO heard,
    about 540 cycles of 9 objects a second beside bench/storm.py's quiet poller.  The young
    collection that freed them every 0.75 s took 3-11 ms with the interpreter's lock held,
    and the CAN thread's SYNC waited behind it.  Now each is freed by its count when it has
    run, and a cancelled one runs as nothing."""

    __slots__ = ("fn", "node")

    def __init__(self, node: CanopenNode, fn: Callable[[], None]) -> None:
        self.node: CanopenNode | None = node
        self.fn: Callable[[], None] | None = fn

    def cancel(self) -> None:
        self.fn = self.node = None

    def __call__(self) -> None:
        node, fn = self.node, self.fn
        self.fn = self.node = None
        if node is None or fn is None:
            return  # cancelled
        node._pending.discard(self)
        if not node._closed:
            fn()


class CanopenNode:
    """The node on the bus, wired to the gateway's image and processes."""

    def __init__(self, config: Config, backend: Backend, clock: Clock | None = None) -> None:
        self.config = config
        self.backend = backend
        self.node_id = config.canopen.node_id
        self.od = build_dictionary(config)
        self.node = Device(self.node_id, self.od)  # canopen's LocalNode, with our SDO server
        self.network = canopen.Network()
        # The notifier thread wakes this often when the bus is quiet; shutting down waits for
        # it, so the default of 1 s would make every stop last a second.
        self.network.NOTIFIER_CYCLE = 0.05
        self.loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread: int | None = None
        self._clock = clock
        self._timers: Clock | None = None  # (start: the clock, its timers off once closed)
        self.pdos = pdo.Pdos(self)
        self.heartbeats: HeartbeatConsumer | None = None
        self.store_path = config.canopen.store_file or store.default_path(
            state_folder(config.source), self.node_id)
        self._alarmed = False  # an EMCY for a process alarm went out and was not reset
        self._master_lost: set[int] = set()
        self._rpdo_lost: set[int] = set()  # RPDOs whose deadline ran out (0x14xx:5)
        self._rpdo_length: set[int] = set()  # RPDOs in a length error (EMCY 0x8210/0x8220)
        self._sync_errors: set[int] = set()  # SYNC EMCYs in force (0x8100, 0x8240)
        self._history: tuple[int, ...] = ()  # 0x1003, newest first (swapped whole)
        self._emcy_queue: deque[bytes] = deque()  # EMCYs waiting for the inhibit time
        self._emcy_timer: Timer | None = None
        self._emcy_last = -1e18
        self._hub: Hub | None = None
        # What a TPDO or an SDO read may map: published by the loop after each change it
        # hears, read by the CAN thread (snapshot.py).  Immutable, swapped in one assignment.
        self._view = Snapshot()
        self._sampling = False  # the loop is to sample N, line and the PLC again (a SYNC)
        # Processes whose status changed since the snapshot was published (0: the last SND),
        # and whether a loop callback is to publish them.
        self._heard: set[int] = set()
        self._publish_due = False
        self.hub_address: tuple[str, int] | None = None
        self._closed = True  # until start(); then until close()
        # The plant's CANopen faults in force (docs/plant.md): the heartbeat producer
        # silenced (the node's NMT slave keeps that: sdo.Nmt.silenced), the TPDOs silenced,
        # an EMCY error code raised by hand.
        self._fault_pdo = False
        self._fault_emcy: int | None = None
        self._pending: set[_Handoff] = set()  # callbacks handed to the loop, not yet run
        # Futures the receive thread waits on for the loop (_on_loop): cancelled by close.
        self._waiting: set[concurrent.futures.Future[Any]] = set()
        self._closing: asyncio.Future[None] | None = None  # the close under way, or done
        self._unsubscribe: list[Callable[[], None]] = []  # from the trace and the image
        self._sdo_source = Source(SourceKind.CANOPEN, f"SDO 0x{0x600 + self.node_id:03X}")
        self._refusals = RateLimitedLog(log)
        # The second SDO server (0x1201), while its COB-IDs are valid: (rx, tx) and it.
        self._second_sdo: tuple[int, int, SdoService] | None = None

    @property
    def clock(self) -> Clock:
        """The clock of everything the node arms: its timers do nothing once it is closed."""
        assert self._timers is not None, "the node is not started"
        return self._timers

    # -- life cycle -----------------------------------------------------------------------

    async def start(self) -> None:
        try:
            self._start()
        except BaseException:
            # The gateway closes only an adapter that started: a node left half started
            # stayed on the bus (its receive thread, SDO answers, heartbeat) for good.
            await self.close()
            raise

    def _start(self) -> None:
        cfg = self.config.canopen
        self._closed = False
        self.loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        if self._clock is None:
            self._clock = LoopClock(self.loop)
        self._timers = UnlessClosed(self._clock, lambda: self._closed)
        self.node.clock = self._timers
        self.heartbeats = HeartbeatConsumer(self._timers, self.subscribe, self.unsubscribe,
                                            self.call_soon, self._on_master_lost,
                                            self._on_master_back)
        self._restore_stored()
        self.network.connect(interface=cfg.interface, channel=cfg.channel, bitrate=cfg.bitrate)
        self.network.add_node(self.node)
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self.node.stored = self._on_stored
        self.node.defer = self._defer
        self.node.stored_form = pdo.stored_form
        self.network.subscribe(0, self._on_nmt)  # after canopen's own NMT handler
        self.pdos.configure_all()
        self._configure_heartbeats()
        self._configure_second_sdo()
        engine = self.backend.engine
        engine.state_listeners.append(self._on_state)
        self._unsubscribe.append(engine.trace.subscribe(self._on_event))
        self._publish()
        self._unsubscribe.append(self.backend.image.subscribe(self._on_image))
        self._boot()
        log.info("CANopen node %d on %s/%s (%s)", self.node_id, cfg.interface, cfg.channel,
                 self.node.nmt.state)
        if cfg.hub:
            self._start_hub()

    def _start_hub(self) -> None:
        """Serve our bus to other processes: each websocket client of the hub gets a bus of
        its own on our interface and channel (python-can-remote)."""
        cfg = self.config.canopen
        try:
            hub = Hub(cfg.hub_host, cfg.hub_port, interface=cfg.interface, channel=cfg.channel,
                      bitrate=cfg.bitrate)
        except OSError as exc:  # name the key to change, as for the other ports
            raise listen_error(exc, "canopen.hub_port", cfg.hub_host, cfg.hub_port) from None
        thread = threading.Thread(target=hub.serve_forever, args=(HUB_POLL_S,),
                                  name="ncgate can-remote hub", daemon=True)
        thread.start()
        self._hub = hub
        host, port = hub.server_address[:2]
        self.hub_address = (str(host), int(port))
        log.info("CANopen hub for other processes: interface 'remote', channel "
                 "'ws://%s:%d/'", host, port)

    async def close(self) -> None:
        """Leave the bus; a second close does nothing.  The engine runs on meanwhile and
        after (the gateway stops its clock once every adapter is closed), so first nothing of
        it reaches the node any more, nothing the node armed or handed the loop runs, and
        only then the bus goes: an SND, a write or a state change that reached the node after
        that made a TPDO send on a bus that was gone ("Not connected to CAN bus", raised in
        the engine's turn).  A close while another is under way waits for that one: when it
        returns, the hub no longer listens."""
        if self._closing is None:
            if self._closed:
                return  # never started
            self._closed = True  # call_soon drops what races in from the CAN thread now
            self._stop()  # at once: the engine's next event or a timer must not reach it
            self._closing = asyncio.ensure_future(self._close())
        await asyncio.shield(self._closing)

    def _stop(self) -> None:
        """Close's first part, before it awaits anything: nothing reaches the node, nothing
        it armed or handed the loop runs."""
        self._detach()
        for call in list(self._pending):
            call.cancel()  # (one not scheduled yet finds the node closed when it runs)
        self._pending.clear()
        # An SDO read the receive thread waits on the loop for (_on_loop) is aborted now: the
        # thread must be free before disconnect joins it, or the loop waits its 2 s timeout.
        for future in list(self._waiting):
            future.cancel()
        self._refusals.flush()
        self.pdos.close()  # its timers and deadlines
        if self._emcy_timer is not None:
            self._emcy_timer.cancel()
        self._emcy_queue.clear()
        if self.heartbeats is not None:
            self.heartbeats.close()
        self.node.nmt.stop_heartbeat()
        self.node.sdo.close()  # type: ignore[attr-defined]
        if self._second_sdo is not None:
            self._second_sdo[2].close()

    async def _close(self) -> None:
        """Close's second part: the bus, then the hub."""
        # Joins the receive thread: a timer it armed meanwhile does nothing (UnlessClosed).
        self.network.disconnect()
        if self._hub is not None:
            # In a thread: the loop goes on serving (and the NC on running) while the hub's
            # thread sees the request, within HUB_POLL_S.
            hub, self._hub = self._hub, None
            try:
                await asyncio.to_thread(hub.shutdown)
            finally:  # a cancelled close still closes the listening socket, and the clients'
                hub.server_close()  # sessions: what they asked the hub to send stops now
                hub.end_sessions()

    def _detach(self) -> None:
        """No engine event (trace, process state, image write) reaches the node from now."""
        engine = self.backend.engine
        if self._on_state in engine.state_listeners:
            engine.state_listeners.remove(self._on_state)
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._unsubscribe = []

    def _boot(self) -> None:
        """Boot-up message, then PRE-OPERATIONAL (or OPERATIONAL with nmt_autostart)."""
        self.network.send_message(0x700 + self.node_id, b"\x00")
        self.node.nmt.send_command(0x80)  # starts the heartbeat producer (0x1017)
        self.call_soon(self.pdos.left_operational)
        if self.config.canopen.nmt_autostart:
            self.node.nmt.send_command(0x01)
            self.call_soon(self.pdos.entered_operational)

    @property
    def operational(self) -> bool:
        return self.node.nmt.state == "OPERATIONAL"

    @property
    def stopped(self) -> bool:
        return self.node.nmt.state == "STOPPED"

    # -- what the PDOs and the heartbeat consumer use (pdo.Host) ----------------------------

    def send(self, cob: int, data: bytes) -> None:
        # (a timer the receive thread armed as close began; a pdo_stop fault)
        if not self._closed and not self._fault_pdo:
            self.network.send_message(cob, data)

    def set_faults(self, heartbeat_stop: bool, pdo_stop: bool, emcy: int | None) -> None:
        """The plant's CANopen faults in force (on the loop): ``heartbeat_stop`` silences
        the heartbeat producer (a master's consumer sees the node lost), ``pdo_stop`` every
        TPDO, ``emcy`` raises an EMCY with that error code (its end: EMCY 0x0000)."""
        if heartbeat_stop != self.node.nmt.silenced:
            # Silenced for as long as the fault is in force: a master's write of 0x1017 or
            # an NMT reset does not start it again (sdo.Nmt).
            self.node.nmt.silenced = heartbeat_stop
            if heartbeat_stop:
                self.node.nmt.stop_heartbeat()
            elif not self._closed:
                self.node.nmt.start_heartbeat(int(pdo.param(self.node, 0x1017, 0)))
        self._fault_pdo = pdo_stop
        if emcy != self._fault_emcy:
            old, self._fault_emcy = self._fault_emcy, emcy
            if old is not None:  # with the register as it is now: without the old fault's
                self._emcy_reset()
            if emcy is not None:
                self._emcy_error(emcy)

    def faults(self) -> list[str]:
        """The plant's faults in force on the node, as the status names them."""
        return [name for name, on in (("heartbeat_stop", self.node.nmt.silenced),
                                      ("pdo_stop", self._fault_pdo),
                                      (f"emcy 0x{self._fault_emcy or 0:04X}",
                                       self._fault_emcy is not None)) if on]

    def subscribe(self, cob: int, callback: Callable[[int, bytearray, float], None]) -> None:
        self.network.subscribe(cob, callback)

    def unsubscribe(self, cob: int, callback: Callable[[int, bytearray, float], None]) -> None:
        self.network.unsubscribe(cob, callback)

    def apply(self, changes: Sequence[tuple[str, int, str, int]], source: Source) -> None:
        """An RPDO's writes (on the loop); a refusal is logged, rate-limited."""
        try:
            self.backend.apply(Writes(tuple((Var.at(a, i, v), value) for a, i, v, value in changes),
                                      source))
        except InputRefused as exc:
            self._refusals.note(f"{source}: RPDO not applied: {exc}")

    def getter(self, index: int, subindex: int) -> Callable[[], int]:
        """A mapped object's value as it is now, for a frame the loop builds of an
        event-driven TPDO (on the loop only: a SYNC's TPDOs use :attr:`view`): the image's
        from the snapshot, the rest from the cell's view."""
        if index < COMMAND:
            return lambda: self._image_value(index, subindex)
        if STATUS_BASE <= index < LAST_SND:
            views, k, j = self.backend.views, index - STATUS_BASE + 1, subindex - 1
            if j == 0:  # the state alone: TPDO1's, built inside every state change
                return lambda: views.state(k)
            return lambda: views.process(k).record[j]
        return lambda: self._read(index, subindex)

    @property
    def view(self) -> Snapshot:
        """What a TPDO or an SDO read may map, as the loop last published it (any thread)."""
        return self._view

    def current(self, statuses: bool = True) -> Snapshot:
        """The snapshot with the changes heard so far published (loop): what a frame the
        loop builds is made of, so a SYNC after it sees what it saw.  The last SND always
        (one read); the processes' status records when ``statuses`` (the frame maps one)."""
        heard = self._heard
        if heard and statuses:
            self._heard = set()
            view = self._view
            status = list(view.status)
            for k in heard:
                if 1 <= k <= len(status):
                    status[k - 1] = self._status_record(k)
            self._view = replace(view, status=tuple(status),
                                 last_snd=_last_snd(self.backend.views.last_snd()),
                                 plc=plc_record(self.backend.views.plc_registers()))
        elif 0 in heard:  # (the records stay noted, for the end of the loop's callback)
            heard.discard(0)
            self._view = replace(self._view,
                                 last_snd=_last_snd(self.backend.views.last_snd()))
        return self._view

    def sample(self) -> Snapshot:
        """Publish the values that change without an event the node hears (block N and
        line, the PLC status) as they are now, with the rest of the processes' status (on
        the loop)."""
        self._heard = set()
        views = self.backend.views  # (the parts it maps: after every SYNC that sent them)
        self._view = replace(self._view, status=tuple(
            self._status_record(k) for k in range(1, self.config.nc.processes + 1)),
            last_snd=_last_snd(views.last_snd()), plc=plc_record(views.plc_registers()))
        return self._view

    def _hear(self, *processes: int) -> None:
        """These processes' status changed (0: the last SND), on the loop: published when a
        frame is built from them, or else once the loop's current callback (the engine's
        turn, the write) is over -- one record per process however many events it had.
        Only while a TPDO is synchronous: nothing else reads them off the loop."""
        if not self.pdos.synchronous:
            return  # nothing on the receive thread reads them (sample() when one does)
        self._heard.update(processes)
        if not self._publish_due:
            self._publish_due = True
            self.call_soon(self._publish_heard)

    def _publish_heard(self) -> None:
        self._publish_due = False
        self.current()

    def sample_later(self) -> None:
        """A SYNC sent sampled values (receive thread): the loop samples them again soon,
        once however many SYNCs ask before it does."""
        if not self._sampling:
            self._sampling = True
            self.call_soon(self._sample_again)

    def _sample_again(self) -> None:
        self._sampling = False  # first: a SYNC from now on asks again
        self.sample()

    # -- threads ----------------------------------------------------------------------------

    def _on_loop(self, fn: Callable[[], T], timeout_s: float = 2.0) -> T:
        """Run ``fn`` on the asyncio loop and wait for its result (from the CAN thread).
        Past ``timeout_s`` it is cancelled (the SDO is aborted) and never runs later."""
        if threading.get_ident() == self._loop_thread:
            return fn()
        future: concurrent.futures.Future[T] = concurrent.futures.Future()
        self._waiting.add(future)
        if self._closed:  # closing: call_soon would drop run, and the wait be in vain
            future.cancel()

        def run() -> None:
            if not future.set_running_or_notify_cancel():
                return  # timed out and aborted: nothing of it may happen now
            try:
                future.set_result(fn())
            except BaseException as exc:  # handed back to the CAN thread
                future.set_exception(exc)

        self.call_soon(run)
        try:
            return future.result(timeout=timeout_s)
        except concurrent.futures.TimeoutError:
            # cancel() fails only once run() has begun: then its result is what counts.
            if future.cancel():
                raise
            return future.result()
        except concurrent.futures.CancelledError:  # the node closes: the master gets an abort
            raise SdoAbortedError(ABORT_GENERAL_ERROR) from None
        finally:
            self._waiting.discard(future)

    def _defer(self, work: Callable[[], None], done: Callable[[int | None], None],
               wanted: Callable[[], bool], timeout_s: float = 2.0) -> None:
        """An SDO write's work, on the loop; ``done`` gets its outcome there.  Not done at all
        when the master moved on meanwhile (``wanted()`` false), or past ``timeout_s`` (the
        master has long given up: it gets an abort, and nothing is applied)."""
        deadline = time.monotonic() + timeout_s

        def run() -> None:
            if not wanted():
                return
            if time.monotonic() > deadline:
                done(ABORT_GENERAL_ERROR)
                return
            try:
                work()
            except SdoAbortedError as exc:
                done(exc.code)
                return
            except Exception:  # a bug of ours: the master gets an abort, not silence
                log.exception("SDO write failed on the loop")
                done(ABORT_GENERAL_ERROR)
                return
            done(None)

        self.call_soon(run)

    def call_soon(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on the loop soon, from any thread; tracked, and dropped once closed.

        Tracked before it is scheduled and untracked by the callback itself, as anyio's
        BlockingPortal keeps its futures: the loop may run a callback before
        ``call_soon_threadsafe`` has returned its handle to this thread, and a handle added
        after that stayed tracked for good (1-2 in 20,000 RPDOs)."""
        assert self.loop is not None
        if self._closed:
            return
        call = _Handoff(self, fn)
        self._pending.add(call)
        try:
            if threading.get_ident() == self._loop_thread:
                self.loop.call_soon(call)
            else:
                self.loop.call_soon_threadsafe(call)
        except RuntimeError:  # the loop is closed: the gateway is gone
            self._pending.discard(call)

    # -- NMT --------------------------------------------------------------------------------

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        command, node = data[0], data[1]
        if node not in (0, self.node_id):
            return
        if command in (0x81, 0x82):  # reset node / reset communication
            # The SDO server restarts with the node: a transfer open before the reset is
            # gone, without an abort (the master that reset the node knows).
            self.node.sdo.reset()  # type: ignore[attr-defined]
            if self._second_sdo is not None:
                self._second_sdo[2].reset()
            self._reset_communication()
            if command == 0x81:
                # Reset node also restores the node's own application values: the SND sender
                # written to 0x2400:2.  The image behind 0x2000..0x23FF is the soft PLC's, not
                # the node's (docs/decisions.md): it is left as it is.
                self.node.data_store.pop(COMMAND, None)
            self._boot()
        elif command == 0x01:
            self.call_soon(self.pdos.entered_operational)
        elif command in (0x02, 0x80):
            # Here, on the receive thread that buffers them, before the next SYNC can apply
            # them: synchronous RPDO data received in OPERATIONAL is stale once it is left.
            self.pdos.discard_sync_rpdos()
            self.call_soon(self.pdos.left_operational)

    def _reset_communication(self) -> None:
        """Communication parameters (0x1000..0x1FFF) back to their power-on values: the
        stored ones (0x1010) or the defaults."""
        for index in [i for i in self.node.data_store if i < 0x2000]:
            del self.node.data_store[index]
        self._restore_stored()
        self.pdos.configure_all()
        self._configure_heartbeats()
        self._configure_second_sdo()

    def _configure_second_sdo(self) -> None:
        """Serve SDO on 0x1201's COB-IDs while both are valid (receive thread, or at start):
        a tool (an HMI, a commissioning laptop) then reads and writes the node without
        sharing 0x600/0x580 + node id with the PLC master.  Its own transfer state."""
        rx, tx = (pdo.param(self.node, SECOND_SDO_SERVER, s) for s in (1, 2))
        wanted = None if (rx | tx) & pdo.NOT_VALID else (rx & 0x7FF, tx & 0x7FF)
        current = self._second_sdo
        if current is not None and current[:2] == wanted:
            return
        if current is not None:
            self.network.unsubscribe(current[0], current[2].on_request)
            current[2].close()
            self._second_sdo = None
        if wanted is not None:
            server = SdoService(wanted[0], wanted[1], self.node)
            server.network = self.network
            self.network.subscribe(wanted[0], server.on_request)
            self._second_sdo = (*wanted, server)

    def _restore_stored(self) -> None:
        stored = store.load(self.store_path)
        if stored is None:
            return
        problem = self._check_stored(stored)
        if problem:
            log.warning("%s: stored CANopen parameters not used (%s); the defaults apply",
                        self.store_path, problem)
            return
        for index, subs in stored.items():
            self.node.data_store[index] = dict(subs)

    def _check_stored(self, stored: store.Parameters) -> str | None:
        """Whether stored parameters fit this dictionary (the config may have changed)."""
        for index, subs in stored.items():
            if not 0x1000 <= index < 0x2000 or index in (STORE, RESTORE, ERROR_HISTORY):
                return f"0x{index:04X} is not a communication parameter"
            for sub, data in subs.items():
                try:
                    obj = self.node.object_for(index, sub)
                except SdoAbortedError:
                    return f"0x{index:04X}:{sub} is not in the dictionary"
                if not obj.writable or 8 * len(data) != len(obj):
                    return f"0x{index:04X}:{sub} does not fit"
        for index, subs in stored.items():  # a mapping must name what this dictionary has
            if pdo.is_pdo_parameter(index) and index & 0x200:
                count = subs.get(0)
                n = int.from_bytes(count, "little") if count else pdo.param(self.node,
                                                                             index, 0)
                for sub in range(1, n + 1):
                    entry = subs.get(sub)
                    value = (int.from_bytes(entry, "little") if entry
                             else pdo.param(self.node, index, sub))
                    try:
                        pdo.mapped_bits(self.node, value, index >= TPDO_MAPPING)
                    except SdoAbortedError:
                        return f"0x{index:04X}:{sub} maps 0x{value:08X}, not mappable here"
        return None

    def _configure_heartbeats(self) -> None:
        assert self.heartbeats is not None
        self.heartbeats.configure([pdo.param(self.node, CONSUMER_HEARTBEAT, s)
                                   for s in range(1, CONSUMER_ENTRIES + 1)])

    # -- SDO: the live image and status -------------------------------------------------------

    def _publish(self) -> None:
        """Everything a TPDO or an SDO read may map, as it is now (loop)."""
        self._publish_image()
        self.sample()

    def _publish_image(self) -> None:
        image = self.backend.image
        self._view = replace(self._view, sa=bytes(image.sa), k=bytes(image.k),
                             syvar=tuple(image.syvar))

    def _on_image(self, values: object, who: str) -> None:
        self._publish_image()
        self.pdos.image_changed()

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> int | None:
        if index == 0x1001:
            return self._on_loop(self._error_register)
        if index == ERROR_HISTORY:
            history = self._history  # one read of what the loop swaps whole
            if subindex == 0:
                return len(history)
            if subindex > len(history):
                raise SdoAbortedError(ABORT_NO_DATA_AVAILABLE)  # no such error recorded
            return history[subindex - 1]
        if index in (STORE, RESTORE) and subindex:
            return 1  # saves and restores on command
        if index < 0x2000 or subindex == 0 or (index == COMMAND and subindex == 4):
            return None  # the dictionary's own value (stored or default)
        if index < COMMAND and self.pdos.done == self.pdos.handed:
            return self._image_value(index, subindex)  # the snapshot, from this thread
        return self._on_loop(lambda: self._read(index, subindex))

    def _image_value(self, index: int, subindex: int) -> int:
        return getter(index, subindex)(self._view)

    def _status_record(self, k: int) -> tuple[int, ...]:
        """0x2500+k-1 sub 1..8, as process k is now (loop): the cell view's record."""
        return self.backend.views.record(k)[:CANOPEN_RECORD]

    def _error_register(self) -> int:
        views = self.backend.views  # (the processes' parts: not the image, not the plant)
        alarms = any(views.process(k).alarm is not None for k in self.backend.engine.processes)
        lost = (REGISTER_GENERIC | REGISTER_COMMUNICATION
                if self._master_lost or self._rpdo_lost or self._rpdo_length
                or self._sync_errors else 0)
        return int(alarms) | lost | (REGISTER_GENERIC if self._fault_emcy is not None else 0)

    def _read(self, index: int, subindex: int) -> int:
        """Any manufacturer object, on the loop: the image from the snapshot, the rest from
        the cell's view."""
        if index < COMMAND:
            return self._image_value(index, subindex)
        views = self.backend.views  # (the part asked for: a TPDO's frame is built per event)
        if STATUS_BASE <= index < LAST_SND:
            return views.process(index - STATUS_BASE + 1).record[subindex - 1]
        if index == LAST_SND:
            return _last_snd(views.last_snd())[subindex - 1]
        if index in OVERRIDE_TOP:
            p = views.process(subindex)
            return p.feed_override if index == FEED_OVERRIDE else p.rapid_override
        if index == PLC_STATUS:
            return plc_record(self.backend.views.plc_registers())[subindex - 1]
        raise SdoAbortedError(ABORT_READ_WRITEONLY)  # 0x2400: write-only

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        # On the CAN thread, before canopen stores the value and answers: an abort raised
        # here refuses the write, and nothing is stored.
        if index < 0x2000:
            number = int.from_bytes(data, "little")
            if pdo.is_pdo_parameter(index):
                pdo.check_write(self.node, index, subindex, number)
            elif index == SYNC_COB_ID:
                pdo.check_sync_cob_id(number)
            elif index == SECOND_SDO_SERVER and subindex in (1, 2):
                _check_server_cob_id(pdo.param(self.node, index, subindex), number,
                                     self.node_id)
            elif index == SYNC_OVERFLOW:
                pdo.check_sync_overflow(number, pdo.param(self.node, CYCLE_PERIOD, 0))
            elif index == CONSUMER_HEARTBEAT:
                entries = [pdo.param(self.node, CONSUMER_HEARTBEAT, s)
                           for s in range(1, CONSUMER_ENTRIES + 1)]
                entries[subindex - 1] = number
                check_entries(entries)
            elif index in (STORE, RESTORE):
                self._store_command(index, number)
            elif index == ERROR_HISTORY:  # sub 0 only (the rest is read-only): 0 clears
                if number != 0:
                    raise SdoAbortedError(ABORT_INVALID_VALUE)
                self._on_loop(self._clear_history)
            elif index == ERROR_BEHAVIOUR and subindex == 1 and number not in (
                    TO_PRE_OPERATIONAL, NO_STATE_CHANGE, TO_STOPPED):
                raise SdoAbortedError(ABORT_INVALID_VALUE)  # reserved or manufacturer's
            return
        value = od.decode_raw(data)
        assert isinstance(value, int)
        if index in OVERRIDE_TOP:
            if value > OVERRIDE_TOP[index]:
                raise SdoAbortedError(ABORT_INVALID_VALUE)
            raise Deferred(lambda: self._write(index, subindex, value))
        if index == COMMAND and subindex == 1:
            # Answered from the loop once the gateway has taken it: every refusal that does
            # not depend on the program (an interlock, a process that cannot take it) is the
            # answer's abort code.  A program to read first is read in a task of the
            # gateway's: the answer does not wait for it, and its outcome shows in the status
            # objects, the EMCY and the trace.
            if command_word(value) is None and (value & 0xFF) not in SEARCH_WORDS:
                raise SdoAbortedError(ABORT_INVALID_VALUE)  # the Modbus command word's
            raise Deferred(lambda: self._run_command(value))
        if index == COMMAND and subindex in (2, 4):
            if subindex == 2:
                self._command(2, value)  # the mailbox's sender: checked here, then stored
            return  # (sub 4: the N number of command words 13/14, stored as it is)
        raise Deferred(lambda: self._write(index, subindex, value))  # answered from the loop

    def _on_stored(self, index: int, subindex: int) -> None:
        """After a write was stored (CAN thread): put it into effect before the answer."""
        if pdo.is_pdo_parameter(index):
            n = (index & 0xFF) + 1
            if index < TPDO_COMMUNICATION:
                self.pdos.configure_rpdo(n)
            else:
                self.call_soon(lambda: self.pdos.configure_tpdo(n))
        elif index == SYNC_COB_ID:
            self.pdos.configure_sync()
        elif index == CYCLE_PERIOD:
            self.pdos.configure_sync_period()
        elif index == SECOND_SDO_SERVER:
            self._configure_second_sdo()
        elif index == CONSUMER_HEARTBEAT:
            self._configure_heartbeats()

    def _store_command(self, index: int, value: int) -> None:
        """0x1010 "save" / 0x1011 "load" (CiA 301): any other value is refused, 0x08000020."""
        if index == STORE and value == store.SAVE:
            parameters = {i: dict(subs) for i, subs in list(self.node.data_store.items())
                          if 0x1000 <= i < 0x2000
                          and i not in (STORE, RESTORE, ERROR_HISTORY)}
            try:
                store.save(self.store_path, parameters)
            except OSError as exc:
                log.error("CANopen parameters not stored: %s", exc)
                raise SdoAbortedError(ABORT_STORE_APPLICATION) from None
            log.info("CANopen communication parameters stored in %s", self.store_path)
        elif index == RESTORE and value == store.LOAD:
            try:
                store.remove(self.store_path)
            except OSError as exc:
                log.error("stored CANopen parameters not removed: %s", exc)
                raise SdoAbortedError(ABORT_STORE_APPLICATION) from None
            log.info("CANopen defaults restored: in effect after the next reset")
        else:
            raise SdoAbortedError(ABORT_STORE_APPLICATION)

    def _run_command(self, word: int) -> None:
        command = command_word(word)
        try:
            if command is None:  # 13..15: with the N number of 0x2400:4
                n = self.node.data_store.get(COMMAND, {}).get(4)
                number = int.from_bytes(n, "little") if n else 0
                for item in search_inputs(word, number, self.backend.runtime,
                                          self._sdo_source) or ():
                    self.backend.apply(item)
                return
            self.backend.apply(Command(command[0], command[1], self._sdo_source))
        except InputRefused as exc:  # the answer: its abort code, and a line in the log
            self._refusals.note(f"command {word} written through 0x2400:1 refused: {exc}")
            raise SdoAbortedError(REFUSAL[exc.reason]) from None

    def _write(self, index: int, subindex: int, value: int) -> None:
        try:
            if index < COMMAND:
                self.backend.apply(Write(Var(*image_target(index, subindex)), value,
                                         self._sdo_source))
            elif index == COMMAND:
                self._command(subindex, value)
            elif index in OVERRIDE_TOP:
                feed = value if index == FEED_OVERRIDE else None
                rapid = value if index == RAPID_OVERRIDE else None
                self.backend.apply(Override(feed, rapid, subindex, self._sdo_source))
        except InputRefused as exc:
            raise SdoAbortedError(REFUSAL[exc.reason]) from None

    def _command(self, subindex: int, value: int) -> None:
        nc = self.config.nc
        if subindex == 2:
            if value not in nc.external:
                raise SdoAbortedError(ABORT_INVALID_VALUE)  # only an external process sends
        else:
            if not 1 <= value <= nc.processes:
                raise SdoAbortedError(ABORT_INVALID_VALUE)  # an unknown SND target
            stored = self.node.data_store.get(COMMAND, {}).get(2)
            if stored is None:
                raise SdoAbortedError(ABORT_APPLICATION_DEVICE_STATE)  # no sender written yet
            self.backend.apply(Snd(stored[0], value, self._sdo_source))

    # -- the master's heartbeat (loop) ------------------------------------------------------

    def _on_master_lost(self, node_id: int, ms: int) -> None:
        self._master_lost.add(node_id)
        self._lost(f"no heartbeat from node {node_id} for {ms} ms (0x1016)",
                   Source(SourceKind.CANOPEN, f"heartbeat of node {node_id}"),
                   EMCY_HEARTBEAT, node_id)

    def rpdo_timeout(self, n: int, ms: int) -> None:
        """RPDO n's deadline ran out (loop): the master's heartbeat may live on while its
        PDOs stopped -- the same alarm and reactions as a lost master, EMCY 0x8250."""
        self._rpdo_lost.add(n)
        self._lost(f"no RPDO{n} for {ms} ms (0x{RPDO_COMMUNICATION + n - 1:04X}:5)",
                   Source(SourceKind.CANOPEN, f"RPDO{n} deadline"), pdo.EMCY_RPDO_TIMEOUT, n)

    def rpdo_back(self, n: int) -> None:
        if n not in self._rpdo_lost:
            return
        self._rpdo_lost.discard(n)
        log.warning("CANopen: RPDO%d comes again (%s)", n,
                    _BACK[self.config.canopen.on_master_lost])
        self._emcy_reset()

    def rpdo_length(self, n: int, emcy: int) -> None:
        """RPDO n's length error began (its EMCY) or ended (an error reset), on the loop."""
        if emcy:
            self._rpdo_length.add(n)
        elif n in self._rpdo_length:
            self._rpdo_length.discard(n)
        else:
            return
        if emcy:
            self._emcy_error(emcy, struct.pack("<B4x", n), n)
        else:
            self._emcy_reset()

    def sync_error(self, emcy: int, on: bool) -> None:
        """A SYNC error began (its EMCY: 0x8100 timeout, 0x8240 length) or ended (an error
        reset), on the loop.  No process reaction: the master's heartbeat says whether it
        lives; the SYNC's timing is the PDOs' concern."""
        if on == (emcy in self._sync_errors):
            return
        if on:
            self._sync_errors.add(emcy)
            log.warning("CANopen: SYNC %s", "timeout (0x1006)" if emcy == pdo.EMCY_SYNC_TIMEOUT
                        else "length disagrees with 0x1019")
        else:
            self._sync_errors.discard(emcy)
        if on:
            self._emcy_error(emcy)
        else:
            self._emcy_reset()

    def _lost(self, what: str, source: Source, emcy: int, detail: int) -> None:
        """A communication error (loop): alarm AL150, its EMCY, 0x1029's NMT reaction,
        then canopen.on_master_lost's for the processes."""
        if self._closed:
            return  # a deadline that ran out as the node closed: nobody is lost
        reaction = self.config.canopen.on_master_lost
        done = {MasterLost.NONE: "no reaction (canopen.on_master_lost = \"none\")",
                MasterLost.HOLD: "feed hold", MasterLost.RESET: "reset"}[reaction]
        self.backend.apply(FieldbusAlarm(AlarmCode.MASTER_LOST, f"CANopen: {what}; {done}",
                                         source))
        self._emcy_error(emcy, struct.pack("<B4x", detail), detail)
        self._communication_error()
        if reaction is MasterLost.HOLD:
            self.backend.apply(Command(CommandKind.FEED_HOLD, None, source))
        elif reaction is MasterLost.RESET:
            self.backend.apply(Command(CommandKind.RESET, None, source))

    def _communication_error(self) -> None:
        """0x1029:1, the NMT state's reaction to a communication error, after its EMCY
        (CiA 301 7.5.2.32); the processes' reaction is canopen.on_master_lost's."""
        behaviour = pdo.param(self.node, ERROR_BEHAVIOUR, 1)
        if behaviour == TO_PRE_OPERATIONAL and self.operational:
            command, state = 0x80, "PRE-OPERATIONAL"
        elif behaviour == TO_STOPPED and not self.stopped:
            command, state = 0x02, "STOPPED"
        else:
            return
        log.warning("CANopen: communication error: the node goes %s (0x1029:1 = %d)", state,
                    behaviour)
        self.node.nmt.send_command(command)
        self.pdos.discard_sync_rpdos()
        self.pdos.left_operational()

    def _on_master_back(self, node_id: int) -> None:
        if node_id not in self._master_lost:
            return
        self._master_lost.discard(node_id)
        log.warning("CANopen: the heartbeat of node %d is back (%s)", node_id,
                    _BACK[self.config.canopen.on_master_lost])
        # The heartbeat error is over: EMCY 0x0000 with the register as it is now (CiA 301
        # 7.2.7.1), so a master sees a process alarm that remains (register bit 0).
        self._emcy_reset()

    # -- EMCY, the error history and the inhibit time (loop) ----------------------------------

    def _emcy_error(self, code: int, data: bytes = b"", info: int = 0) -> None:
        """An error occurs: recorded in 0x1003 (newest first; the upper 16 bits say more:
        the alarm code, the node or PDO number), then its EMCY with the register as it is."""
        self._history = ((info & 0xFFFF) << 16 | code, *self._history)[:HISTORY_ENTRIES]
        self._emit(code, data)

    def _emcy_reset(self) -> None:
        """An error is over: EMCY 0x0000 with the register as it is now."""
        self._emit(0, b"")

    def _emit(self, code: int, data: bytes) -> None:
        if self.stopped or self._closed:
            return  # no EMCY in STOPPED (CiA 301; the history keeps the error), nor closed
        if len(self._emcy_queue) == EMCY_QUEUE:
            self._emcy_queue.popleft()
        self._emcy_queue.append(struct.pack("<HB5s", code, self._error_register(), data))
        self._emcy_next()

    def _emcy_next(self) -> None:
        """Send what waits, each EMCY at least 0x1015 (100 us units) after the last."""
        while self._emcy_queue and self._emcy_timer is None:
            inhibit_s = pdo.param(self.node, EMCY_INHIBIT, 0) * 100e-6
            wait = self._emcy_last + inhibit_s - self.clock.monotonic()
            if wait > 0:
                self._emcy_timer = self.clock.call_later(wait, self._emcy_due)
                return
            payload = self._emcy_queue.popleft()
            if not self.stopped:
                self.network.send_message(0x80 + self.node_id, payload)
                self._emcy_last = self.clock.monotonic()

    def _emcy_due(self) -> None:
        self._emcy_timer = None
        self._emcy_next()

    def _clear_history(self) -> None:
        self._history = ()

    # -- PDO triggers (loop) -------------------------------------------------------------------

    def _on_state(self, process: Process | None, old: ProcessState) -> None:
        if process is None:
            self._hear(*range(1, self.config.nc.processes + 1))
        else:
            self._hear(process.number)
        self.pdos.status_changed()

    def _on_event(self, event: Event) -> None:
        # Heard first, for the TPDOs below and the receive thread's next SYNC: an SND (or a
        # signal, which counts like one) changes its sender's and its targets' counts and the
        # last SND; any other event of a process its wait, alarm, N or line.  Not an image
        # write: the image publishes itself, and a program may write every block.
        if isinstance(event, ev.Snd):
            self._hear(0, event.proc, event.to)
        elif isinstance(event, ev.Signal):
            targets = event.to if isinstance(event.to, tuple) else range(
                1, self.config.nc.processes + 1)
            self._hear(0, event.proc, *targets)
        elif not isinstance(event, ev.Write) and event.proc:
            self._hear(event.proc)
        if isinstance(event, ev.Alarm):
            if event.proc == 0:
                return  # a fieldbus alarm: its own EMCY (above)
            self._alarmed = True
            self._emcy_error(EMCY_SOFTWARE, struct.pack("<BH2x", event.proc & 0xFF,
                                                        int(event.code) & 0xFFFF),
                             int(event.code))
        elif isinstance(event, ev.End) and event.how == "reset" and self._alarmed:
            # A reset clears the alarms one process at a time: when none is left, say so.
            if self._error_register() == 0:
                self._alarmed = False
                self._emcy_reset()
        elif isinstance(event, ev.Snd | ev.Signal):  # a signal counts like an SND (spec 5.6)
            self.pdos.snd()


# What the log says when a lost master's heartbeat comes back, by canopen.on_master_lost.
_BACK = {
    MasterLost.HOLD: "the processes stay as they are: cycle start resumes the hold",
    MasterLost.RESET: "the processes were reset when it was lost: a cycle start runs the "
                      "main program again",
    MasterLost.NONE: "nothing was done when it was lost (canopen.on_master_lost = \"none\"): "
                     "the processes ran on",
}


def _check_server_cob_id(current: int, cob: int, node_id: int) -> None:
    """0x1201's COB-IDs (CiA 301 7.5.2.33): 11 bits (bits 11..30 clear), changed only while
    invalid, not an identifier CiA 301 table 3 reserves for NMT, SYNC/EMCY/TIME, heartbeat
    or LSS, and not the default server's own: 0x06090030 otherwise."""
    can_id = cob & 0x7FF
    if cob & 0x7FFFF800:
        raise SdoAbortedError(ABORT_INVALID_VALUE)
    if not (current | cob) & pdo.NOT_VALID and (current ^ cob) & 0x7FF:
        raise SdoAbortedError(ABORT_INVALID_VALUE)
    if not cob & pdo.NOT_VALID and (
            can_id in (0x600 + node_id, 0x580 + node_id)
            or (pdo.restricted(can_id) and not 0x581 <= can_id <= 0x67F)):
        raise SdoAbortedError(ABORT_INVALID_VALUE)


def _last_snd(last: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
    """0x2600 sub 1..4 (the event number, sender, target, block N) of the view's last SND."""
    sender, target, n, number = last
    return number & 0xFFFFFFFF, sender, target, n & 0xFFFF
