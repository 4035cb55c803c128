"""The OPC UA server: asyncua in a process of its own, fed by the gateway's loop
(docs/decisions.md, "OPC UA: a process of its own fed snapshots").

asyncua's ``init`` builds the standard address space in one go, holding the interpreter for
0.2 s even on a thread, and its subscriptions publish with no budget: on the gateway's loop,
or on a thread of the gateway's process, they would make the PLC scan and the pollers late
(bench/opcua.py).  So the server is ``python -m ncgate.gateway.opcua.space``, and this module
is the gateway's side of it: it imports no asyncua, and hands the process what changed
(:mod:`ncgate.gateway.opcua.model`), in the frames of :mod:`ncgate.gateway.opcua.wire`:

- a process's view inside each change of its state (the engine's state listeners), so that a
  subscription sees every state, in order;
- the image once per loop turn in which it was written (the image's listeners mark it, one
  ``call_soon`` sends it), and alarms and part-program messages as they are traced;
- the sampled values (the block, the line, the positions, the PLC status) every ``SAMPLE_S``.

A client's write of an image node comes back as a frame, goes through ``Gateway.apply``
attributed ``opcua <peer>`` (or ``opcua <user>``), and the refusal's reason goes back, which
the process answers with the status code of :data:`ncgate.gateway.opcua.codes.REFUSAL`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from ncgate.config.schema import OpcuaConfig
from ncgate.errors import InputRefused, Reason
from ncgate.gateway.errors import GatewayError, listen_error
from ncgate.gateway.opcua.model import (
    ALARM_SEVERITY,
    MESSAGE_SEVERITY,
    EventView,
    PlantView,
    PlcView,
    ProcessView,
    StateView,
    machine_name,
    plant_views,
    plc_view,
    process_view,
    snd_text,
    state_view,
)
from ncgate.gateway.opcua.wire import frame, read_frame
from ncgate.inputs import Source, SourceKind, Write
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine.events import Alarm, Display, Snd
from ncgate.interpreter.engine.states import describe_where

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.interpreter.engine import Process, ProcessState

log = logging.getLogger("ncgate.opcua")

SAMPLE_S = 0.1  # how often the values without an event (line, block, position, PLC) are read
START_TIMEOUT_S = 60.0  # the process's start: an interpreter, asyncua, 2,000 nodes
# The process keeps nothing: past this it is killed, so that SIGTERM ends the gateway within
# its second.  (asyncua closing 10 sessions of 2,000 monitored items took 3.6 s at nice 10 on
# a busy machine: bench/storm.py, phase opcua.)  Its clients see the connection close.
STOP_TIMEOUT_S = 0.5
BEHIND_BYTES = 4 << 20  # frames not yet read by the process: past this, they wait here
REGION = {"SA": "sa_bits", "SK": "k_bytes", "SYVAR": "syvars"}  # opcua.writable's names


class OpcuaServer:
    """The adapter (``Adapter``: ``start``, ``close``)."""

    def __init__(self, gw: Gateway) -> None:
        self.gw = gw
        self.config: OpcuaConfig = gw.config.opcua
        self.endpoint: str | None = None
        self.address: tuple[str, int] | None = None
        self.writes = 0
        self.refused = 0
        self.sessions = 0  # the clients' sessions and subscriptions, as the process tells
        self.subscriptions = 0
        self._loop: asyncio.AbstractEventLoop | None = None  # the gateway's
        self._process: asyncio.subprocess.Process | None = None
        self._reader: asyncio.Task[None] | None = None
        self._ready: asyncio.Future[int] | None = None
        self._closing = False
        self._detach: list[Callable[[], None]] = []
        self._batch: list[tuple[str, Any]] = []
        self._flush_due = False
        self._image_dirty = False
        self._sampler: asyncio.TimerHandle | None = None
        self._last: dict[int, ProcessView] = {}
        self._last_state: dict[int, StateView] = {}
        self._last_plc: PlcView | None = None
        self._last_plant: tuple[PlantView, ...] = ()

    # -- the gateway's loop ----------------------------------------------------------------

    async def start(self) -> None:
        loop = self._loop = asyncio.get_running_loop()
        self._ready = loop.create_future()
        self._process = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "ncgate.gateway.opcua.space",
            stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE)
        self._send(("start", self.config, self._layout()))
        self._reader = loop.create_task(self._read())
        try:
            async with asyncio.timeout(START_TIMEOUT_S):
                port = await self._ready
        except BaseException:
            await self.close()
            raise
        self.address = (self.config.host, port)
        self.endpoint = f"opc.tcp://{self.config.host}:{port}/"
        engine, image = self.gw.engine, self.gw.image
        engine.state_listeners.append(self._on_state)
        self._detach.append(lambda: engine.state_listeners.remove(self._on_state))
        self._detach.append(image.subscribe(self._on_write))
        self._detach.append(self.gw.runtime.trace.subscribe(self._on_event))
        self._image_dirty = True
        self._sample()

    def _send(self, message: Any) -> None:
        process = self._process
        if process is not None and process.stdin is not None and not self._closing:
            process.stdin.write(frame(message))

    async def _read(self) -> None:
        """The process's frames: ready, an error at its start, a client's write, the count of
        its clients' sessions and subscriptions."""
        process, ready = self._process, self._ready
        assert process is not None and process.stdout is not None and ready is not None
        try:
            while True:
                message = await read_frame(process.stdout)
                kind = message[0]
                if kind == "ready" and not ready.done():
                    ready.set_result(message[1])
                elif kind == "error" and not ready.done():
                    ready.set_exception(GatewayError(f"OPC UA server: {message[1]}"))
                elif kind == "listen_error" and not ready.done():
                    _, number, reason = message
                    why = OSError(number, os.strerror(number) if number else reason)
                    ready.set_exception(listen_error(why, "opcua.port", self.config.host,
                                                     self.config.port))
                elif kind == "clients":
                    _, self.sessions, self.subscriptions = message
                elif kind == "write":
                    _, number, key, value, who = message
                    try:
                        result: Reason | str | None = self.write_on_loop(key, value, who)
                    except Exception:  # not a refusal: the client gets BadInternalError
                        log.exception("opcua %s: write of %s", who, key)
                        result = "error"
                    self._send(("result", number, result))
        except EOFError:
            if not ready.done():
                ready.set_exception(GatewayError("OPC UA server: its process ended before "
                                                 "it served (its log is on stderr)"))
            elif not self._closing:
                log.error("the OPC UA server's process ended (its log is on stderr)")
                self._closing = True  # nothing reads its pipe any more

    def _layout(self) -> dict[str, Any]:
        """What the address space is made of, read here once (the process builds it)."""
        gw = self.gw
        plc = gw.config.plc
        runtime = gw.runtime
        symbols = {name: str(runtime.var(name)) for name in gw.config.symbols}
        source = gw.config.source
        return {"cell": source.stem if source is not None else "ncgate",  # its certificate's
                "machine": machine_name(source),
                "plant": [model.name for model in gw.config.plant.model],
                "processes": sorted(gw.engine.processes),
                "sa_bits": plc.sa_bits, "k_bytes": plc.k_bytes, "syvars": plc.syvars,
                "symbols": symbols, "comments": dict(gw.config.symbols.comments)}

    def _on_state(self, process: Process, old: ProcessState) -> None:
        # Every change, in order (a sampler would miss a short state); its state only.
        view = state_view(process)
        if self._last_state.get(process.number) != view:
            self._last_state[process.number] = view
            self._push(("state", view))

    def _send_process(self, number: int) -> None:
        view = process_view(self.gw, number)
        if self._last.get(number) != view:
            self._last[number] = view
            self._push(("process", view))

    def _on_write(self, changes: Sequence[Any], writer: str) -> None:
        if not self._image_dirty:
            self._image_dirty = True
            self._schedule()

    def _on_event(self, event: Any) -> None:
        kind = type(event)
        if kind is Alarm:
            code = AlarmCode(event.code).label
            # The report names the process and the block, as the console's alarm line does.
            where = f" {describe_where(event.where)}" if event.where is not None else ""
            report = f"P{event.proc}{where}: {code} {event.message}"
            self._push(("event", EventView(True, event.proc, code, report, ALARM_SEVERITY)))
        elif kind is Snd:
            where = describe_where(event.where) if event.where is not None else ""
            self._push(("snd", snd_text(event.t, event.proc, event.to, where)))
        elif kind is Display:
            self._push(("event", EventView(False, event.proc, "", event.text,
                                           MESSAGE_SEVERITY)))

    def _sample(self) -> None:
        """The values that change without an event, every SAMPLE_S."""
        assert self._loop is not None
        for number in self.gw.engine.processes:
            self._send_process(number)
        plant = plant_views(self.gw)
        if plant != self._last_plant:
            self._last_plant = plant
            self._push(("plant", plant))
        plc = plc_view(self.gw)
        if plc != self._last_plc:
            self._last_plc = plc
            self._push(("plc", plc))
        self._schedule()
        self._sampler = self._loop.call_later(SAMPLE_S, self._sample)

    def _push(self, item: tuple[str, Any]) -> None:
        if self._image_dirty:
            # A write that changed the image comes before what it caused (a WAI that resumed,
            # an alarm): the image as it is now goes first.
            self._image_dirty = False
            self._batch.append(("image", self.gw.image.snapshot()))
        self._batch.append(item)
        self._schedule()

    def _schedule(self) -> None:
        if not self._flush_due and self._loop is not None:
            self._flush_due = True
            self._loop.call_soon(self._flush)

    def _flush(self) -> None:
        """Hand what changed in this loop turn to the server's process, in order."""
        self._flush_due = False
        if self._image_dirty:
            self._image_dirty = False
            self._batch.append(("image", self.gw.image.snapshot()))
        process = self._process
        if not self._batch or process is None or process.stdin is None:
            return
        if process.stdin.transport.get_write_buffer_size() > BEHIND_BYTES:
            return  # the process is behind: this turn's changes join the next hand-over
        batch, self._batch = self._batch, []
        self._send(("batch", batch))

    async def close(self) -> None:
        for detach in self._detach:
            detach()
        self._detach = []
        if self._sampler is not None:
            self._sampler.cancel()
        process, self._process = self._process, None
        if process is not None:
            if process.stdin is not None and not self._closing:
                with contextlib.suppress(ConnectionError):
                    process.stdin.write(frame(("stop",)))
                process.stdin.close()
            self._closing = True
            try:
                async with asyncio.timeout(STOP_TIMEOUT_S):
                    await process.wait()
            except TimeoutError:
                log.info("opcua: the server's process did not stop within %g s: killed",
                         STOP_TIMEOUT_S)
                process.kill()
                await process.wait()
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reader

    def write_on_loop(self, key: str, value: Any, who: str) -> Reason | None:
        """A client's write of an image node (``key``: ``SA10`` or an I/O name), on the
        gateway's loop: why it was refused, or None."""
        try:
            var = self.gw.runtime.var(key)
            if REGION[var.area] not in self.config.writable:
                raise InputRefused(Reason.READ_ONLY, f"{var}: opcua.writable does not list "
                                   f"{REGION[var.area]}")
            if self.config.users and not who.startswith("user "):
                raise InputRefused(Reason.ROLE_FORBIDS, "an anonymous session only reads")
            if isinstance(value, bool):
                value = int(value)
            if not isinstance(value, int):
                raise InputRefused(Reason.BAD_VALUE, f"{var}: expected an integer")
            detail = who.removeprefix("user ")
            self.gw.apply(Write(var, value, Source(SourceKind.OPCUA, detail)))
        except InputRefused as refused:
            self.refused += 1
            log.info("opcua %s: write of %s refused: %s", who, key, refused)
            return refused.reason
        self.writes += 1
        return None
