"""The console's port: listened on at start, its web stack loaded at the first connection.

aiohttp and the console's handlers are 14 MiB of the gateway's memory (docs/decisions.md,
"The console loads at its first connection").  A gateway in a rack that nobody opens a page
of should not carry them, yet its console must be there the moment someone does, on the
port it said at start (and a taken port must still be an error at start).  So this adapter
binds and listens at start, as aiohttp would, but does not accept: the loop watches the
listening sockets, and the first connection that arrives imports the console *on a thread*
(an import of 0.1-0.3 s on the loop would hold the scan and the pollers up), then hands it
the same sockets.  The connection waits in the listen backlog meanwhile, and so does any
other; none is refused.  The live stream's feed (``EventFeed``, no web library) subscribes
to the trace at start, so a page opened later still gets the ring's events since then.

No aiohttp here (``tests/integration/test_adapters.py`` checks the process's maps).
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import importlib
import logging
import socket
from collections.abc import Callable
from typing import TYPE_CHECKING

from ncgate.config.schema import WebConfig
from ncgate.gateway.errors import listen_error
from ncgate.gateway.web.feed import EventFeed

if TYPE_CHECKING:
    from ncgate.gateway.app import Gateway
    from ncgate.gateway.web.console import WebConsole

log = logging.getLogger("ncgate.web")

BACKLOG = 128  # connections the kernel holds while the console loads (aiohttp's own default)


class ConsolePort:
    """The console as the gateway's adapter (``start``, ``close``): ``address`` and ``url``
    from the start, ``console`` once a client has connected."""

    def __init__(self, gateway: Gateway, config: WebConfig, default_port: int = 0) -> None:
        self.gw = gateway
        self.config = config
        self.default_port = default_port
        self.address: tuple[str, int] | None = None
        self.console: WebConsole | None = None
        self._sockets: list[socket.socket] = []
        self._feed: EventFeed | None = None
        self._unsubscribe: Callable[[], None] | None = None
        self._waking: asyncio.Task[None] | None = None

    @property
    def streams(self) -> int:
        """The live streams open (none before the console has loaded)."""
        return self.console.streams if self.console is not None else 0

    @property
    def url(self) -> str:
        assert self.address is not None
        host, port = self.address
        scheme = "https" if self.config.tls.enabled else "http"
        return f"{scheme}://{f'[{host}]' if ':' in host else host}:{port}/"

    async def start(self) -> None:
        """Listen.  The default port taken: the console stays off, ``address`` None (``run``
        goes on without it); a port set in the config that is taken raises OSError naming
        the key."""
        loop = asyncio.get_running_loop()
        port = self.config.port if self.config.port is not None else self.default_port
        try:
            self._sockets = await _listen(loop, self.config.host, port)
        except OSError as exc:
            if self.config.port is None and port:
                log.warning("web console off: %s:%d is taken (%s); set web.port or --web "
                            "HOST:PORT", self.config.host, port, exc.strerror)
                return
            raise listen_error(exc, "web.port", self.config.host, port) from None
        host, bound = self._sockets[0].getsockname()[:2]  # the port asked for may be 0
        self.address = (host, bound)
        gw = self.gw
        self._feed = EventFeed(loop, behind=lambda: gw.behind)
        self._unsubscribe = self.gw.runtime.trace.subscribe(self._feed.listen)
        for sock in self._sockets:
            loop.add_reader(sock.fileno(), self._knock)

    def _knock(self) -> None:
        """A connection waits on a listening socket: load the console (once)."""
        loop = asyncio.get_running_loop()
        for sock in self._sockets:
            loop.remove_reader(sock.fileno())
        if self._waking is None:
            self._waking = loop.create_task(self._wake())

    async def _wake(self) -> None:
        assert self._feed is not None
        try:
            module = await asyncio.to_thread(importlib.import_module,
                                             "ncgate.gateway.web.console")
            console: WebConsole = module.WebConsole(self.gw, self.config)
            await console.start(self._sockets, self._feed)
        except Exception:  # (aiohttp broken on disk under a long-running gateway, say)
            log.exception("web console: could not start; it is off")
            self._close_sockets()  # its clients are refused, not left waiting
            return
        self.console = console
        # What the import left alive (aiohttp's modules, about 100k objects) goes to the
        # collector's permanent generation, as if it had been loaded at start: else the next
        # full collections walk it on the loop (9-10 ms each: bench/storm.py's quiet phase,
        # whose first status request loads the console, had its poller's max at 9.5 ms,
        # not 5).  The objects are freed by their counts as ever; gc.unfreeze (a kept big
        # parse's release, interpreter/heap.py) hands them back.
        gc.freeze()
        log.debug("web console loaded at its first connection")

    async def close(self) -> None:
        waking, self._waking = self._waking, None
        if waking is not None and not waking.done():
            waking.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await waking
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None
        console, self.console = self.console, None
        if console is not None:
            await console.close()  # its server closes the sockets
        else:
            self._close_sockets()
        if self._feed is not None:
            self._feed.close()
            self._feed = None
        self.address = None

    def _close_sockets(self) -> None:
        with contextlib.suppress(RuntimeError):  # the loop may be closing
            loop = asyncio.get_running_loop()
            for sock in self._sockets:
                if sock.fileno() >= 0:
                    loop.remove_reader(sock.fileno())
        for sock in self._sockets:
            sock.close()
        self._sockets = []


async def _listen(loop: asyncio.AbstractEventLoop, host: str,
                  port: int) -> list[socket.socket]:
    """Listening sockets for ``host``:``port``, one per address it resolves to, as
    ``loop.create_server`` (hence aiohttp) binds them: SO_REUSEADDR, IPv6 only on IPv6."""
    infos = await loop.getaddrinfo(host or None, port, type=socket.SOCK_STREAM,
                                   flags=socket.AI_PASSIVE)
    sockets: list[socket.socket] = []
    try:
        for family, kind, proto, _, address in dict.fromkeys(infos):
            sock = socket.socket(family, kind, proto)
            sockets.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
            sock.listen(BACKLOG)
            sock.setblocking(False)
    except OSError:
        for sock in sockets:
            sock.close()
        raise
    return sockets
