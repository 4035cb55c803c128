"""The OPC UA server: asyncua on a thread and an event loop of its own, fed by the gateway's
loop (docs/decisions.md, "OPC UA: a thread of its own fed snapshots").

asyncua's ``init`` builds the standard address space in one go (measured: 0.3-1 s with the
loop held), and its subscriptions publish with no budget; on the gateway's loop either would
make the PLC scan late.  So the server runs on a thread with its own loop, and the gateway's
loop only hands it what changed (:mod:`ncgate.gateway.opcua.model`):

- a process's view inside each change of its state (the engine's state listeners), so that a
  subscription sees every state, in order;
- the image once per loop turn in which it was written (the image's listeners mark it, one
  ``call_soon`` sends it), and alarms and part-program messages as they are traced;
- the sampled values (the block, the line, the positions, the PLC status) every ``SAMPLE_S``.

The thread writes them into the nodes (only the values that changed); asyncua's subscriptions
take it from there.  A client's write of an image node hops onto the gateway's loop, goes
through ``Gateway.apply`` attributed ``opcua <peer>`` (or ``opcua <user>``), and its refusal
comes back as the status code of :data:`ncgate.gateway.opcua.codes.REFUSAL`.

This module is the gateway loop's side and imports no asyncua: the server's side
(:mod:`ncgate.gateway.opcua.space`) is imported on the thread, since importing asyncua holds
the interpreter for 0.2-0.5 s (bench/opcua.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from ncgate.config.loader import OpcuaConfig
from ncgate.errors import InputRefused, Reason
from ncgate.gateway.errors import GatewayError
from ncgate.gateway.opcua.model import (
    ALARM_SEVERITY,
    MESSAGE_SEVERITY,
    EventView,
    PlcView,
    ProcessView,
    plc_view,
    process_view,
)
from ncgate.inputs import Source, SourceKind, Write
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine.events import Alarm, Display
from ncgate.interpreter.engine.states import describe_where

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.opcua.space import Space
    from ncgate.interpreter.engine import Process, ProcessState

log = logging.getLogger("ncgate.opcua")

SAMPLE_S = 0.1  # how often the values without an event (line, block, position, PLC) are read
START_TIMEOUT_S = 30.0
REGION = {"SA": "sa_bits", "SK": "k_bytes", "SYVAR": "syvars"}  # opcua.writable's names


class OpcuaServer:
    """The adapter (``Adapter``: ``start``, ``close``)."""

    def __init__(self, gw: Gateway) -> None:
        self.gw = gw
        self.config: OpcuaConfig = gw.config.opcua
        self.endpoint: str | None = None
        self.address: tuple[str, int] | None = None
        self.sessions = 0
        self.writes = 0
        self.refused = 0
        self.config_symbols = frozenset(gw.config.symbols)  # (the server's thread reads it)
        self._loop: asyncio.AbstractEventLoop | None = None  # the gateway's
        self.space: Space | None = None  # the server's side, set on its thread
        self._thread: threading.Thread | None = None
        self._done: asyncio.Future[None] | None = None
        self._detach: list[Callable[[], None]] = []
        self._batch: list[tuple[str, Any]] = []
        self._flush_due = False
        self._image_dirty = False
        self._sampler: asyncio.TimerHandle | None = None
        self._last: dict[int, ProcessView] = {}
        self._last_plc: PlcView | None = None

    # -- the gateway's loop ----------------------------------------------------------------

    async def start(self) -> None:
        loop = self._loop = asyncio.get_running_loop()
        ready: asyncio.Future[tuple[str, int]] = loop.create_future()
        self._done = loop.create_future()
        layout = self._layout()
        self._thread = threading.Thread(target=self._run, args=(ready, layout),
                                        name="ncgate-opcua", daemon=True)
        self._thread.start()
        async with asyncio.timeout(START_TIMEOUT_S):
            self.address = await ready
        host, port = self.address
        self.endpoint = f"opc.tcp://{host}:{port}/"
        engine, image = self.gw.engine, self.gw.image
        engine.state_listeners.append(self._on_state)
        self._detach.append(lambda: engine.state_listeners.remove(self._on_state))
        self._detach.append(image.subscribe(self._on_write))
        self._detach.append(self.gw.runtime.trace.subscribe(self._on_event))
        self._image_dirty = True
        self._sample()

    def _layout(self) -> dict[str, Any]:
        """What the address space is made of, read here once (the thread builds it)."""
        gw = self.gw
        plc = gw.config.plc
        runtime = gw.runtime
        symbols = {name: str(runtime.var(name)) for name in gw.config.symbols}
        source = gw.config.source
        return {"cell": source.stem if source is not None else "ncgate",
                "processes": sorted(gw.engine.processes),
                "sa_bits": plc.sa_bits, "k_bytes": plc.k_bytes, "syvars": plc.syvars,
                "symbols": symbols, "comments": dict(gw.config.symbols.comments)}

    def _on_state(self, process: Process, old: ProcessState) -> None:
        self._send_process(process.number)

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
        elif kind is Display:
            self._push(("event", EventView(False, event.proc, "", event.text,
                                           MESSAGE_SEVERITY)))

    def _sample(self) -> None:
        """The values that change without an event, every SAMPLE_S."""
        assert self._loop is not None
        for number in self.gw.engine.processes:
            self._send_process(number)
        plc = plc_view(self.gw)
        if plc != self._last_plc:
            self._last_plc = plc
            self._push(("plc", plc))
        self._schedule()
        self._sampler = self._loop.call_later(SAMPLE_S, self._sample)

    def _push(self, item: tuple[str, Any]) -> None:
        self._batch.append(item)
        self._schedule()

    def _schedule(self) -> None:
        if not self._flush_due and self._loop is not None:
            self._flush_due = True
            self._loop.call_soon(self._flush)

    def _flush(self) -> None:
        """Hand what changed in this loop turn to the server's thread, in order."""
        self._flush_due = False
        if self._image_dirty:
            self._image_dirty = False
            self._batch.append(("image", self.gw.image.snapshot()))
        batch, self._batch = self._batch, []
        space = self.space
        if batch and space is not None and space.loop is not None and space.inbox is not None:
            space.loop.call_soon_threadsafe(space.inbox.put_nowait, batch)

    async def close(self) -> None:
        for detach in self._detach:
            detach()
        self._detach = []
        if self._sampler is not None:
            self._sampler.cancel()
        space = self.space
        if space is not None and space.loop is not None and space.stop is not None:
            with contextlib.suppress(RuntimeError):  # its loop has ended already
                space.loop.call_soon_threadsafe(space.stop.set)
        if self._done is not None:
            await self._done

    @property
    def gateway_loop(self) -> asyncio.AbstractEventLoop:
        assert self._loop is not None
        return self._loop

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

    # -- the server's thread ---------------------------------------------------------------

    def _run(self, ready: asyncio.Future[tuple[str, int]], layout: dict[str, Any]) -> None:
        """The server's thread: asyncua imported and served here, never on the loop."""
        loop = self.gateway_loop
        try:
            from ncgate.gateway.opcua.space import serve

            serve(self, ready, layout)
        except BaseException as exc:  # to the gateway's loop, which raises it in start()
            error = GatewayError(f"OPC UA server: {exc}")

            def fail() -> None:
                if not ready.done():
                    ready.set_exception(error)
            if not loop.is_closed():
                loop.call_soon_threadsafe(fail)
        finally:
            done = self._done
            if done is not None and not loop.is_closed():
                loop.call_soon_threadsafe(lambda: None if done.done() else done.set_result(None))
