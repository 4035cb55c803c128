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
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import hashlib
import hmac
import logging
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from asyncua import ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.internal_session import InternalSession
from asyncua.server.server import Server
from asyncua.server.user_managers import UserManager
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes

from ncgate import __version__
from ncgate.config.loader import OpcuaConfig, UaSecurity
from ncgate.errors import InputRefused, Reason
from ncgate.gateway.errors import GatewayError
from ncgate.gateway.opcua.codes import REFUSAL
from ncgate.gateway.opcua.model import (
    ALARM_SEVERITY,
    MESSAGE_SEVERITY,
    EventView,
    PlcView,
    ProcessView,
    plc_view,
    process_view,
)
from ncgate.inputs import Source, SourceKind, Var, Write
from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.engine.events import Alarm, Display
from ncgate.interpreter.engine.states import describe_where

if TYPE_CHECKING:
    from asyncua.common.node import Node
    from asyncua.server.event_generator import EventGenerator

    from ncgate.gateway.app import Gateway
    from ncgate.interpreter.engine import Process, ProcessState

log = logging.getLogger("ncgate.opcua")

SAMPLE_S = 0.1  # how often the values without an event (line, block, position, PLC) are read
START_TIMEOUT_S = 30.0

# The companion specifications' namespaces (their URIs as the OPC Foundation publishes them).
DI = "http://opcfoundation.org/UA/DI/"
MACHINERY = "http://opcfoundation.org/UA/Machinery/"
MACHINE_TOOL = "http://opcfoundation.org/UA/MachineTool/"
CNC = "http://opcfoundation.org/UA/CNC"
IMAGE = "urn:ncgate:image"  # the image, the PLC, the processes as ncgate names them
NCGATE = "urn:ncgate:ua"  # ncgate's own nodes (the instances, the stand-in types)
# The numeric ids OPC 40501-1's nodeset gives its types (what a client may look a type up by).
MACHINE_TOOL_TYPE_ID = 13
ALERT_TYPE_ID = 39

_REGION = {"SA": "sa_bits", "SK": "k_bytes", "SYVAR": "syvars"}  # opcua.writable's names
_VTYPE = {"SA": ua.VariantType.Boolean, "SK": ua.VariantType.Byte,
          "SYVAR": ua.VariantType.Int16}
_SECURITY = {
    UaSecurity.NONE: [ua.SecurityPolicyType.NoSecurity],
    UaSecurity.SIGN: [ua.SecurityPolicyType.Basic256Sha256_Sign],
    UaSecurity.SIGN_ENCRYPT: [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt],
}


def password_matches(stored: str, password: str) -> bool:
    """``stored`` is ``pbkdf2_sha256$<iterations>$<salt>$<hex>`` (``[opcua.users]``)."""
    _, iterations, salt, digest = stored.split("$")
    mine = hashlib.pbkdf2_hmac("sha256", password.encode(), salt.encode(), int(iterations))
    return hmac.compare_digest(mine.hex(), digest)


