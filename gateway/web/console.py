"""The commissioning console: the page, the HTTP API under ``/api/`` and the live stream
(docs/console.md), served by aiohttp on the gateway's own event loop.

The only module that imports the web library.  What it serves:

- ``GET /`` the page, ``GET /static/…`` its script and style (package data, no build step);
- ``GET /api/status`` processes with their why-records, PLC and variables, image and last
  writers, fieldbus peers, counters; ``GET /api/events?since=N`` the trace's latest events;
  ``GET /api/stream`` the live stream (server-sent events: ``status`` and ``events``);
  ``GET /api/timeline.svg`` the timeline picture of the latest events;
  ``GET /api/programs`` the programs on the storage devices;
  ``GET /api/commands`` the command table (ncgate.commands) and the lanes' buttons;
- ``POST /api/write`` ``{"var": "SA10", "value": 1}`` as writer ``web``;
  ``POST /api/command`` ``{"command": "start" | "hold" | "reset"}``, or ``{"command":
  "start", "program": "PROG92", "process": 2}``.

Who may do what: reads are open to whoever reaches the port.  A write or a command is refused
from a foreign ``Origin`` (403, no cross-site writes from a browser tab), without the token
when ``web.token`` is set (401), and always under ``web.read_only`` (403).  Bound to loopback
(the default) the console answers only requests addressed to a loopback name (a DNS-rebinding
page cannot reach it); bound elsewhere, the config must set a token.  Errors are JSON:
``{"error": message}`` with the HTTP status.
"""

from __future__ import annotations

import asyncio
import hmac
import io
import logging
import math
import re
import socket
import time
from collections.abc import Awaitable, Callable
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError

from ncgate import commands
from ncgate.config.checks import is_loopback
from ncgate.config.schema import WebConfig
from ncgate.errors import InputRefused, Reason
from ncgate.gateway.door import only_releases_hold
from ncgate.gateway.ratelimit import LogFlood
from ncgate.gateway.record import program_files
from ncgate.gateway.timeline import write_gantt
from ncgate.gateway.tls import server_context
from ncgate.gateway.view import plant_status
from ncgate.gateway.web.feed import EventFeed, Turns
from ncgate.gateway.web.status import LiveStatus, status
from ncgate.inputs import (
    Break,
    ClearFault,
    Command,
    CommandKind,
    Fault,
    Force,
    Override,
    Source,
    SourceKind,
    Start,
    Write,
    var_name,
)
from ncgate.interpreter.engine import ProcessState
from ncgate.interpreter.engine.trace import to_jsonl
from ncgate.interpreter.storage import PROGRAM_SUFFIXES, program_name

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway

log = logging.getLogger("ncgate.web")

STATUS_EVERY_S = 0.25  # a stream's status at most this often (and when anything changed)
MESSAGE_BYTES = 64 * 1024  # a stream's message (one data line) at most this long
STREAMS_PER_TURN = 8  # streams that send in one loop turn; the others in the next ones
PING_S = 15.0  # a comment line on a quiet stream, so that proxies and clients keep it
WRITE_TIMEOUT_S = 10.0  # a client that takes no data this long is dropped
BODY_LIMIT = 16 * 1024
BODY_TIMEOUT_S = 5.0  # a request body not whole this long after its headers is refused (408)
# A connection with no request under way is closed after this long: a client that sent half a
# request line was held for aiohttp's default hour, and 1,100 such ones took every file
# descriptor of a process at the common limit of 1,024 (the Modbus server could accept no one).
IDLE_S = 10.0
# The longest variable, target or program name a request may give (the longest real one, an
# I/O name of [symbols] or a PLC path, is far shorter); what is longer is refused unechoed.
NAME_LIMIT = 200
# On every answer, the page's included: nothing of another origin runs in it, no other site
# may frame it (a framed console takes a click on a decoy as the operator's: clickjacking),
# no answer is sniffed as another type, no address leaks in a Referer.  The page has no
# inline script or style, so the strictest CSP holds (a real-browser test loads it).
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'",
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}
COMMANDS = {"start": 1, "hold": 2, "reset": 3}  # the page's words (start: a cycle start)
# Every command by its name, from the command table (ncgate.commands): the command
# word's kinds, the switches (with "on"), and "break" (with "at").
KINDS = {**{k.label: k for k in CommandKind}, "start": CommandKind.CYCLE_START,
         "hold": CommandKind.FEED_HOLD}
SWITCHES = {name: (CommandKind(on.word), CommandKind(off.word))
            for name, (on, off) in commands.switches().items()}
