"""The OPC UA server's process (``python -m ncgate.gateway.opcua.space``, started by
:class:`ncgate.gateway.opcua.server.OpcuaServer`): asyncua's server, the address space
(docs/opcua.md has the node set), the values the gateway's loop sends written into the nodes,
the events raised, and a client's write of an image node sent back to the gateway's loop.

A process of its own (docs/decisions.md, "OPC UA: a process of its own fed snapshots"):
asyncua's import and init, and its publishing, never take the gateway's interpreter.  It
talks to the gateway through its stdin and stdout in the frames of
:mod:`ncgate.gateway.opcua.wire`; its log goes to stderr.  It never touches the engine or the
image; it reads what the loop sends it, and ends when its stdin does.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import dataclasses
import hashlib
import hmac
import itertools
import logging
import os
import re
import signal
import sys
import uuid
from collections.abc import Awaitable, Callable, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from asyncua import ua
from asyncua.common.structures104 import new_enum
from asyncua.common.utils import ServiceError
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.uacrypto import load_certificate
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from asyncua.server.event_generator import EventGenerator
from asyncua.server.internal_session import InternalSession
from asyncua.server.server import Server
from asyncua.server.user_managers import UserManager
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes
from cryptography import x509
from cryptography.hazmat.primitives import serialization

from ncgate import __version__
from ncgate.config.schema import (
    UA_TRUSTED_SUFFIXES,
    OpcuaConfig,
    UaSecurity,
    x509_certificate,
)
from ncgate.errors import Reason
from ncgate.gateway.opcua.codes import REFUSAL
from ncgate.gateway.opcua.model import (
    CHANNEL_MODE,
    CHANNEL_STATE,
    CNC_CHANNEL_STATUS,
    CNC_PROGRAM_STATUS,
    SHOWN_VIEW,
    SND_LOG,
    Enumeration,
    EventView,
    ProcessView,
    StateView,
)
from ncgate.gateway.opcua.server import REGION
from ncgate.gateway.opcua.transport import CheckedServer
from ncgate.gateway.opcua.wire import frame, read_frame
from ncgate.gateway.ratelimit import LogFlood
from ncgate.gateway.tls import expiry_warning
from ncgate.inputs import Var

if TYPE_CHECKING:
    from asyncua.common.node import Node

log = logging.getLogger("ncgate.opcua")
# The budget of the lines asyncua logs for itself (main puts it on the process's handler).
FLOOD = LogFlood()
NICE = 10

# The companion specifications' namespaces (their URIs as the OPC Foundation publishes them).
DI = "http://opcfoundation.org/UA/DI/"
MACHINERY = "http://opcfoundation.org/UA/Machinery/"
MACHINE_TOOL = "http://opcfoundation.org/UA/MachineTool/"
CNC = "http://opcfoundation.org/UA/CNC"
IMAGE = "urn:ncgate:image"  # the image, the PLC, the processes as ncgate names them
NCGATE = "urn:ncgate:ua"  # ncgate's own nodes (the instances, the X/Y/Z positions)
# The numeric ids the published nodesets give the companion types ncgate declares (what a
# client may look a type up by).  tests/integration/opcua/test_nodesets.py checks each id,
# browse name, supertype and enumeration against the OPC Foundation's nodeset XML.
MACHINE_TOOL_TYPE_ID = 13  # OPC 40501-1 (MachineTool)
ELEMENT_MONITORING_TYPE_ID = 23  # abstract: ChannelMonitoringType's supertype
CHANNEL_MONITORING_TYPE_ID = 16
ALERT_TYPE_ID = 39  # a subtype of AlarmConditionType
ERROR_CODE_ID = 231  # AlertType's ErrorCode property
CHANNEL_STATE_ID = 64  # DataType: Active 0, Interrupted 1, Reset 2
CHANNEL_MODE_ID = 67  # DataType
CNC_COMPONENT_TYPE_ID = 1001  # OPC 40502 (CNC); abstract: CncChannelType's supertype
CNC_CHANNEL_TYPE_ID = 1002
CNC_MESSAGE_TYPE_ID = 1011  # an event type, a subtype of BaseEventType
CNC_PROGRAM_STATUS_ID = 3002  # DataType CncChannelProgramStatus
CNC_CHANNEL_STATUS_ID = 3003  # DataType CncChannelStatus (ActStatus): Active, Interrupted, Reset
# Each enumeration's EnumValues property (model.py has the names): (namespace, DataType's id,
# the property's id), as the published nodesets declare them.
_ENUMERATIONS = {CHANNEL_STATE: (MACHINE_TOOL, CHANNEL_STATE_ID, 266),
                 CHANNEL_MODE: (MACHINE_TOOL, CHANNEL_MODE_ID, 288),
                 CNC_PROGRAM_STATUS: (CNC, CNC_PROGRAM_STATUS_ID, 6225),
                 CNC_CHANNEL_STATUS: (CNC, CNC_CHANNEL_STATUS_ID, 6223)}

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
    """Anonymous sessions read; a user of ``[opcua.users]`` -- a name and its password, or a
    client presenting a user's certificate as its identity -- may write."""

    def __init__(self, users: Mapping[str, str | Path]) -> None:
        self.passwords = {name: v for name, v in users.items() if isinstance(v, str)}
        # A certificate user by its certificate's DER bytes (what the identity token carries).
        self.certificates: dict[bytes, str] = {}
        for name, path in users.items():
            if isinstance(path, Path):
                loaded = x509_certificate(path.read_bytes())
                self.certificates[loaded.public_bytes(serialization.Encoding.DER)] = name
        # Set while a session activates with an X.509 identity token: asyncua passes the
        # secure channel's client certificate for every token, an anonymous one too.
        self.x509 = False

    def get_user(self, iserver: Any, username: str | None = None,
                 password: str | None = None, certificate: Any = None) -> User | None:
        if self.x509:  # asyncua has checked the token's signature
            name = self.certificates.get(bytes(certificate))
            return None if name is None else User(role=UserRole.User, name=name)
        if username is None:  # asyncua's rules let its Anonymous role read nothing
            return User(role=UserRole.User)
        stored = self.passwords.get(username)
        if stored is None or password is None or not password_matches(stored, password):
            return None  # asyncua answers BadUserAccessDenied
        return User(role=UserRole.User, name=username)


class _Trusted(TrustStore):
    """asyncua's trust store over ``opcua.trusted``: its verification (the certificate itself
    or a CA that signed it, by cryptography's verifier), with files as well as folders.
    asyncua 2.1 reads only folders, and in them only names with ``der`` or ``pem``: a folder's
    ``*.crt`` would be left out without a word."""

    async def _load_trust_location(self, location: Path) -> list[x509.Certificate]:
        return [await load_certificate(content, "der" if content[:1] == b"0" else "pem")
                for content in _trusted_files(location)]  # DER starts with a SEQUENCE, 0x30


def _trusted_files(location: Path) -> list[bytes]:
    """The certificates' bytes (read once, at the start, before the server serves)."""
    files = ([location] if location.is_file() else
             sorted(f for f in location.iterdir() if f.suffix.lower() in UA_TRUSTED_SUFFIXES))
    return [f.read_bytes().lstrip() for f in files]


class _Validator(CertificateValidator):
    """The check of a client's application certificate at CreateSession: in its validity,
    its subject alternative name holding the client's application URI, and trusted.  A refusal
    is one log line (asyncua's trust store logs a traceback of its own)."""

    async def validate(self, cert: x509.Certificate,
                       app_description: ua.ApplicationDescription) -> None:
        try:
            await super().validate(cert, app_description)
        except ServiceError as refused:
            log.warning("a client certificate refused (%s): %s, application %s",
                        ua.StatusCode(refused.code).name,  # type: ignore[arg-type]
                        cert.subject.rfc4514_string(),
                        app_description.ApplicationUri)
            raise