class _Users(UserManager):
    """Anonymous sessions read; a name and password of ``[opcua.users]`` may write."""

    def __init__(self, users: dict[str, str]) -> None:
        self.users = users

    def get_user(self, iserver: Any, username: str | None = None,
                 password: str | None = None, certificate: Any = None) -> User | None:
        if username is None:  # asyncua's rules let its Anonymous role read nothing
            return User(role=UserRole.User)
        stored = self.users.get(username)
        if stored is None or password is None or not password_matches(stored, password):
            return None  # asyncua answers BadUserAccessDenied
        return User(role=UserRole.User, name=username)


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
        self._loop: asyncio.AbstractEventLoop | None = None  # the gateway's
        self._ua_loop: asyncio.AbstractEventLoop | None = None  # the server's thread's
        self._thread: threading.Thread | None = None
        self._stop: asyncio.Event | None = None  # set on the server's loop
        self._done: asyncio.Future[None] | None = None
        self._detach: list[Callable[[], None]] = []
        self._batch: list[tuple[str, Any]] = []
        self._flush_due = False
        self._image_dirty = False
        self._sampler: asyncio.TimerHandle | None = None
        self._last: dict[int, ProcessView] = {}
        self._last_plc: PlcView | None = None
        # The server's side (its thread only).
        self._server: Server | None = None
        self._nodes: dict[str, ua.NodeId] = {}  # a value's key -> its node
        self._symbol_nodes: dict[str, list[ua.NodeId]] = {}  # a variable -> its I/O names'
        self._values: dict[str, Any] = {}  # what each node shows now
        self._inbox: asyncio.Queue[list[tuple[str, Any]]] | None = None
        self._alerts: EventGenerator | None = None
        self._messages: EventGenerator | None = None
        self.image_ns = 0

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
        ua_loop, inbox = self._ua_loop, self._inbox
        if batch and ua_loop is not None and inbox is not None:
            ua_loop.call_soon_threadsafe(inbox.put_nowait, batch)

    async def close(self) -> None:
        for detach in self._detach:
            detach()
        self._detach = []
        if self._sampler is not None:
            self._sampler.cancel()
        if self._ua_loop is not None and self._stop is not None:
            with contextlib.suppress(RuntimeError):  # its loop has ended already
                self._ua_loop.call_soon_threadsafe(self._stop.set)
        if self._done is not None:
            await self._done

    def _write_on_loop(self, key: str, value: Any, who: str) -> int:
        """A client's write of an image node, on the gateway's loop: the status code."""
        try:
            var = self.gw.runtime.var(key)
            if _REGION[var.area] not in self.config.writable:
                raise InputRefused(Reason.READ_ONLY, f"{var}: opcua.writable does not list "
                                   f"{_REGION[var.area]}")
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
            return REFUSAL[refused.reason]
        self.writes += 1
        return StatusCodes.Good

    # -- the server's thread ---------------------------------------------------------------

    def _run(self, ready: asyncio.Future[tuple[str, int]], layout: dict[str, Any]) -> None:
        loop = self._loop
        assert loop is not None
        try:
            asyncio.run(self._serve(ready, layout))
        except BaseException as exc:  # to the gateway's loop, which raises it in start()
            error = GatewayError(f"OPC UA server: {exc}")

            def fail() -> None:
                if not ready.done():
                    ready.set_exception(error)
            loop.call_soon_threadsafe(fail)
        finally:
            done = self._done
            if done is not None and not loop.is_closed():
                loop.call_soon_threadsafe(lambda: None if done.done() else done.set_result(None))

    async def _serve(self, ready: asyncio.Future[tuple[str, int]],
                     layout: dict[str, Any]) -> None:
        assert self._loop is not None
        self._ua_loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        self._inbox = asyncio.Queue()
        config = self.config
        server = self._server = Server(user_manager=_Users(dict(config.users)))
        await server.init()
        server.set_endpoint(f"opc.tcp://{config.host}:{config.port}/")
        server.set_server_name(f"ncgate {layout['cell']} (virtual)")
        await server.set_application_uri(f"urn:ncgate:{layout['cell']}")
        server.set_security_policy(_SECURITY[config.security])
        if config.certificate is not None and config.private_key is not None:
            await server.load_certificate(str(config.certificate))
            await server.load_private_key(Path(config.private_key))
        server.iserver.create_session = self._session  # type: ignore[method-assign]
        await self._build(server, layout)
        await server.start()
        try:
            port = int(server.bserver.port or 0)  # type: ignore[union-attr]
            self._loop.call_soon_threadsafe(
                lambda: None if ready.done() else ready.set_result((config.host, port)))
            consumer = asyncio.create_task(self._consume())
            await self._stop.wait()
            consumer.cancel()
        finally:
            await server.stop()

    def _session(self, name: Any, user: User = User(role=UserRole.Anonymous),  # noqa: B008
                 external: bool = False) -> InternalSession:
        server = self._server
        assert server is not None
        iserver = server.iserver
        return _Session(self, iserver, iserver.aspace, iserver.subscription_service, name,
                        user=user, external=external)

    async def _consume(self) -> None:
        assert self._inbox is not None
        while True:
            batch = await self._inbox.get()
            for kind, item in batch:
                if kind == "process":
                    await self._show_process(item)
                elif kind == "image":
                    await self._show_image(*item)
                elif kind == "plc":
                    await self._show({"plc.State": item.state, "plc.Scans": item.scans,
                                      "plc.Fault": item.fault})
                elif kind == "event":
                    await self._raise(item)

    async def _show(self, values: dict[str, Any]) -> None:
        server = self._server
        assert server is not None
        for key, value in values.items():
            if self._values.get(key, _UNSET) == value:
                continue
            self._values[key] = value
            node = self._nodes.get(key)
            if node is None:
                continue
            shown = ua.DataValue(_variant(key, value))
            await server.write_attribute_value(node, shown)
            for alias in self._symbol_nodes.get(key, ()):
                await server.write_attribute_value(alias, shown)

    async def _show_process(self, v: ProcessView) -> None:
        k = f"P{v.number}."
        await self._show({
            k + "ChannelState": v.channel_state, k + "FeedOverride": float(v.feed_override),
            k + "RapidOverride": float(v.rapid_override), k + "State": v.state,
            k + "ActStatus": v.channel_state, k + "ActProgramStatus": v.program_status,
            k + "ActProgramName": v.program, k + "ActMainProgramName": v.program,
            k + "ActProgramBlock": list(v.blocks), k + "ActProgramLine": v.line,
            k + "ActFeedrate": v.feed, k + "ActOverride": float(v.feed_override),
            k + "X": v.position[0], k + "Y": v.position[1], k + "Z": v.position[2],
            k + "N": v.n})
        if v.number == 1:  # the cell's ActiveProgram is its first process's
            await self._show({"ActiveProgram.Name": v.program,
                              "ActiveProgram.State": v.state})

    async def _show_image(self, sa: bytes, k: bytes, syvar: tuple[int, ...]) -> None:
        values: dict[str, Any] = {}
        for i, byte in enumerate(sa):
            if self._values.get(f"SA.{i}") == byte:
                continue  # 8 bits unchanged: skipped whole
            self._values[f"SA.{i}"] = byte
            for bit in range(8):
                values[f"SA{8 * i + bit}"] = bool(byte >> bit & 1)
        values.update((f"SK{i}", byte) for i, byte in enumerate(k))
        values.update((f"SYVAR{i}", word) for i, word in enumerate(syvar))
        await self._show(values)

    async def _raise(self, e: EventView) -> None:
        generator = self._alerts if e.alarm else self._messages
        if generator is None:
            return
        event: Any = generator.event
        event.Message = ua.LocalizedText(e.message)
        event.Severity = e.severity
        event.SourceName = f"Process {e.process}" if e.process else "cell"
        if e.alarm:
            event.ErrorCode = e.code
        await generator.trigger(message=e.message)

    # -- the address space (the server's thread, before it serves) -------------------------

    async def _build(self, server: Server, layout: dict[str, Any]) -> None:
        di = await server.register_namespace(DI)
        machinery = await server.register_namespace(MACHINERY)
        mt = await server.register_namespace(MACHINE_TOOL)
        cnc = await server.register_namespace(CNC)
        own = await server.register_namespace(NCGATE)
        img = self.image_ns = await server.register_namespace(IMAGE)
        objects = server.nodes.objects
        base_object = server.get_node(ObjectIds.BaseObjectType)
        base_event = server.get_node(ObjectIds.BaseEventType)

        # The types a dashboard looks for.  The whole DI/Machinery/IA/MachineTool/CNC
        # nodesets are not loaded (docs/opcua.md says why): MachineToolType and AlertType
        # have the ids of OPC 40501-1's nodeset, the rest are ncgate's stand-ins.
        machine_tool_type = await base_object.add_object_type(
            _id(MACHINE_TOOL_TYPE_ID, mt), ua.QualifiedName("MachineToolType", mt))
        channel_type = await base_object.add_object_type(
            _id("ChannelMonitoringType", own),
            ua.QualifiedName("ChannelMonitoringType", mt))
        cnc_channel_type = await base_object.add_object_type(
            _id("CncChannelType", own), ua.QualifiedName("CncChannelType", cnc))
        alert_type = await base_event.add_object_type(
            _id(ALERT_TYPE_ID, mt), ua.QualifiedName("AlertType", mt))
        await alert_type.add_property(_id("AlertType.ErrorCode", own),
                                      ua.QualifiedName("ErrorCode", mt), "",
                                      varianttype=ua.VariantType.String)
        message_type = await base_event.add_object_type(
            _id("NotificationEventType", own),
            ua.QualifiedName("NotificationEventType", mt))

        cell = layout["cell"]
        machines = await objects.add_folder(_id("Machines", own),
                                            ua.QualifiedName("Machines", machinery))
        machine = await machines.add_object(_id(f"Machines/{cell}", own),
                                            ua.QualifiedName(cell, own),
                                            objecttype=machine_tool_type.nodeid)
        ident = await machine.add_object(_id("Identification", own),
                                         ua.QualifiedName("Identification", machinery))
        for name, value in (("Manufacturer", ua.LocalizedText("ncgate (virtual)")),
                            ("Model", ua.LocalizedText(cell)),
                            ("SoftwareRevision", __version__),
                            ("ProductInstanceUri", f"urn:ncgate:{cell}")):
            await ident.add_property(_id(f"Identification.{name}", own),
                                     ua.QualifiedName(name, di), value)
        monitoring = await machine.add_object(_id("Monitoring", own),
                                              ua.QualifiedName("Monitoring", mt))
        production = await machine.add_object(_id("Production", own),
                                              ua.QualifiedName("Production", mt))
        active = await production.add_object(_id("ActiveProgram", own),
                                              ua.QualifiedName("ActiveProgram", mt))
        await self._var(active, "ActiveProgram.Name", own, mt, "Name", "")
        await self._var(active, "ActiveProgram.State", own, mt, "State", "IDLE")
        notification = await machine.add_object(_id("Notification", own),
                                                ua.QualifiedName("Notification", mt))
        messages = await notification.add_object(_id("Messages", own),
                                                 ua.QualifiedName("Messages", mt))
        await messages.write_attribute(AttributeIds.EventNotifier, ua.DataValue(
            ua.Variant(1, ua.VariantType.Byte)))  # SubscribeToEvents
        self._alerts = await server.get_event_generator(alert_type, messages.nodeid)
        self._messages = await server.get_event_generator(message_type, messages.nodeid)

        cnc_interface = await objects.add_object(_id("CncInterface", own),
                                                 ua.QualifiedName("CncInterface", cnc))
        channels = await cnc_interface.add_object(_id("CncChannelList", own),
                                                  ua.QualifiedName("CncChannelList", cnc))
        vendor = await objects.add_folder(_id("Image", img),
                                          ua.QualifiedName("Image", img))
        vendor_processes = await vendor.add_folder(_id("Processes", img),
                                                   ua.QualifiedName("Processes", img))
        for number in layout["processes"]:
            k, name = f"P{number}.", f"Process {number}"
            mon = await monitoring.add_object(_id(f"Monitoring/{name}", own),
                                              ua.QualifiedName(name, own),
                                              objecttype=channel_type.nodeid)
            await self._var(mon, k + "ChannelState", own, mt, "ChannelState", 2)
            await self._var(mon, k + "ChannelMode", own, mt, "ChannelMode", 0)  # Automatic
            await self._var(mon, k + "FeedOverride", own, mt, "FeedOverride", 100.0)
            await self._var(mon, k + "RapidOverride", own, mt, "RapidOverride", 100.0)
            ch = await channels.add_object(_id(f"CncChannelList/{name}", own),
                                           ua.QualifiedName(name, own),
                                           objecttype=cnc_channel_type.nodeid)
            for var, initial in (("ActStatus", 2), ("ActProgramStatus", 0),
                                 ("ActProgramName", ""), ("ActMainProgramName", ""),
                                 ("ActProgramBlock", ["", "", ""]), ("ActProgramLine", 0),
                                 ("ActFeedrate", 0.0), ("ActOverride", 100.0)):
                await self._var(ch, k + var, own, cnc, var, initial)
            for axis in "XYZ":
                await self._var(ch, k + axis, own, cnc, axis, 0.0)
            p = await vendor_processes.add_object(_id(name, img),
                                                  ua.QualifiedName(name, img))
            await self._var(p, k + "State", img, img, "State", "IDLE", node_key=f"{name}.State")
            await self._var(p, k + "N", img, img, "N", -1, node_key=f"{name}.N")
        plc = await vendor.add_object(_id("PLC", img), ua.QualifiedName("PLC", img))
        await self._var(plc, "plc.State", img, img, "State", "NONE", node_key="PLC.State")
        await self._var(plc, "plc.Scans", img, img, "Scans", 0, node_key="PLC.Scans")
        await self._var(plc, "plc.Fault", img, img, "Fault", "", node_key="PLC.Fault")
        await self._build_image(vendor, img, layout)

    async def _var(self, parent: Node, key: str, ns: int, browse_ns: int, name: str,
                   initial: Any, node_key: str | None = None) -> Node:
        node_id = _id(node_key or key.replace(".", "/"), ns)
        node = await parent.add_variable(node_id, ua.QualifiedName(name, browse_ns),
                                         _variant(key, initial))
        self._nodes[key] = node.nodeid
        self._values[key] = initial
        return node

    async def _build_image(self, vendor: Node, img: int, layout: dict[str, Any]) -> None:
        writable = self.config.writable
        areas = (("SA", layout["sa_bits"], False), ("SK", layout["k_bytes"], 0),
                 ("SYVAR", layout["syvars"], 0))
        names = {var: name for name, var in layout["symbols"].items()}
        for area, size, initial in areas:
            folder = await vendor.add_folder(_id(area, img), ua.QualifiedName(area, img))
            for i in range(size):
                key = f"{area}{i}"
                node = await folder.add_variable(_id(key, img), ua.QualifiedName(key, img),
                                                 ua.Variant(initial, _VTYPE[area]))
                if _REGION[area] in writable:
                    await node.set_writable()
                if key in names:
                    await node.write_attribute(AttributeIds.Description, ua.DataValue(
                        ua.Variant(ua.LocalizedText(f"I/O name {names[key]}"))))
                self._nodes[key] = node.nodeid
                self._values[key] = initial
        # Each I/O name of [symbols] is a node of its own showing its variable's value.
        folder = await vendor.add_folder(_id("Symbols", img),
                                         ua.QualifiedName("Symbols", img))
        for name, var in layout["symbols"].items():
            parsed = Var.parse(var)
            if parsed.view != {"SA": "bit", "SK": "BY", "SYVAR": "IN"}[parsed.area]:
                continue  # a byte or word view of SA, a word of SK: shown by its variables
            node = await folder.add_variable(_id(name, img), ua.QualifiedName(name, img),
                                             ua.Variant(self._values.get(var, 0),
                                                        _VTYPE[parsed.area]))
            comment = layout["comments"].get(name)
            if comment:
                await node.write_attribute(AttributeIds.Description, ua.DataValue(
                    ua.Variant(ua.LocalizedText(comment))))
            if _REGION[parsed.area] in writable:
                await node.set_writable()
            self._symbol_nodes.setdefault(var, []).append(node.nodeid)