# The buttons on a process's lane (app.js asks /api/commands): (name, text) in word order.
LANE_BUTTONS = [(c.name, c.button) for c in commands.COMMANDS
                if c.button is not None and not c.cell_only]
# Why the door refused an input -> the HTTP status the API answers (the JSON body says the
# reason in words).  Total: a test checks that every Reason has a row.
HTTP_STATUS: dict[Reason, int] = {
    Reason.UNKNOWN_VARIABLE: 422,
    Reason.OUTSIDE_IMAGE: 422,
    Reason.BAD_VALUE: 422,
    Reason.READ_ONLY: 403,
    Reason.UNKNOWN_PROCESS: 422,
    Reason.EXTERNAL_PROCESS: 409,
    Reason.NOT_EXTERNAL: 422,
    Reason.BUSY: 409,
    Reason.INTERLOCK: 409,
    Reason.NOT_RUNNING: 409,
    Reason.NOT_CONFIGURED: 409,
    Reason.PROGRAM_NOT_FOUND: 404,
    Reason.PROGRAM_INVALID: 422,
    Reason.ROLE_FORBIDS: 403,
    Reason.UNSUPPORTED: 422,
}
ASSETS = ("index.html", "app.js", "style.css")
_TYPES = {"html": "text/html", "js": "text/javascript", "css": "text/css"}

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class ApiError(Exception):
    def __init__(self, status: int, message: str, headers: dict[str, str] | None = None
                 ) -> None:
        super().__init__(message)
        self.status, self.message, self.headers = status, message, headers or {}