async def trust_validator(trusted: tuple[Path, ...]) -> _Validator:
    store = _Trusted(list(trusted), [])
    await store.load()
    return _Validator(CertificateValidatorOptions.BASIC_VALIDATION
                      | CertificateValidatorOptions.TRUSTED, store)


class _Condition:
    """One AlertType condition (an ``AlarmConditionType``, OPC 10000-9 5.8): a process's
    alarms, or the cell's (process 0: the fieldbus side's, AL150).  Active while the process
    is in ALARM; the cell's stop nothing and are pending nowhere in ncgate, so theirs is
    active until a client acknowledges it.  Retained while active or unacknowledged: its
    latest event is what ConditionRefresh sends again (``Space._refresh``)."""

    def __init__(self, process: int, node: ua.NodeId, generator: EventGenerator,
                 climb: Callable[[Any], Awaitable[None]]) -> None:
        self.process = process
        self.node = node  # the ConditionId
        self.generator = generator  # its own: its event object is this condition's latest
        self.climb = climb  # the event to the notifiers above Messages (Space._climb)
        self.active = False
        self.acked = True

    async def report(self) -> None:
        event: Any = self.generator.event
        event.Retain = self.active or not self.acked
        setattr(event, "ActiveState/Id", self.active)
        event.ActiveState = ua.LocalizedText("Active" if self.active else "Inactive")
        setattr(event, "AckedState/Id", self.acked)
        event.AckedState = ua.LocalizedText("Acknowledged" if self.acked else "Unacknowledged")
        await self.generator.trigger(message=event.Message.Text if event.Message else None)
        await self.climb(event)

    @property
    def retained(self) -> bool:
        """What ConditionRefresh sends again: raised once, and active or unacknowledged."""
        return (getattr(self.generator.event.EventId, "Value", None) is not None
                and (self.active or not self.acked))

    async def raised(self, e: EventView) -> None:
        event: Any = self.generator.event
        event.Message = ua.LocalizedText(e.message)
        event.Severity = e.severity
        event.ErrorCode = e.code
        event.ConditionName = e.code
        self.active, self.acked = True, False
        await self.report()

    async def cleared(self) -> None:
        if self.active:
            self.active = False
            await self.report()

    async def acknowledge(self, event_id: bytes) -> int | None:
        """A client's Acknowledge: why not (a status code), or None."""
        latest = getattr(self.generator.event.EventId, "Value", None)  # None: never raised
        if latest is None or event_id != latest:
            return StatusCodes.BadEventIdUnknown  # not this condition's latest event
        if self.acked:
            return StatusCodes.BadConditionBranchAlreadyAcked
        self.acked = True
        if self.process == 0:
            self.active = False  # the cell's: pending nowhere but here
        await self.report()
        return None


class Link:
    """The gateway at the other end of the pipes: what this process sends it, and the
    answers to the writes it asked the gateway's loop to apply."""

    def __init__(self, config: OpcuaConfig, symbols: frozenset[str], out: Any) -> None:
        self.config = config
        self.symbols = symbols  # the I/O names of [symbols] (their nodes' ids)
        self._out = out
        self._numbers = itertools.count(1)
        self._pending: dict[int, asyncio.Future[Reason | str | None]] = {}

    def send(self, message: Any) -> None:
        # A blocking write: the gateway's loop reads its end at once, and frames are small.
        self._out.write(frame(message))

    async def write(self, key: str, value: Any, who: str) -> Reason | str | None:
        """A client's write, applied by the gateway's loop: why it was refused, None, or
        ``"error"`` when it failed otherwise."""
        number = next(self._numbers)
        answer: asyncio.Future[Reason | str | None] = (
            asyncio.get_running_loop().create_future())
        self._pending[number] = answer
        self.send(("write", number, key, value, who))
        return await answer

    def answered(self, number: int, refused: Reason | str | None) -> None:
        answer = self._pending.pop(number, None)
        if answer is not None and not answer.done():
            answer.set_result(refused)


def main() -> None:
    """The process: serve until the gateway sends stop or closes the pipe."""
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    # Its warnings of a None endpoint and of its revised values are asyncua's to itself.
    logging.getLogger("asyncua").setLevel(logging.ERROR)
    # And it logs an ERROR for every request it refuses: a client's flood of them is said in
    # a few lines with their count, not a line each.
    for handler in logging.getLogger().handlers:
        handler.addFilter(FLOOD)
    # stdout carries the frames only: anything printed goes to stderr.
    out = os.fdopen(os.dup(1), "wb", buffering=0)
    os.dup2(2, 1)
    # Ctrl-C in a terminal reaches the whole process group: the gateway stops this process
    # itself, by its stdin, after its own clean shutdown.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # Below the gateway: when the machine is busy, the cell's scan and pollers come first --
    # once it serves (below_the_gateway: Linux's SCHED_IDLE).  It starts at the gateway's
    # own priority: its start is the gateway's (the PLC scans once every adapter is up), and
    # at nice 10 on two cores a test suite kept full (load 7) it got 3 % of a core and did
    # not start within START_TIMEOUT_S.  Where there is no SCHED_IDLE, nice 10 from the start,
    # as the program checker's child (interpreter/child.py).
    if hasattr(os, "nice") and not _idle_scheduler():  # (POSIX)
        os.nice(NICE)
    asyncio.run(_serve(out))
    # Nothing of this process outlives it (it keeps nothing on disk): the interpreter's own
    # teardown of asyncua's address space took a second, past the gateway's wait, which
    # then killed it at every stop.
    logging.shutdown()
    sys.stderr.flush()
    os._exit(0)


def _idle_scheduler() -> bool:
    return hasattr(os, "sched_setscheduler") and hasattr(os, "SCHED_IDLE")


def below_the_gateway() -> None:
    """Once serving: Linux's SCHED_IDLE, every thread of the process (it runs on what the
    others leave, and one of theirs that wakes takes the core at once -- at nice 10 it held
    the core a while, and a poller's p99 under 10 dashboards doubled, as a bare server's
    did); elsewhere it stays at nice 10.  Not while it starts: asyncua's init is a second of
    CPU, and on a machine whose cores are full it took longer than a start may (at nice 10
    too: it starts at nice 0)."""
    if not _idle_scheduler():
        return
    for task in os.listdir("/proc/self/task") if os.path.isdir("/proc/self/task") else ["0"]:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(int(task), os.SCHED_IDLE, os.sched_param(0))


async def _serve(out: Any) -> None:
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin.buffer)
    try:
        _, config, layout = await read_frame(reader)
    except EOFError:
        return
    link = Link(config, frozenset(layout["symbols"]), out)
    space = Space(link)
    try:
        await space.serve(reader, layout)
    except Exception as exc:  # said to the gateway, whose start raises it
        link.send(("error", f"{type(exc).__name__}: {exc}"))
        raise