_UNSET = object()


def _id(identifier: int | str, ns: int) -> ua.NodeId:
    """A NodeId (asyncua types its fields with NewTypes that plain ints and strs are)."""
    return ua.NodeId(identifier, ns)  # type: ignore[arg-type]


def _variant(key: str, value: Any) -> ua.Variant:
    area = key.rstrip("0123456789")
    if area in _VTYPE and key[len(area):].isdigit():
        return ua.Variant(value, _VTYPE[area])
    if isinstance(value, bool):
        return ua.Variant(value, ua.VariantType.Boolean)
    if isinstance(value, int):
        return ua.Variant(value, ua.VariantType.Int32)
    if isinstance(value, float):
        return ua.Variant(value, ua.VariantType.Double)
    if isinstance(value, list):
        return ua.Variant(value, ua.VariantType.String)
    return ua.Variant(value, ua.VariantType.String)


class _Session(InternalSession):
    """A client's session: its writes of the image go through the gateway's door."""

    def __init__(self, owner: OpcuaServer, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.owner = owner

    def _who(self) -> str:
        user = self.user
        if user is not None and user.name:
            return f"user {user.name}"
        name = self.name
        if isinstance(name, tuple) and len(name) >= 2:
            return f"{name[0]}:{name[1]}"
        return str(name)

    async def write(self, params: ua.WriteParameters) -> list[ua.StatusCode]:
        owner = self.owner
        results: list[ua.StatusCode] = []
        for item in params.NodesToWrite:
            node = item.NodeId
            key = _image_key(owner, node)
            if key is None or item.AttributeId != AttributeIds.Value:
                one = ua.WriteParameters(NodesToWrite=[item])
                results.extend(await super().write(one))
                continue
            value = item.Value.Value.Value if item.Value.Value is not None else None
            loop = owner._loop
            assert loop is not None
            future: concurrent.futures.Future[int] = concurrent.futures.Future()

            def act(key: str = key, value: Any = value,
                    future: concurrent.futures.Future[int] = future) -> None:
                try:
                    future.set_result(owner._write_on_loop(key, value, self._who()))
                except BaseException as exc:
                    future.set_exception(exc)
            loop.call_soon_threadsafe(act)
            code = await asyncio.wrap_future(future)
            results.append(ua.StatusCode(code))  # type: ignore[arg-type]
        return results


def _image_key(owner: OpcuaServer, node: ua.NodeId) -> str | None:
    """The image variable or I/O name an image node shows (None: not an image node)."""
    if node.NamespaceIndex != owner.image_ns or not isinstance(node.Identifier, str):
        return None
    ident = node.Identifier
    area = ident.rstrip("0123456789")
    if area in _VTYPE and ident[len(area):].isdigit():
        return ident
    if ident in owner.gw.config.symbols:
        return ident
    return None