class WebConsole:
    """The console of one gateway: ``await start()``, ``address``, ``await close()``."""

    def __init__(self, gateway: Gateway, config: WebConfig) -> None:
        self.gw = gateway
        self.config = config
        self.address: tuple[str, int] | None = None
        self.streams = 0
        self._feed: EventFeed | None = None
        # (position, the feed's seq) -> (the position after, the event messages): streams at
        # one position share one rendering of a batch (50 pages cost one, not fifty).
        self._batches: dict[tuple[int, int], tuple[int, str]] = {}
        # Streams take turns: at most STREAMS_PER_TURN of them send in one loop turn, so that
        # fifty pages woken by one batch do not hold the fieldbus up for one long turn.
        self._turns: Turns | None = None  # (made on the loop, at start)
        self._runner: web.AppRunner | None = None
        self._status_cache: tuple[tuple[int, ...], float, dict[str, str]] | None = None
        self._last_record: Path | None = None  # the record GET /api/record serves
        self._live: LiveStatus | None = None  # the streams' status, built by what changed
        self._status_texts: dict[tuple[str, ...], str] = {}  # by the parts a stream lacks
        self._status_texts_of: dict[str, str] | None = None  # ... of this status
        self._assets = {name: resources.files("ncgate.gateway.web").joinpath(
            "static", name).read_bytes() for name in ASSETS}
        self._loopback = is_loopback(config.host)

    # -- life -----------------------------------------------------------------------------

    async def start(self, sockets: list[socket.socket], feed: EventFeed) -> None:
        """Serve on ``sockets`` (listening: ``ConsolePort`` bound them at the gateway's
        start) the events of ``feed`` (subscribed to the trace since then)."""
        app = web.Application(middlewares=[self._guard], client_max_size=BODY_LIMIT)
        app.on_response_prepare.append(_secure)
        app.router.add_get("/", self._asset("index.html"))
        for name in ASSETS:
            app.router.add_get(f"/static/{name}", self._asset(name))
        app.router.add_get("/api/status", self._status)
        app.router.add_get("/api/events", self._events)
        app.router.add_get("/api/stream", self._stream)
        app.router.add_get("/api/timeline.svg", self._timeline)
        app.router.add_get("/api/programs", self._programs)
        app.router.add_get("/api/commands", self._commands)
        app.router.add_post("/api/write", self._write)
        app.router.add_post("/api/command", self._command)
        app.router.add_get("/api/force", self._forced)
        app.router.add_post("/api/force", self._force)
        app.router.add_post("/api/fault", self._fault)
        app.router.add_delete("/api/force", self._unforce_all)
        app.router.add_get("/api/trace.jsonl", self._trace)
        app.router.add_get("/api/record", self._record)
        app.router.add_post("/api/record", self._record_switch)
        runner = web.AppRunner(app, access_log=None, shutdown_timeout=1.0,
                               handle_signals=False, keepalive_timeout=IDLE_S)
        await runner.setup()
        # (Once per process, and left: a console closed must not take it from another.)
        logging.getLogger("aiohttp.server").addFilter(_MALFORMED)
        tls = self.config.tls
        # [web.tls]: HTTPS only, with the loader the Modbus TLS port uses (the files were
        # checked when the config loaded).
        context = (server_context(tls.cert, tls.key) if tls.cert is not None
                   and tls.key is not None else None)
        try:
            for sock in sockets:
                await web.SockSite(runner, sock, ssl_context=context).start()
        except BaseException:
            await runner.cleanup()
            raise
        self._runner = runner
        host, bound = runner.addresses[0][:2]
        self.address = (host, bound)
        self._feed = feed
        self._turns = Turns(asyncio.get_running_loop(), STREAMS_PER_TURN)

    async def close(self) -> None:
        if self._live is not None:
            self._live.close()
            self._live = None
        if self._feed is not None:
            self._feed.close()  # every stream returns
        if self._turns is not None:
            self._turns.close()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        self.address = None

    # -- who may do what ---------------------------------------------------------------------

    @web.middleware
    async def _guard(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        try:
            if self._loopback and not _loopback_host(request.host):
                raise ApiError(403, f"the console answers requests to a loopback address, not "
                               f"to {request.host!r} (web.host)")
            if request.method not in ("GET", "HEAD"):
                self._may_change(request)
            return await handler(request)
        except ApiError as exc:
            return _error(exc.status, exc.message, exc.headers)
        except web.HTTPException as exc:  # aiohttp's own: 404, 405, 413 ...
            if exc.status < 400:
                raise
            return _error(exc.status, exc.reason, {})
        except (asyncio.CancelledError, KeyboardInterrupt, SystemExit):
            raise
        except Exception as exc:  # a bug of ours: said, and the server goes on
            log.exception("web console: %s %s failed", request.method, request.path)
            return _error(500, f"internal error: {exc}", {})

    def _may_change(self, request: web.Request) -> None:
        origin = request.headers.get("Origin")
        here = f"{request.scheme}://{request.host}"
        if (origin is not None and origin != here) or (
                request.headers.get("Sec-Fetch-Site") == "cross-site"):
            raise ApiError(403, f"a write from another origin ({origin or 'cross-site'}) is "
                           "refused")
        token = self.config.token
        if token is not None:
            given = request.headers.get("Authorization", "")
            if not (given.startswith("Bearer ") and hmac.compare_digest(
                    given[7:].strip().encode(), token.encode())):
                raise ApiError(401, "this console needs its token: Authorization: Bearer "
                               "<web.token>", {"WWW-Authenticate": 'Bearer realm="ncgate"'})
        if self.config.read_only:
            raise ApiError(403, "the console is read-only (web.read_only)")

    # -- the page ---------------------------------------------------------------------------

    def _asset(self, name: str) -> Handler:
        body = self._assets[name]
        kind = _TYPES[name.rsplit(".", 1)[1]]

        async def serve(request: web.Request) -> web.StreamResponse:
            return web.Response(body=body, content_type=kind, charset="utf-8",
                                headers={"Cache-Control": "no-cache"})
        return serve

    # -- reads ------------------------------------------------------------------------------

    async def _status(self, request: web.Request) -> web.StreamResponse:
        image = request.query.get("image", "1") != "0"
        return web.json_response(status(self.gw, image=image))

    def _batch(self, feed: EventFeed, position: int) -> tuple[int, str]:
        """The event messages after ``position`` and the position after them, made once for
        every stream that stands there."""
        key = (position, feed.seq)
        found = self._batches.get(key)
        if found is None:
            texts, missed = feed.since(position)
            after = position + missed + len(texts)
            found = (after, "".join(event_messages(texts, missed, after)) if texts else "")
            if len(self._batches) >= 256:
                self._batches.clear()
            self._batches[key] = found
        return found

    async def _events(self, request: web.Request) -> web.StreamResponse:
        assert self._feed is not None
        since = _int_query(request, "since", 0)
        texts, missed = self._feed.since(since)
        last = since + missed + len(texts) if texts else self._feed.seq  # (paged: ask again)
        body = f'{{"seq":{last},"missed":{missed},"events":[{",".join(texts)}]}}'
        return web.Response(text=body, content_type="application/json")

    async def _programs(self, request: web.Request) -> web.StreamResponse:
        # Files a program name can name (spec 1.1): not the config, the PLC logic, a README.
        names = sorted({program_name(path) for path in program_files(self.gw.config)
                        if path.suffix.lower() in PROGRAM_SUFFIXES})
        return web.json_response({"programs": names, "main": self.gw.config.nc.main})

    async def _commands(self, request: web.Request) -> web.StreamResponse:
        """The command table (ncgate.commands): the names ``POST /api/command`` takes, and
        the buttons of a process's lane, which the page draws from it."""
        rows = [{"word": c.word, "name": c.name, "title": c.title, "help": c.help,
                 "cell_only": c.cell_only, "switch": c.switch}
                for c in commands.COMMANDS if not c.with_n]
        return web.json_response({"commands": rows, "switches": sorted(SWITCHES),
                                  "lane": [list(b) for b in LANE_BUTTONS]})

    async def _timeline(self, request: web.Request) -> web.StreamResponse:
        config = self.gw.config.nc
        out = io.StringIO()
        write_gantt(self.gw.trace, config.processes, out, external=config.external)
        return web.Response(text=out.getvalue(), content_type="image/svg+xml")

    async def _trace(self, request: web.Request) -> web.StreamResponse:
        """The events kept (``trace.ring``) as a trace file: one JSON line each."""
        events = self.gw.runtime.trace.events
        body = "".join(to_jsonl(event) + "\n" for event in events)
        name = f"ncgate-trace-{self.gw.session}.jsonl"
        return web.Response(text=body, content_type="application/jsonl", headers={
            "Content-Disposition": f'attachment; filename="{name}"'})

    async def _record(self, request: web.Request) -> web.StreamResponse:
        """The session record being written (as far as it is), or the last one."""
        recorder = self.gw.recorder
        if recorder is not None:
            recorder.flush()
            self._last_record = recorder.path
        path = self._last_record
        if path is None or not path.is_file():
            raise ApiError(404, "no record: start one (POST /api/record {\"on\": true}, or "
                           "run --record FILE)")
        return web.FileResponse(path, headers={
            "Content-Type": "application/jsonl",
            "Content-Disposition": f'attachment; filename="{path.name}"'})

    async def _record_switch(self, request: web.Request) -> web.StreamResponse:
        """``{"on": true}`` starts a record (beside ``run --record``'s file, or in the
        folder ``run`` was started in); ``{"on": false}`` closes it with its stop line."""
        body = await self._body(request)
        on = body.get("on")
        if not isinstance(on, bool):
            raise ApiError(400, 'expected {"on": true} or {"on": false}')
        gw = self.gw
        if not on:
            path = gw.stop_record()
            if path is None:
                raise ApiError(409, "no record is being written")
            self._last_record = path
            log.info("web %s: record %s closed", request.remote, path)
            return web.json_response({"record": None, "last": str(path)})
        if gw.recorder is not None:
            raise ApiError(409, f"a record is being written already ({gw.recorder.path})")
        # The replay starts every process from its program's start: a record begun while
        # one runs would hold the rest of a run without its start (docs/decisions.md).
        busy = [p.number for p in gw.view.processes
                if not p.external and p.state is not ProcessState.IDLE]
        if busy:
            raise ApiError(409, f"process {busy[0]} runs a program: start a record while "
                           "every process is idle (Reset first)")
        # Nor do forces or faults come into a replay that were in force before its record:
        # it would replay another cell (a hostile try: a clamp that never closes, replayed
        # closing, and a divergence that named neither).
        plc, plant = gw.runtime.plc, gw.runtime.plant
        forces = len(gw.image.forced) + (len(plc.forced) if plc is not None else 0)
        faults = len(plant.faults) if plant is not None else 0
        if forces or faults:
            raise ApiError(409, f"{forces} force(s) and {faults} fault(s) are in force, which "
                           "a replay of this record would not have: release the forces and "
                           "clear the faults first (or record from the start: run --record)")
        path = gw.start_record(record_path(gw.record_folder))
        self._last_record = path
        log.info("web %s: recording to %s", request.remote, path)
        return web.json_response({"record": str(path)})

    def _status_parts(self) -> dict[str, str]:
        """The status as JSON parts (each top-level key, and the image's ``sa``, ``k``,
        ``syvar`` and ``writers`` apart), built at most once per STATUS_EVERY_S for every
        stream; a stream sends the parts that changed since it last sent them."""
        gw = self.gw
        now = asyncio.get_running_loop().time()
        # What the status shows changes with the trace, the image and the clock -- and, while
        # the cell is idle and none of those move, with what is not traced: a record started
        # or stopped, the breakpoints set; anything else at the latest a second later.
        key = (gw.runtime.trace.seq, gw.image.generation, int(gw.engine.now * 1000),
               id(gw.recorder), len(gw.engine.breakpoints), int(now))
        cached = self._status_cache
        if cached is None or (cached[0] != key and now - cached[1] >= STATUS_EVERY_S / 2):
            if self._live is None:
                self._live = LiveStatus(gw)
            cached = (key, now, self._live.parts())
            self._status_cache = cached
        return cached[2]

    def _status_message(self, parts: dict[str, str], changed: dict[str, str]) -> str:
        """The status messages of these changed parts, made once for every stream that
        lacks the same parts of the same status (streams in step all lack the same)."""
        if parts is not self._status_texts_of:  # a new status: the old texts serve nobody
            self._status_texts_of = parts
            self._status_texts.clear()
        key = tuple(changed)
        found = self._status_texts.get(key)
        if found is None:
            found = self._status_texts[key] = "".join(status_messages(changed))
        return found

    async def _stream(self, request: web.Request) -> web.StreamResponse:
        """Server-sent events, coalesced for each client: ``status`` (what changed since
        the last one -- the first is whole -- at most every STATUS_EVERY_S) and ``events``
        (the trace events since the last batch, at most one batch per feed.BATCH_S, with
        ``id`` = the last seq so that a reconnecting page resumes where it was).  No message
        is longer than MESSAGE_BYTES but a single status part: a client that connects to a
        full ring, or falls behind, gets its events in several messages."""
        feed, turns = self._feed, self._turns
        assert feed is not None and turns is not None
        if self.streams >= self.config.max_streams:
            raise ApiError(503, f"{self.streams} live streams already (web.max_streams)")
        since = _int_query(request, "since", -1)
        last_id = request.headers.get("Last-Event-ID", "")
        if last_id.isdigit():
            since = int(last_id)
        if since > feed.seq:
            since = 0  # an id of an earlier session (the gateway restarted): from the start
        response = web.StreamResponse(headers={"Content-Type": "text/event-stream",
                                               "Cache-Control": "no-cache",
                                               "X-Accel-Buffering": "no"})
        self.streams += 1
        try:
            await response.prepare(request)
            # A new page gets what the ring holds (its timeline and log start filled).
            position = max(since, 0)
            sent: dict[str, str] = {}  # the status parts this client has
            status_at = written_at = -1e9
            loop = asyncio.get_running_loop()
            await self._send(response, "retry: 1000\n\n")
            while not feed.closed and not _gone(request):
                await turns.take()
                messages: list[str] = []
                now = loop.time()
                if now - status_at >= STATUS_EVERY_S:  # first: it names the session
                    parts = self._status_parts()
                    changed = {name: text for name, text in parts.items()
                               if sent.get(name) != text}
                    if changed:
                        messages.append(self._status_message(parts, changed))
                        sent.update(changed)
                        status_at = now
                position, text = self._batch(feed, position)
                if text:
                    messages.append(text)
                if not messages and now - written_at >= PING_S:
                    messages.append(": ping\n\n")
                if messages:
                    await self._send(response, "".join(messages))
                    written_at = now
                if position < feed.seq:  # more than one read's worth: the rest at once
                    await asyncio.sleep(0)
                    continue
                await feed.wait(STATUS_EVERY_S)
        except (ConnectionError, TimeoutError):
            # The client went away (a reset; aiohttp's "Connection lost" when it went while a
            # write waited: that was an ERROR with a traceback each), or read nothing for
            # WRITE_TIMEOUT_S: its stream ends.
            pass
        finally:
            self.streams -= 1
        return response

    @staticmethod
    async def _send(response: web.StreamResponse, text: str) -> None:
        async with asyncio.timeout(WRITE_TIMEOUT_S):
            await response.write(text.encode("utf-8"))

    # -- writes and commands -------------------------------------------------------------------

    async def _body(self, request: web.Request) -> dict[str, Any]:
        if request.content_type != "application/json":
            raise ApiError(415, "send JSON (Content-Type: application/json)")
        try:
            # A body is at most BODY_LIMIT bytes: one that has not come whole within
            # BODY_TIMEOUT_S is not coming (a slow or stalled client holds nothing longer).
            async with asyncio.timeout(BODY_TIMEOUT_S):
                body = await request.json()
        except TimeoutError:
            log.info("web %s: %s %s: the body did not come within %g s", request.remote,
                     request.method, request.path, BODY_TIMEOUT_S)
            raise ApiError(408, f"the body did not come within {BODY_TIMEOUT_S:g} s") \
                from None
        except ConnectionResetError:  # the client went away mid-body: one line, no more
            log.info("web %s: %s %s: the client went away before its body was whole",
                     request.remote, request.method, request.path)
            raise ApiError(400, "the connection was lost before the body was whole") \
                from None
        except ValueError as exc:
            if "integer string conversion" in str(exc):  # Python's limit, not bad JSON
                raise ApiError(400, "a number in the body has more digits than any value "
                               "here can hold") from None
            raise ApiError(400, "the body is not JSON") from None
        except UnicodeDecodeError:
            raise ApiError(400, "the body is not JSON") from None
        except RecursionError:  # [[[[...: deeper than the parser's stack
            raise ApiError(400, "the body is nested too deeply") from None
        if not isinstance(body, dict):
            raise ApiError(400, "expected a JSON object")
        for key in ("var", "target", "clear"):  # names, echoed in the answers: never essays
            named = body.get(key)
            if isinstance(named, str) and len(named) > NAME_LIMIT:
                raise ApiError(400, f'"{key}": a name of at most {NAME_LIMIT} characters, '
                               f"got {len(named)}")
        return body

    async def _forced(self, request: web.Request) -> web.StreamResponse:
        """The force list: each forced variable and its value."""
        plc = self.gw.runtime.plc
        return web.json_response({"forced": [
            {"var": var_name(area, index, view), "value": value}
            for (area, index, view), value in self.gw.views.status().forced] + [
            {"var": path, "value": value}
            for path, value in (plc.forced.values() if plc is not None else ())]})

    async def _force(self, request: web.Request) -> web.StreamResponse:
        """``{"var": "SA10", "value": 1}`` forces; ``"value": null`` releases it."""
        body = await self._body(request)
        var, value = body.get("var"), body.get("value")
        # A release says "value": null; a body without "value" is no request to release.
        if not isinstance(var, str) or not var.strip() or "value" not in body:
            raise ApiError(400, 'expected {"var": "SA10", "value": 1 or null}')
        if value is not None and (not isinstance(value, int | float) or (
                isinstance(value, float) and not math.isfinite(value))):
            raise ApiError(400, f'"value": a number, true, false or null, got {value!r}')
        try:
            item = Force(self.gw.runtime.force_target(var), value, _source(request))
            self.gw.apply(item)
        except InputRefused as exc:
            raise ApiError(HTTP_STATUS[exc.reason], f"{var}: {exc}") from None
        log.info("web %s: force %s = %s", request.remote, item.var, value)
        return web.json_response({"var": str(item.var), "value": value})

    async def _fault(self, request: web.Request) -> web.StreamResponse:
        """``{"target": "clamp", "kind": "never"}`` (and the kind's keys, ``for_s``) injects a
        fault; ``{"clear": "clamp"}`` clears the target's, ``{"clear": "all"}`` every one."""
        body = await self._body(request)
        source = _source(request)
        item: Fault | ClearFault
        if "clear" in body:
            target = body["clear"]
            if set(body) != {"clear"} or not isinstance(target, str) or not target.strip():
                raise ApiError(400, 'expected {"clear": "clamp"} or {"clear": "all"}')
            item = ClearFault(None if target.strip() in ("all", "*") else target, source)
        else:
            target, kind = body.get("target"), body.get("kind")
            if not isinstance(target, str) or not isinstance(kind, str):
                raise ApiError(400, 'expected {"target": "clamp", "kind": "never"} (and the '
                               'kind\'s keys) or {"clear": "clamp"}')
            params = {k: v for k, v in body.items() if k not in ("target", "kind", "for_s")}
            for_s = body.get("for_s")
            if for_s is not None and (isinstance(for_s, bool)
                                      or not isinstance(for_s, int | float)):
                raise ApiError(400, f'"for_s": a time in seconds, got {for_s!r}')
            item = Fault(target, kind, tuple(sorted((k, tuple(v) if isinstance(v, list) else v)
                                                    for k, v in params.items())), for_s, source)
        try:
            self.gw.apply(item)
        except InputRefused as exc:
            raise ApiError(HTTP_STATUS[exc.reason], str(exc)) from None
        # (no line of its own: the trace's fault and fault_clear events are logged, each
        # attributed to its source as every input's is -- `ncgate run`'s log)
        plant = self.gw.views.plant()
        return web.json_response(plant_status(plant)["faults"] if plant is not None else [])

    async def _unforce_all(self, request: web.Request) -> web.StreamResponse:
        self.gw.apply(Force(None, None, _source(request)))
        log.info("web %s: every force released", request.remote)
        return web.json_response({"forced": []})

    async def _write(self, request: web.Request) -> web.StreamResponse:
        body = await self._body(request)
        var, value = body.get("var"), body.get("value")
        if not isinstance(var, str) or not var.strip():
            raise ApiError(400, 'expected {"var": "SA10", "value": 1}: "var" is missing')
        if isinstance(value, bool) or not isinstance(value, int):
            raise ApiError(400, f'"value": expected a whole number, got {value!r}')
        name = var.strip().upper()
        if name.endswith("FEED_OVERRIDE"):
            found = re.fullmatch(r"(?:P([0-9]{1,3})\.)?FEED_OVERRIDE", name)
            if found is None:
                raise ApiError(422, f"{var}: FEED_OVERRIDE, or P<k>.FEED_OVERRIDE")
            process = found.group(1)
            try:
                self.gw.apply(Override(value, None, int(process) if process else None,
                                       _source(request)))
            except InputRefused as exc:
                raise ApiError(HTTP_STATUS[exc.reason], f"{var}: {exc}") from None
            return web.json_response({"var": name, "value": value})
        try:
            item = Write(self.gw.runtime.var(var), value, _source(request))
            self.gw.apply(item)
        except InputRefused as exc:
            raise ApiError(HTTP_STATUS[exc.reason], f"{var}: {exc}") from None
        log.info("web %s: %s = %d", request.remote, item.var, value)
        return web.json_response({"var": str(item.var), "value": value})

    async def _command(self, request: web.Request) -> web.StreamResponse:
        body = await self._body(request)
        command = body.get("command")
        names = [*KINDS, *SWITCHES, "break"]
        if command not in names:
            raise ApiError(400, f"\"command\": expected one of {', '.join(names)}, got "
                           f"{command!r}")
        program, process = body.get("program"), body.get("process", 1)
        source = _source(request)
        item: Command | Start | Break
        if program is None and ("at" in body or "with_calc" in body) and command != "break":
            raise ApiError(400, '"at" and "with_calc" go with "program" (a block search)')
        if command == "break":
            at, on = body.get("at"), body.get("on", True)
            if not isinstance(at, str) or not isinstance(on, bool):
                raise ApiError(400, 'expected {"command": "break", "at": "PROG92:8", "on": '
                               'true}')
            item = Break(at, on, source)
        elif program is None:
            one = body.get("process")
            if one is not None and (isinstance(one, bool) or not isinstance(one, int)):
                raise ApiError(400, f'"process": a process number or null, got {one!r}')
            if command in SWITCHES:
                on = body.get("on")
                if not isinstance(on, bool):
                    raise ApiError(400, f'"on": true or false, for {command}')
                kind = SWITCHES[command][0 if on else 1]
            else:
                kind = KINDS[command]
            item = Command(kind, one, source)
        elif command != "start":
            raise ApiError(400, '"program" goes with the "start" command')
        else:
            processes = self.gw.config.nc.processes
            if not isinstance(program, str) or not program or (
                    isinstance(process, bool) or not isinstance(process, int)
                    or not 1 <= process <= processes):
                raise ApiError(400, f'expected {{"command": "start", "program": NAME, '
                               f'"process": 1..{processes}}}')
            if any(c in program for c in "/\\") or program.startswith("."):
                raise ApiError(400, f'"program": a program\'s name on the storage devices, '
                               f"not a path: {program!r}")
            at, with_calc = body.get("at"), body.get("with_calc", False)
            if (at is not None and not isinstance(at, str)) or not isinstance(with_calc, bool):
                raise ApiError(400, '"at": a label or an N number (a block search), '
                               '"with_calc": true or false')
            item = Start(program, process, source, at, with_calc)
        if isinstance(item, Command) and item.kind is CommandKind.RELOAD_PLC:
            return await self._reload_plc(item, request)
        # (asked before it acts: after it, the hold is gone)
        released = only_releases_hold(self.gw.runtime, item) if isinstance(item, Command) \
            else None
        try:
            await self.gw.apply_async(item)  # a program is read off the loop
        except InputRefused as exc:
            raise ApiError(HTTP_STATUS[exc.reason], str(exc)) from None
        if isinstance(item, Start):
            log.info("web %s: start %s in P%d", request.remote, program, process)
            return web.json_response({"command": command, "program": program,
                                      "process": process})
        if released is not None:
            log.info("web %s: %s %s", request.remote, command, released)
            return web.json_response({"command": command, "message": released})
        log.info("web %s: %s", request.remote, command)
        return web.json_response({"command": command})


    async def _reload_plc(self, item: Command, request: web.Request) -> web.StreamResponse:
        """Online change: 200 with what was kept, or 422 with the diagnostics when the logic
        did not load (the old logic runs on)."""
        if item.process is not None:
            raise ApiError(400, "reload_plc acts on the whole cell: give it without a process")
        try:
            outcome = await self.gw.reload_plc(item.source)
        except InputRefused as exc:
            raise ApiError(HTTP_STATUS[exc.reason], str(exc)) from None
        log.info("web %s: reload_plc (%s)", request.remote, "loaded" if outcome.ok else
                 "not loaded")
        return web.json_response({"command": "reload_plc", **outcome.as_dict()},
                                 status=200 if outcome.ok else 422)


def record_path(folder: Path) -> Path:
    """A new record's file in ``folder``: ``ncgate-record-<UTC time>.jsonl``, never one
    that exists."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    path = folder / f"ncgate-record-{stamp}.jsonl"
    number = 2
    while path.exists():
        path = folder / f"ncgate-record-{stamp}-{number}.jsonl"
        number += 1
    return path


def status_messages(parts: dict[str, str]) -> list[str]:
    """``event: status`` messages holding these parts, packed up to MESSAGE_BYTES each (a
    part is never split): ``{"t": ..., "image": {"sa": ...}}``, to be merged by the page."""
    messages: list[str] = []
    top: list[str] = []
    image: list[str] = []
    size = 0

    def close() -> None:
        nonlocal top, image, size
        items = top + ([f'"image":{{{",".join(image)}}}'] if image else [])
        if items:
            messages.append(f"event: status\ndata: {{{','.join(items)}}}\n\n")
        top, image, size = [], [], 0

    for name, text in parts.items():
        area, _, sub = name.partition(".")
        item = f'"{sub or area}":{text}'
        if size and size + len(item) > MESSAGE_BYTES:
            close()
        (image if sub else top).append(item)
        size += len(item) + 1
    close()
    return messages


def event_messages(texts: list[str], missed: int, position: int) -> list[str]:
    """``event: events`` messages of these events (the last one's seq is ``position``), up
    to MESSAGE_BYTES each; ``id`` is the seq of each message's last event, ``missed`` is in
    the first."""
    chunks: list[list[str]] = [[]]
    size = 0
    for text in texts:
        if chunks[-1] and size + len(text) + 1 > MESSAGE_BYTES - 64:  # 64: the envelope
            chunks.append([])
            size = 0
        chunks[-1].append(text)
        size += len(text) + 1
    messages = []
    seq = position - len(texts)
    for number, chunk in enumerate(chunks):
        seq += len(chunk)
        messages.append(f'id: {seq}\nevent: events\ndata: {{"missed":'
                        f'{missed if number == 0 else 0},"events":[{",".join(chunk)}]}}\n\n')
    return messages


async def _secure(request: web.Request, response: web.StreamResponse) -> None:
    response.headers.update(SECURITY_HEADERS)


def _gone(request: web.Request) -> bool:
    """The client closed its connection (aiohttp does not cancel a handler for that)."""
    transport = request.transport
    return transport is None or transport.is_closing()


def _source(request: web.Request) -> Source:
    """The console's attribution: ``web`` and the browser's address."""
    peer = request.remote or "?"
    return Source(SourceKind.WEB, peer, peer)


def _error(status: int, message: str, headers: dict[str, str]) -> web.Response:
    return web.json_response({"error": message}, status=status, headers=headers)


def _int_query(request: web.Request, name: str, default: int) -> int:
    text = request.query.get(name)
    if text is None:
        return default
    try:
        return int(text)
    except ValueError:
        raise ApiError(400, f"?{name}=: expected a whole number, got {text!r}") from None


def _loopback_host(host_header: str) -> bool:
    host = host_header
    if host.startswith("["):
        host = host[1:].split("]", 1)[0]
    elif host.count(":") == 1:
        host = host.split(":", 1)[0]
    return is_loopback(host.lower())


class _MalformedRequests(logging.Filter):
    """aiohttp logs a request it cannot parse (a header line of 20 KB, a bad request line) as
    an ERROR with a traceback: any client could write one per request.  It is the client's
    fault, not ours: one INFO line, a few of a kind every 10 s (LogFlood)."""

    def __init__(self) -> None:
        super().__init__()
        self._flood = LogFlood()

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError):
            remote = record.args[0] if isinstance(record.args, tuple) and record.args else "?"
            record.msg, record.args = "web %s: a malformed request (%s)", (
                remote, str(exc).replace("\n", " ")[:200])
            record.exc_info = record.exc_text = None
            record.levelno, record.levelname = logging.INFO, "INFO"
            return self._flood.filter(record)
        return True


_MALFORMED = _MalformedRequests()