class Space:
    """asyncua's server and what its nodes show."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self._server: Server | None = None
        self._nodes: dict[str, ua.NodeId] = {}  # a value's key -> its node
        self._symbol_nodes: dict[str, list[ua.NodeId]] = {}  # a variable -> its I/O names'
        self._values: dict[str, Any] = {}  # what each node shows now
        self._last_image: tuple[bytes, bytes, tuple[int, ...]] = (b"", b"", ())  # shown
        self._conditions: dict[int, _Condition] = {}  # by process (0: the cell)
        self._messages: EventGenerator | None = None
        # The notifier hierarchy (HasNotifier): each notifier's parent, up to Server.
        self._above: dict[ua.NodeId, ua.NodeId] = {}
        self._refresh_events: tuple[Any, Any] | None = None  # RefreshStart, RefreshEnd
        self.image_ns = 0
        self._snds: list[str] = []  # the SND log, oldest first
        self.sessions: set[_Session] = set()  # the clients' activated sessions
        self.created: set[_Session] = set()  # every session not closed (opcua.max_sessions)
        # The image's nodes and the I/O names' (by key: SA10, door_closed): each one's
        # VariantType, and which of them opcua.writable lets a client write.
        self.image_types: dict[str, ua.VariantType] = {}
        self.writable: set[str] = set()
        self._clients = (0, 0)  # (sessions, subscriptions) as last told to the gateway

    async def serve(self, reader: asyncio.StreamReader, layout: dict[str, Any]) -> None:
        """Build, serve, and apply the gateway's frames until stop (or its pipe closes)."""
        config = self.link.config
        self.users = _Users(config.users)
        server = self._server = CheckedServer(user_manager=self.users)
        await server.init()  # (ConditionRefresh is ncgate's own: _build_conditions)
        server.set_endpoint(f"opc.tcp://{config.host}:{config.port}/")
        server.set_server_name(f"ncgate {layout['machine']} (virtual)")
        await server.set_application_uri(f"urn:ncgate:{layout['cell']}")
        server.set_security_policy(_SECURITY[config.security])
        if config.certificate is not None and config.private_key is not None:
            # The PEM files as Modbus/TLS and the console take them, with the same warning of
            # a certificate that has expired or is about to (gateway/tls.py).
            warning = expiry_warning(config.certificate)
            if warning is not None:
                log.warning("%s", warning)
            pem = config.certificate.read_bytes().lstrip().startswith(b"-----")
            await server.load_certificate(config.certificate.read_bytes(),
                                          "pem" if pem else "der")
            await server.load_private_key(config.private_key.read_bytes(), format="pem")
        if config.trusted:
            # Empty is any client certificate, which the config allows on loopback only
            # (docs/decisions.md, OPC UA, "Which client certificates are trusted").
            server.set_certificate_validator(await trust_validator(config.trusted))
            logging.getLogger("asyncuagds.validate").setLevel(logging.CRITICAL)
        server.iserver.create_session = self._session  # type: ignore[method-assign]
        # A client gone without closing its session (killed) holds it, and its subscriptions,
        # this long at most (asyncua's own cap is 10 minutes).
        server.iserver.max_session_timeout_ms = config.max_session_timeout_s * 1000
        await self._build(server, layout)
        # The limits where a client reads them (OPC 10000-5 6.3.2, ServerCapabilitiesType).
        for capability, limit in (
                (ObjectIds.Server_ServerCapabilities_MaxSessions, config.max_sessions),
                (ObjectIds.Server_ServerCapabilities_MaxSubscriptionsPerSession,
                 config.max_subscriptions_per_session),
                (ObjectIds.Server_ServerCapabilities_MaxMonitoredItemsPerSubscription,
                 config.max_monitored_items_per_subscription),
                (ObjectIds.Server_ServerCapabilities_MaxSubscriptions,
                 server.iserver.max_subscriptions)):
            await server.write_attribute_value(_id(capability, 0), ua.DataValue(
                ua.Variant(limit, ua.VariantType.UInt32)))
        starting = logging.getLogger("asyncua.server.server")
        level = starting.level
        starting.setLevel(logging.CRITICAL)  # (it logs a bind's failure with a traceback)
        try:
            await server.start()
        except OSError as exc:  # the port: said to the gateway, which names opcua.port
            self.link.send(("listen_error", exc.errno, exc.strerror or str(exc)))
            with contextlib.suppress(Exception):  # what init started, so that it ends
                await server.stop()
            return
        finally:
            starting.setLevel(level)
        try:
            below_the_gateway()  # (before ready: the gateway's start sees it done)
            self.link.send(("ready", int(server.bserver.port or 0)))  # type: ignore[union-attr]
            while True:
                try:
                    message = await read_frame(reader)
                except EOFError:
                    return
                kind = message[0]
                if kind == "batch":
                    await self._apply(message[1])
                elif kind == "result":
                    self.link.answered(message[1], message[2])
                elif kind == "stop":
                    return
        finally:
            FLOOD.flush(log)  # before asyncua's stop, which may outlast the process's time
            # asyncua's stop awaits its clock task, which sleeps a second between ticks: every
            # stop outlasted the gateway's wait and was killed.  The task is ended here.
            iserver = server.iserver
            ticking, iserver.time_task = iserver.time_task, None
            if ticking is not None:
                ticking.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await ticking
            await server.stop()

    def _session(self, name: Any, user: User = User(role=UserRole.Anonymous),  # noqa: B008
                 external: bool = False) -> InternalSession:
        server = self._server
        assert server is not None
        if external and len(self.created) >= self.link.config.max_sessions:
            # CreateSession past opcua.max_sessions: Bad_TooManySessions (OPC 10000-4 5.6.2;
            # asyncua's only cap is 1,000 activated sessions for its whole process).  Refused
            # before the session exists: asyncua registers a session as it makes it, and one
            # refused later (in its CreateSession) stayed registered, 0.5 kB each, and an
            # ActivateSession after it raised in asyncua (a hostile try).
            raise ServiceError(StatusCodes.BadTooManySessions)
        iserver = server.iserver
        return _Session(self, iserver, iserver.aspace, iserver.subscription_service, name,
                        user=user, external=external)

    def clients_changed(self) -> None:
        """Tell the gateway how many sessions and subscriptions its clients hold now (the
        console's fieldbus panel), when that changed."""
        server = self._server
        assert server is not None
        clients = (len(self.sessions),
                   len(server.iserver.subscription_service.subscriptions))
        if clients != self._clients:
            self._clients = clients
            self.link.send(("clients", *clients))

    async def _apply(self, batch: list[tuple[str, Any]]) -> None:
        """One loop turn's changes, in the order they happened."""
        for kind, item in batch:
            if kind == "state":
                await self._show_state(item)
            elif kind == "process":
                await self._show_process(item)
            elif kind == "image":
                await self._show_image(*item)
            elif kind == "plc":
                await self._show({"plc.State": item.state, "plc.Scans": item.scans,
                                  "plc.Fault": item.fault})
            elif kind == "event":
                await self._raise(item)
            elif kind == "snd":
                self._snds = [*self._snds, item][-SND_LOG:]
                await self._show({"SndLog": list(self._snds)})
            elif kind == "plant":
                await self._show({f"plant.{m.name}.{part}": value for m in item
                                  for part, value in (("State", m.state), ("Fault", m.fault))})

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
            shown = _shown(key, value)
            await server.write_attribute_value(node, shown)
            for alias in self._symbol_nodes.get(key, ()):
                await server.write_attribute_value(alias, shown)

    async def _show_state(self, v: StateView | ProcessView) -> None:
        k = f"P{v.number}."
        await self._show({
            k + "ChannelState": v.channel_state, k + "State": v.state,
            k + "ActStatus": v.channel_state, k + "ActProgramStatus": v.program_status,
            k + "ActProgramName": v.program, k + "ActMainProgramName": v.program})
        condition = self._conditions.get(v.number)
        if condition is not None and v.state != "ALARM":  # a reset: the alarm is gone
            await condition.cleared()
        if v.number == 1:  # the cell's ActiveProgram is its first process's
            await self._show({"ActiveProgram.Name": v.program,
                              "ActiveProgram.State": v.state})

    async def _show_process(self, v: ProcessView) -> None:
        await self._show_state(v)
        k = f"P{v.number}."
        await self._show({
            k + "FeedOverride": float(v.feed_override),
            k + "RapidOverride": float(v.rapid_override),
            k + "ActProgramBlock": list(v.blocks), k + "ActProgramLine": str(v.line),
            k + "ActFeedrate": v.feed, k + "ActOverride": float(v.feed_override),
            k + "X": v.position[0], k + "Y": v.position[1], k + "Z": v.position[2],
            k + "N": v.n})

    async def _show_image(self, sa: bytes, k: bytes, syvar: tuple[int, ...]) -> None:
        # Only what differs from the last image is looked at: a scan changes a few of its
        # bytes and words, and an image comes every loop turn that wrote one.  (An SA byte
        # unchanged is 8 bits skipped whole.)
        last_sa, last_k, last_syvar = self._last_image
        self._last_image = (sa, k, syvar)
        values: dict[str, Any] = {}
        for i, (byte, was) in enumerate(itertools.zip_longest(sa, last_sa)):
            if byte != was:
                for bit in range(8):
                    values[f"SA{8 * i + bit}"] = bool(byte >> bit & 1)
        values.update((f"SK{i}", byte) for i, (byte, was) in
                      enumerate(itertools.zip_longest(k, last_k)) if byte != was)
        values.update((f"SYVAR{i}", word) for i, (word, was) in
                      enumerate(itertools.zip_longest(syvar, last_syvar)) if word != was)
        await self._show(values)

    async def _raise(self, e: EventView) -> None:
        if e.alarm:
            condition = self._conditions.get(e.process)
            if condition is not None:
                await condition.raised(e)
            return
        generator = self._messages
        if generator is None:
            return
        event: Any = generator.event
        event.Message = ua.LocalizedText(e.message)
        event.Severity = e.severity
        event.SourceName = f"Process {e.process}" if e.process else "cell"
        await generator.trigger(message=e.message)
        await self._climb(event)

    # -- events up the notifier hierarchy ---------------------------------------------------
    #
    # asyncua 2.1 delivers an event only to the monitored items at its emitting node
    # (FreeOpcUa/opcua-asyncio#105), and its ConditionRefresh only to those and the Server's
    # brackets.  OPC 10000-3 7.17 has a notifier report the events of the notifiers below it
    # (HasNotifier), the Server object at the top: a SCADA alarm list subscribes there.

    def _chain(self, notifier: ua.NodeId) -> list[ua.NodeId]:
        """``notifier`` and each notifier above it, up to the Server object."""
        chain = [notifier]
        while chain[-1] in self._above:
            chain.append(self._above[chain[-1]])
        return chain

    async def _climb(self, event: Any) -> None:
        """An event asyncua has just delivered at its emitting node, to the monitored items of
        every notifier above it: the same event (its EventId), not another."""
        server = self._server
        assert server is not None
        subscriptions = server.iserver.subscription_service.subscriptions
        for notifier in self._chain(event.emitting_node)[1:]:
            seen = _at(event, notifier)
            for subscription in list(subscriptions.values()):
                await subscription.monitored_item_srv.trigger_event(seen)

    async def _refresh(self, parent: ua.NodeId, *args: Any) -> Any:
        """ConditionType's ConditionRefresh (OPC 10000-9 5.5.7): SubscriptionId."""
        refused = _arguments(args, (ua.VariantType.UInt32,))
        return refused if refused is not None else await self._refreshed(args[0])

    async def _refresh2(self, parent: ua.NodeId, *args: Any) -> Any:
        """ConditionType's ConditionRefresh2 (OPC 10000-9 5.5.8): SubscriptionId,
        MonitoredItemId."""
        refused = _arguments(args, (ua.VariantType.UInt32, ua.VariantType.UInt32))
        return refused if refused is not None else await self._refreshed(*args)

    async def _refreshed(self, subscription_id: ua.Variant,
                         monitored_item: ua.Variant | None = None) -> ua.StatusCode | list[Any]:
        """ConditionRefresh and ConditionRefresh2: a RefreshStart event to every event item
        of the subscription (or to the one item), each retained condition to the items whose
        notifier it reaches, and a RefreshEnd."""
        server = self._server
        assert server is not None and self._refresh_events is not None
        subscription = server.iserver.subscription_service.subscriptions.get(
            subscription_id.Value)
        if subscription is None:
            return ua.StatusCode(StatusCodes.BadSubscriptionIdInvalid)  # type: ignore[arg-type]
        items = subscription.monitored_item_srv
        # (The event items by notifier: asyncua 2.1 keeps them in _monitored_events only.)
        watched = [(mid, notifier) for notifier, mids in items._monitored_events.items()
                   for mid in mids]
        if monitored_item is not None:
            watched = [w for w in watched if w[0] == monitored_item.Value]
            if not watched:
                invalid = StatusCodes.BadMonitoredItemIdInvalid
                return ua.StatusCode(invalid)  # type: ignore[arg-type]
        if not watched:
            return ua.StatusCode(StatusCodes.BadNothingToDo)  # type: ignore[arg-type]
        start, end = (_stamped(e) for e in self._refresh_events)
        for mid, notifier in watched:
            await items.trigger_event(_at(start, notifier), mid)
        for condition in self._conditions.values():
            if not condition.retained:
                continue
            event = condition.generator.event
            reached = self._chain(event.emitting_node)
            for mid, notifier in watched:
                if notifier in reached:
                    await items.trigger_event(_at(event, notifier), mid)
        for mid, notifier in watched:
            await items.trigger_event(_at(end, notifier), mid)
        return []

    async def _acknowledge(self, parent: ua.NodeId, *args: Any) -> Any:
        """AcknowledgeableConditionType's Acknowledge, called on a condition (OPC 10000-9
        5.7.3): EventId, Comment.  It changes the condition's AckedState only; the alarm stays
        in ncgate until a reset, as on the console."""
        refused = _arguments(args, (ua.VariantType.ByteString, ua.VariantType.LocalizedText))
        if refused is not None:
            return refused
        event_id = args[0]
        condition = next((c for c in self._conditions.values() if c.node == parent), None)
        if condition is None:
            return ua.StatusCode(StatusCodes.BadNodeIdUnknown)  # type: ignore[arg-type]
        why = await condition.acknowledge(bytes(event_id.Value or b""))
        if why is not None:
            return ua.StatusCode(why)  # type: ignore[arg-type]
        return []

    # -- the address space (before it serves) ----------------------------------------------

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
        alarm_condition = server.get_node(ObjectIds.AlarmConditionType)

        # The types a dashboard looks for, with the NodeIds, browse names and supertypes of
        # the published nodesets.  The whole DI/Machinery/IA/MachineTool/CNC nodesets are not
        # loaded (docs/opcua.md says why): only these types, without the declarations ncgate
        # does not fill.
        machine_tool_type = await base_object.add_object_type(
            _id(MACHINE_TOOL_TYPE_ID, mt), ua.QualifiedName("MachineToolType", mt))
        element_monitoring = await base_object.add_object_type(
            _id(ELEMENT_MONITORING_TYPE_ID, mt), ua.QualifiedName("ElementMonitoringType", mt))
        channel_type = await element_monitoring.add_object_type(
            _id(CHANNEL_MONITORING_TYPE_ID, mt), ua.QualifiedName("ChannelMonitoringType", mt))
        cnc_component = await base_object.add_object_type(
            _id(CNC_COMPONENT_TYPE_ID, cnc), ua.QualifiedName("CncComponentType", cnc))
        cnc_channel_type = await cnc_component.add_object_type(
            _id(CNC_CHANNEL_TYPE_ID, cnc), ua.QualifiedName("CncChannelType", cnc))
        for abstract in (element_monitoring, cnc_component):
            await abstract.write_attribute(AttributeIds.IsAbstract, ua.DataValue(
                ua.Variant(True, ua.VariantType.Boolean)))
        # AlertType is an AlarmConditionType in OPC 40501-1: a condition per process
        # (_build_conditions, docs/decisions.md).
        alert_type = await alarm_condition.add_object_type(
            _id(ALERT_TYPE_ID, mt), ua.QualifiedName("AlertType", mt))
        await alert_type.add_property(_id(ERROR_CODE_ID, mt),
                                      ua.QualifiedName("ErrorCode", mt), "",
                                      varianttype=ua.VariantType.String)
        # A part program's message (DIS) is OPC 40502's CncMessageType: MachineTool's
        # NotificationEventType is abstract, and no event may be of an abstract type.
        message_type = await base_event.add_object_type(
            _id(CNC_MESSAGE_TYPE_ID, cnc), ua.QualifiedName("CncMessageType", cnc))

        cell = layout["machine"]  # (not the application URI's: model.machine_name)
        machines = await objects.add_folder(_id("Machines", own),
                                            ua.QualifiedName("Machines", machinery))
        machine = await machines.add_object(_id(f"Machines/{cell}", own),
                                            ua.QualifiedName(cell, own),
                                            objecttype=machine_tool_type.nodeid)
        # MachineToolType's Identification is DI's browse name (OPC 40501-1's nodeset).
        ident = await machine.add_object(_id("Identification", own),
                                         ua.QualifiedName("Identification", di))
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
        # The notifier hierarchy, browsable (OPC 10000-3 7.17): Server -> the cell ->
        # Notification -> Messages; Messages's events reach each notifier above it (_climb).
        for above, below in ((server.nodes.server, machine), (machine, notification),
                             (notification, messages)):
            await above.add_reference(below.nodeid, ObjectIds.HasNotifier)
            await below.set_event_notifier([ua.EventNotifier.SubscribeToEvents])
            self._above[below.nodeid] = above.nodeid
        self._messages = await server.get_event_generator(message_type, messages.nodeid)
        await self._build_conditions(server, layout, alert_type, messages, own)

        cnc_interface = await objects.add_object(_id("CncInterface", own),
                                                 ua.QualifiedName("CncInterface", cnc))
        channels = await cnc_interface.add_object(_id("CncChannelList", own),
                                                  ua.QualifiedName("CncChannelList", cnc))
        vendor = await objects.add_folder(_id("Image", img),
                                          ua.QualifiedName("Image", img))
        vendor_processes = await vendor.add_folder(_id("Processes", img),
                                                   ua.QualifiedName("Processes", img))
        # The enumerations with the published ids and values (model.py maps the states).
        channel_state_t = await _enumeration(server, CHANNEL_STATE)
        channel_mode_t = await _enumeration(server, CHANNEL_MODE)
        program_status_t = await _enumeration(server, CNC_PROGRAM_STATUS)
        channel_status_t = await _enumeration(server, CNC_CHANNEL_STATUS)
        for number in layout["processes"]:
            k, name = f"P{number}.", f"Process {number}"
            mon = await monitoring.add_object(_id(f"Monitoring/{name}", own),
                                              ua.QualifiedName(name, own),
                                              objecttype=channel_type.nodeid)
            await self._var(mon, k + "ChannelState", own, mt, "ChannelState", 2,
                            datatype=channel_state_t)
            await self._var(mon, k + "ChannelMode", own, mt, "ChannelMode", 0,  # Automatic
                            datatype=channel_mode_t)
            await self._var(mon, k + "FeedOverride", own, mt, "FeedOverride", 100.0)
            await self._var(mon, k + "RapidOverride", own, mt, "RapidOverride", 100.0)
            ch = await channels.add_object(_id(f"CncChannelList/{name}", own),
                                           ua.QualifiedName(name, own),
                                           objecttype=cnc_channel_type.nodeid)
            await self._var(ch, k + "ActStatus", own, cnc, "ActStatus", 2,
                            datatype=channel_status_t)
            await self._var(ch, k + "ActProgramStatus", own, cnc, "ActProgramStatus", 0,
                            datatype=program_status_t)
            for var, initial in (("ActProgramName", ""), ("ActMainProgramName", ""),
                                 ("ActProgramBlock", ["", "", ""]), ("ActProgramLine", "0"),
                                 ("ActFeedrate", 0.0), ("ActOverride", 100.0)):
                await self._var(ch, k + var, own, cnc, var, initial)
            for axis in "XYZ":  # ncgate's names: 40502's PosTcpBcsX is a structure
                await self._var(ch, k + axis, own, own, axis, 0.0)
            p = await vendor_processes.add_object(_id(name, img),
                                                  ua.QualifiedName(name, img))
            await self._var(p, k + "State", img, img, "State", "IDLE", node_key=f"{name}.State")
            await self._var(p, k + "N", img, img, "N", -1, node_key=f"{name}.N")
        plc = await vendor.add_object(_id("PLC", img), ua.QualifiedName("PLC", img))
        await self._var(plc, "plc.State", img, img, "State", "NONE", node_key="PLC.State")
        await self._var(plc, "plc.Scans", img, img, "Scans", 0, node_key="PLC.Scans")
        await self._var(plc, "plc.Fault", img, img, "Fault", "", node_key="PLC.Fault")
        await self._var(vendor, "SndLog", img, img, "SndLog", [], node_key="SndLog")
        plant = await vendor.add_folder(_id("Plant", img), ua.QualifiedName("Plant", img))
        for name in layout["plant"]:
            model = await plant.add_object(_id(f"Plant/{name}", img), ua.QualifiedName(name, img))
            await self._var(model, f"plant.{name}.State", img, img, "State", "",
                            node_key=f"Plant/{name}.State")
            await self._var(model, f"plant.{name}.Fault", img, img, "Fault", "",
                            node_key=f"Plant/{name}.Fault")
        await self._build_image(vendor, img, layout)

    async def _build_conditions(self, server: Server, layout: dict[str, Any], alert_type: Node,
                                messages: Node, own: int) -> None:
        """An AlertType condition per process and one for the cell, under ``Messages``, and
        Acknowledge, ConditionRefresh and ConditionRefresh2 bound."""
        await messages.add_reference(alert_type.nodeid, ObjectIds.GeneratesEvent)
        for number in (0, *layout["processes"]):
            name = f"Process {number}" if number else "cell"
            node = await messages.add_object(_id(f"Alarms/{name}", own),
                                             ua.QualifiedName(f"Alarm {name}", own))
            generator = EventGenerator(server.iserver.isession)
            await generator.init(alert_type.nodeid, messages.nodeid, add_generates_event=False)
            event: Any = generator.event
            event.NodeId = node.nodeid  # the ConditionId
            event.SourceName = name
            event.ConditionName = ""
            setattr(event, "EnabledState/Id", True)
            event.EnabledState = ua.LocalizedText("Enabled")
            event.ErrorCode = ""
            self._conditions[number] = _Condition(number, node.nodeid, generator, self._climb)
        isession = server.iserver.isession
        isession.add_method_callback(
            _id(ObjectIds.AcknowledgeableConditionType_Acknowledge, 0), self._acknowledge)
        brackets = []
        for etype in (ObjectIds.RefreshStartEventType, ObjectIds.RefreshEndEventType):
            generator = EventGenerator(isession)  # its event only: _refresh sends it
            await generator.init(etype, add_generates_event=False)  # from the Server object
            brackets.append(generator.event)
        self._refresh_events = (brackets[0], brackets[1])
        isession.add_method_callback(_id(ObjectIds.ConditionType_ConditionRefresh, 0),
                                     self._refresh)
        isession.add_method_callback(_id(ObjectIds.ConditionType_ConditionRefresh2, 0),
                                     self._refresh2)

    async def _var(self, parent: Node, key: str, ns: int, browse_ns: int, name: str,
                   initial: Any, node_key: str | None = None,
                   datatype: ua.NodeId | None = None) -> Node:
        node_id = _id(node_key or key.replace(".", "/"), ns)
        node = await parent.add_variable(node_id, ua.QualifiedName(name, browse_ns),
                                         _variant(key, initial), datatype=datatype)
        if isinstance(initial, list):  # ActProgramBlock's 3 blocks; the SND log, any length
            await _one_dimension(node, len(initial))
        self._nodes[key] = node.nodeid
        self._values[key] = initial
        return node

    async def _build_image(self, vendor: Node, img: int, layout: dict[str, Any]) -> None:
        writable = self.link.config.writable
        areas = (("SA", layout["sa_bits"], False), ("SK", layout["k_bytes"], 0),
                 ("SYVAR", layout["syvars"], 0))
        names = {var: name for name, var in layout["symbols"].items()}
        for area, size, initial in areas:
            folder = await vendor.add_folder(_id(area, img), ua.QualifiedName(area, img))
            for i in range(size):
                key = f"{area}{i}"
                node = await folder.add_variable(_id(key, img), ua.QualifiedName(key, img),
                                                 ua.Variant(initial, _VTYPE[area]))
                self.image_types[key] = _VTYPE[area]
                if REGION[area] in writable:
                    await node.set_writable()
                    self.writable.add(key)
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
            if parsed.view != SHOWN_VIEW[parsed.area]:
                continue  # a byte or word view of SA, a word of SK: shown by its variables
            node = await folder.add_variable(_id(name, img), ua.QualifiedName(name, img),
                                             ua.Variant(self._values.get(var, 0),
                                                        _VTYPE[parsed.area]))
            comment = layout["comments"].get(name)
            if comment:
                await node.write_attribute(AttributeIds.Description, ua.DataValue(
                    ua.Variant(ua.LocalizedText(comment))))
            self.image_types[name] = _VTYPE[parsed.area]
            if REGION[parsed.area] in writable:
                await node.set_writable()
                self.writable.add(name)
            self._symbol_nodes.setdefault(var, []).append(node.nodeid)


_UNSET = object()


def _arguments(args: tuple[Any, ...],
               types: tuple[ua.VariantType, ...]) -> ua.CallMethodResult | None:
    """A method call's input arguments against the method's (OPC 10000-4 5.12.2, Call): too
    few is Bad_ArgumentsMissing, too many Bad_TooManyArguments, and an argument not a scalar
    of its DataType Bad_InvalidArgument, with Bad_TypeMismatch in its inputArgumentResults.
    None when they fit.  Checked here, before the method runs: asyncua answers a method that
    raises with Bad_UnexpectedError and an ERROR traceback in the log, which a client could
    fill by calling with a wrong argument (docs/opcua.md has the checks)."""
    result = ua.CallMethodResult()
    if len(args) != len(types):
        result.StatusCode = ua.StatusCode(
            StatusCodes.BadArgumentsMissing if len(args) < len(types)  # type: ignore[arg-type]
            else StatusCodes.BadTooManyArguments)
        return result
    checks = [ua.StatusCode() if _scalar_of(arg, vtype)
              else ua.StatusCode(StatusCodes.BadTypeMismatch)  # type: ignore[arg-type]
              for arg, vtype in zip(args, types, strict=True)]
    if all(check.is_good() for check in checks):
        return None
    result.StatusCode = ua.StatusCode(StatusCodes.BadInvalidArgument)  # type: ignore[arg-type]
    result.InputArgumentResults = checks
    return result


def _scalar_of(variant: object, vtype: ua.VariantType) -> bool:
    """``variant`` is one value of exactly ``vtype``: no widening, no array (what a method's
    argument and a write of an image node must be, OPC 10000-4 5.12.2 and 5.11.4)."""
    return (isinstance(variant, ua.Variant) and variant.VariantType == vtype
            and not variant.is_array and not isinstance(variant.Value, list))


async def _enumeration(server: Server, enumeration: Enumeration) -> ua.NodeId:
    """An enumeration DataType as its nodeset declares it: the DataTypeDefinition (what an
    OPC UA 1.04 client reads) and the EnumValues property (what older clients read, and the
    published nodesets carry), with the published NodeIds."""
    uri, type_id, values_id = _ENUMERATIONS[enumeration]
    ns = await server.get_namespace_index(uri)
    datatype = await new_enum(server, _id(type_id, ns), ua.QualifiedName(enumeration.name, ns),
                              list(enumeration.names))
    values = [ua.EnumValueType(Value=i, DisplayName=ua.LocalizedText(name))
              for i, name in enumerate(enumeration.names)]
    prop = await datatype.add_property(_id(values_id, ns), ua.QualifiedName("EnumValues", 0),
                                       values, varianttype=ua.VariantType.ExtensionObject,
                                       datatype=_id(ObjectIds.EnumValueType, 0))
    await _one_dimension(prop, len(values))
    return datatype.nodeid


async def _one_dimension(node: Node, length: int) -> None:
    """An array variable's ValueRank 1 and ArrayDimensions (0: any length), as the nodesets
    declare theirs (asyncua gives a list's variable ValueRank 0, one or more dimensions)."""
    await node.write_attribute(AttributeIds.ValueRank, ua.DataValue(ua.Variant(
        ua.ValueRank.OneDimension, ua.VariantType.Int32)))
    await node.write_attribute(AttributeIds.ArrayDimensions, ua.DataValue(ua.Variant(
        [length], ua.VariantType.UInt32)))


def _at(event: Any, notifier: ua.NodeId) -> Any:
    """``event`` as the notifier ``notifier`` reports it: the same fields (its EventId), for
    the monitored items there (asyncua routes an event by its ``emitting_node``)."""
    if event.emitting_node == notifier:
        return event
    seen = copy.copy(event)
    seen.emitting_node = notifier
    return seen


def _stamped(event: Any) -> Any:
    """A new occurrence of ``event`` (a refresh bracket): a new EventId and time, as
    asyncua's ``EventGenerator.trigger`` gives one."""
    now = datetime.now(UTC)
    stamped = copy.copy(event)
    stamped.EventId = ua.Variant(uuid.uuid4().hex.encode(), ua.VariantType.ByteString)
    stamped.Time = stamped.ReceiveTime = now
    return stamped



def _id(identifier: int | str, ns: int) -> ua.NodeId:
    """A NodeId (asyncua types its fields with NewTypes that plain ints and strs are)."""
    return ua.NodeId(identifier, ns)  # type: ignore[arg-type]


class _Shown(ua.DataValue):
    """A value the gateway shows, never changed once written (a new one each time, its
    list a new list): a monitored item may keep it as it is.  asyncua deep-copies every
    value each monitored item keeps (``MonitoredItemValues.set_current_datavalue``, so that a
    value a server changes in place still reads as a change): beside bench/storm.py's 10
    sessions of 2,000 items that copy was 40 % of this process's time."""

    def __deepcopy__(self, memo: dict[int, Any]) -> _Shown:
        return self


# The values shown, by their variant type and value: made once (a Variant's and a DataValue's
# checks are a fifth of this process's time beside a 1 kHz SND/WAI loop's state changes).
_SHOWN: dict[tuple[Any, type, Any], _Shown] = {}
SHOWN_KEPT = 4096


def _shown(key: str, value: Any) -> _Shown:
    if isinstance(value, list):  # (the SND log: a new list each time, never kept)
        return _Shown(_variant(key, value))
    index = (_image_type(key), type(value), value)  # (True == 1: the type tells them apart)
    found = _SHOWN.get(index)
    if found is None:
        if len(_SHOWN) >= SHOWN_KEPT:
            _SHOWN.clear()
        found = _SHOWN[index] = _Shown(_variant(key, value))
    return found


def _image_type(key: str) -> ua.VariantType | None:
    """The variant type of an image variable's node (SA10, SK3, SYVAR7); None for others."""
    area = key.rstrip("0123456789")
    return _VTYPE[area] if area in _VTYPE and key[len(area):].isdigit() else None


def _variant(key: str, value: Any) -> ua.Variant:
    vtype = _image_type(key)
    if vtype is not None:
        return ua.Variant(value, vtype)
    if isinstance(value, bool):
        return ua.Variant(value, ua.VariantType.Boolean)
    if isinstance(value, int):
        return ua.Variant(value, ua.VariantType.Int32)
    if isinstance(value, float):
        return ua.Variant(value, ua.VariantType.Double)
    if isinstance(value, list):
        return ua.Variant(value, ua.VariantType.String)
    return ua.Variant(value, ua.VariantType.String)


# The AccessLevel bits that let a client write (OPC 10000-3 8.57, AccessLevelType):
# CurrentWrite, HistoryWrite, StatusWrite, TimestampWrite.
_WRITE_BITS = sum(1 << bit for bit in (ua.AccessLevel.CurrentWrite, ua.AccessLevel.HistoryWrite,
                                       ua.AccessLevel.StatusWrite, ua.AccessLevel.TimestampWrite))


# ConditionType's two refresh methods: each takes a subscription of the calling session.
_REFRESHES = frozenset(_id(i, 0) for i in (ObjectIds.ConditionType_ConditionRefresh,
                                           ObjectIds.ConditionType_ConditionRefresh2))


class _Session(InternalSession):
    """A client's session: its writes of the image go through the gateway's door."""

    def __init__(self, owner: Space, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.owner = owner
        self._activation: asyncio.Task[None] | None = None  # (_unless_activated)

    def activate_session(self, params: ua.ActivateSessionParameters,
                         peer_certificate: bytes | None) -> ua.ActivateSessionResult:
        users = self.owner.users
        users.x509 = isinstance(params.UserIdentityToken, ua.X509IdentityToken)
        try:  # (synchronous: no other session activates meanwhile)
            result = super().activate_session(params, peer_certificate)
        finally:
            users.x509 = False
        self.owner.sessions.add(self)
        self.owner.clients_changed()
        return result

    async def create_session(self, params: ua.CreateSessionParameters,
                             sockname: tuple[str, int] | None = None,
                             ) -> ua.CreateSessionResult:
        """CreateSession, counted for opcua.max_sessions (refused before this session was
        made: :meth:`Space._session`), and closed unless activated in time."""
        result = await super().create_session(params, sockname)
        self.owner.created.add(self)
        self._activation = asyncio.create_task(self._unless_activated())
        return result

    async def _unless_activated(self) -> None:
        """Close this session if it is not activated within its timeout (OPC 10000-4 5.6.2).
        asyncua closes one only when its connection goes: a client sending CreateSession
        again and again on one connection, activating none, held max_sessions for good
        (asyncua forgets all but the connection's last)."""
        await asyncio.sleep(self.session_timeout or self.owner.link.config.max_session_timeout_s)
        if not self.is_activated() and self in self.owner.created:
            await self.close_session(True)

    async def close_session(self, delete_subs: bool = True) -> None:
        if self._activation is not None and self._activation is not asyncio.current_task():
            self._activation.cancel()
        try:
            # Its subscriptions go with it, whatever DeleteSubscriptions says: kept, they
            # belonged to no session, no limit counted them, and a client closing sessions
            # with false filled the server's 1,000 for good (a hostile try).  None is kept
            # for a TransferSubscriptions, which only the same user's session may make.
            await super().close_session(True)
        finally:
            self.owner.created.discard(self)
            self.owner.sessions.discard(self)
            self.owner.clients_changed()

    async def call(self, params: list[ua.CallMethodRequest]) -> list[ua.CallMethodResult]:
        """Call: a ConditionRefresh or ConditionRefresh2 for a subscription of another session
        is Bad_SubscriptionIdInvalid, as for one that does not exist (OPC 10000-9 5.5.7: a
        subscription of the calling session).  asyncua does not tell a method who calls it,
        so it is answered here: before, any client had another's alarms sent again."""
        subscriptions = self.subscription_service.subscriptions
        refused: dict[int, ua.CallMethodResult] = {}
        for i, request in enumerate(params):
            first = request.InputArguments[0] if request.InputArguments else None
            if request.MethodId in _REFRESHES and first is not None and (
                    first.VariantType == ua.VariantType.UInt32):
                sub = subscriptions.get(first.Value)
                if sub is not None and sub.session_id != self.session_id:
                    refused[i] = ua.CallMethodResult(StatusCode=ua.StatusCode(
                        StatusCodes.BadSubscriptionIdInvalid))  # type: ignore[arg-type]
        if not refused:
            return await super().call(params)
        rest = [request for i, request in enumerate(params) if i not in refused]
        answered = iter(await super().call(rest) if rest else [])
        return [refused[i] if i in refused else next(answered) for i in range(len(params))]

    async def create_subscription(self, params: ua.CreateSubscriptionParameters,
                                  callback: Any, request_callback: Any = None,
                                  ) -> ua.CreateSubscriptionResult:
        """CreateSubscription: Bad_TooManySubscriptions past this session's
        opcua.max_subscriptions_per_session (asyncua counts only the whole server's, 1,000, which
        one client could take alone and, killed, keep until its session timed out)."""
        if self._room() <= 0:
            raise ServiceError(StatusCodes.BadTooManySubscriptions)
        result = await super().create_subscription(params, callback, request_callback)
        self.owner.clients_changed()
        return result

    def _room(self) -> int:
        """The subscriptions this session may still take (opcua.max_subscriptions_per_session
        less those it holds: asyncua counts only the whole server's)."""
        held = sum(1 for sub in self.subscription_service.subscriptions.values()
                   if sub.session_id == self.session_id)
        return self.owner.link.config.max_subscriptions_per_session - held

    async def transfer_subscriptions(  # type: ignore[override]
            self, params: ua.TransferSubscriptionsParameters, callback: Any,
    ) -> list[ua.TransferResult]:
        """TransferSubscriptions (OPC 10000-4 5.13.7) of a subscription of another session of
        the same user (a name or a certificate; an anonymous session takes none: any other
        client could take its subscriptions), within this session's
        opcua.max_subscriptions_per_session.  asyncua checked neither: one session gathered
        64 subscriptions, and any session took another client's (a hostile try)."""
        subscriptions = self.subscription_service.subscriptions
        room = self._room()
        sessions = {session.session_id: session for session in self.owner.created}
        taken: list[int] = []
        results: list[ua.TransferResult | None] = []
        for sid in params.SubscriptionIds:
            sub = subscriptions.get(sid)
            owner = sessions.get(sub.session_id) if sub is not None else None
            if sub is None or sub.session_id == self.session_id:
                results.append(None)  # asyncua's answer (unknown; already this session's)
                taken.append(sid)
            elif not self._named() or owner is None or owner.user is None or (
                    owner.user.name != self.user.name):
                results.append(ua.TransferResult(StatusCode=ua.StatusCode(
                    StatusCodes.BadUserAccessDenied)))  # type: ignore[arg-type]
            elif room <= 0:
                results.append(ua.TransferResult(StatusCode=ua.StatusCode(
                    StatusCodes.BadTooManySubscriptions)))  # type: ignore[arg-type]
            else:
                room -= 1
                results.append(None)
                taken.append(sid)
        done = iter(await super().transfer_subscriptions(dataclasses.replace(
            params, SubscriptionIds=taken), callback) if taken else [])
        return [next(done) if result is None else result for result in results]

    async def create_monitored_items(self, params: ua.CreateMonitoredItemsParameters,
                                     ) -> list[ua.MonitoredItemCreateResult]:
        """CreateMonitoredItems: the items past the subscription's
        opcua.max_monitored_items_per_subscription are each Bad_TooManyMonitoredItems (OPC
        10000-4 5.13.2), the others are created."""
        subscription = self.subscription_service.subscriptions.get(params.SubscriptionId)
        if subscription is None:  # asyncua's answer: Bad_SubscriptionIdInvalid
            return await super().create_monitored_items(params)
        # (asyncua 2.1 counts a subscription's items nowhere else.)
        held = len(subscription.monitored_item_srv._monitored_items)
        room = max(0, self.owner.link.config.max_monitored_items_per_subscription - held)
        items = list(params.ItemsToCreate)
        over = [ua.MonitoredItemCreateResult(StatusCode=ua.StatusCode(
            StatusCodes.BadTooManyMonitoredItems)) for _ in items[room:]]  # type: ignore[arg-type]
        if not over:
            return await super().create_monitored_items(params)
        created: list[ua.MonitoredItemCreateResult] = []
        if room:
            created = await super().create_monitored_items(
                dataclasses.replace(params, ItemsToCreate=items[:room]))
        return created + over

    async def delete_subscriptions(self, ids: list[int]) -> list[ua.StatusCode]:
        result = await super().delete_subscriptions(ids)
        self.owner.clients_changed()
        return result

    async def read(self, params: ua.ReadParameters) -> list[ua.DataValue]:
        """asyncua's Read, with UserAccessLevel for this session: asyncua keeps one per node,
        what set_writable gave every session alike; an anonymous session while [opcua.users]
        is set writes nothing (``may_write``), so its UserAccessLevel drops every write bit."""
        results = await super().read(params)
        if not self.owner.link.config.users or self._named():
            return results
        for i, item in enumerate(params.NodesToRead):
            shown = results[i]
            if (item.AttributeId == AttributeIds.UserAccessLevel and shown.Value is not None
                    and isinstance(shown.Value.Value, int) and shown.Value.Value & _WRITE_BITS):
                results[i] = dataclasses.replace(shown, Value=ua.Variant(
                    shown.Value.Value & ~_WRITE_BITS, ua.VariantType.Byte))
        return results

    def _who(self) -> str:
        user = self.user
        if user is not None and user.name:
            return f"user {user.name}"
        name = self.name
        if isinstance(name, tuple) and len(name) >= 2:
            return f"{name[0]}:{name[1]}"
        return str(name)

    def may_write(self, key: str) -> bool:
        """Whether this session may write the image node ``key``: its region is in
        opcua.writable and, with [opcua.users] set, the session is a user's (what
        ``write_on_loop`` holds it to, and what its UserAccessLevel says)."""
        owner = self.owner
        return key in owner.writable and (not owner.link.config.users or self._named())

    def _named(self) -> bool:
        """A user's session (a name and password, or a certificate), not an anonymous one."""
        return self.user is not None and bool(self.user.name)

    def _writable(self, node: ua.NodeId, attribute: int) -> bool:
        """Whether anyone may write this attribute of a node outside the image: its Value by
        its AccessLevel, any other by its WriteMask (every view of ours says no)."""
        if attribute == AttributeIds.Value:
            level = self.aspace.read_attribute_value(node, AttributeIds.AccessLevel)
            return level.Value is not None and bool(
                level.Value.Value & ua.AccessLevel.CurrentWrite.mask)
        mask = self.aspace.read_attribute_value(node, AttributeIds.WriteMask)
        return mask.Value is not None and bool(mask.Value.Value)

    async def write(self, params: ua.WriteParameters) -> list[ua.StatusCode]:
        owner = self.owner
        results: list[ua.StatusCode] = []
        for item in params.NodesToWrite:
            node = item.NodeId
            key = _image_key(owner, node)
            if key not in owner.image_types or item.AttributeId != AttributeIds.Value:
                if node not in self.aspace:  # (asyncua said Bad_UserAccessDenied of it)
                    results.append(ua.StatusCode(
                        StatusCodes.BadNodeIdUnknown))  # type: ignore[arg-type]
                    continue
                if not self._writable(node, item.AttributeId):
                    # No one may write it (asyncua said Bad_UserAccessDenied, as if another
                    # user could; OPC 10000-4 7.34: the access level does not allow it).
                    results.append(ua.StatusCode(
                        StatusCodes.BadNotWritable))  # type: ignore[arg-type]
                    continue
                one = ua.WriteParameters(NodesToWrite=[item])
                results.extend(await super().write(one))
                continue
            assert key is not None
            if self.may_write(key):  # (one that may not is refused by the loop's table)
                wrong = _write_refused(item, owner.image_types[key])
                if wrong is not None:
                    results.append(ua.StatusCode(wrong))  # type: ignore[arg-type]
                    continue
            value = item.Value.Value.Value if item.Value.Value is not None else None
            refused = await owner.link.write(key, value, self._who())
            code = (StatusCodes.Good if refused is None
                    else REFUSAL[refused] if isinstance(refused, Reason)
                    else StatusCodes.BadInternalError)
            results.append(ua.StatusCode(code))  # type: ignore[arg-type]
        return results


# A NumericRange (OPC 10000-4 7.27, its BNF in A.3): dimensions of an index or a range.
_NUMERIC_RANGE = re.compile(r"\d+(:\d+)?(,\d+(:\d+)?)*")


def _write_refused(item: ua.WriteValue, vtype: ua.VariantType) -> int | None:
    """The protocol's own refusal of a write of an image node (OPC 10000-4 5.11.4, Write),
    before it goes to the gateway's loop, so that nothing of it is applied or traced; None
    when the gateway's door is to judge the value.  The image keeps a scalar value and
    nothing else: an IndexRange is Bad_IndexRangeInvalid when its syntax is wrong (7.27),
    and Bad_WriteNotSupported otherwise, as is a StatusCode other than Good (5.11.4.2: a
    Server that cannot write what the client asks writes nothing); a timestamp is ignored
    (below); a value not a scalar of the node's DataType is Bad_TypeMismatch, exactly, no
    widening (docs/opcua.md, "Writes")."""
    if item.IndexRange:
        return (StatusCodes.BadWriteNotSupported if _valid_range(item.IndexRange)
                else StatusCodes.BadIndexRangeInvalid)
    data = item.Value
    status = data.StatusCode
    if status is not None and not status.is_good():
        return StatusCodes.BadWriteNotSupported
    # A timestamp is not kept and not refused: asyncua's own write_value stamps every write
    # with a SourceTimestamp, so refusing it (as Part 4 5.11.4 lets a server that keeps none)
    # refused every asyncua dashboard's writes (a hostile try; docs/decisions.md).
    variant = data.Value
    if not _scalar_of(variant, vtype) or variant.Value is None:
        return StatusCodes.BadTypeMismatch
    return None


def _valid_range(text: str) -> bool:
    """``text`` is a NumericRange by its syntax: each range's low index below its high."""
    if not _NUMERIC_RANGE.fullmatch(text):
        return False
    for dimension in text.split(","):
        low, _, high = dimension.partition(":")
        if high and int(low) >= int(high):
            return False
    return True


def _image_key(owner: Space, node: ua.NodeId) -> str | None:
    """The image variable or I/O name an image node shows (None: not an image node)."""
    if node.NamespaceIndex != owner.image_ns or not isinstance(node.Identifier, str):
        return None
    ident = node.Identifier
    area = ident.rstrip("0123456789")
    if area in _VTYPE and ident[len(area):].isdigit():
        return ident
    if ident in owner.link.symbols:
        return ident
    return None


if __name__ == "__main__":
    main()
