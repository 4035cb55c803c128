"""The node's can-remote hub: python-can-remote's ``RemoteServer``, each client's session
ended whole, however the client goes.

A hub client (``interface = "remote"``) gets a bus of its own on the node's interface, and
may ask the hub to send a frame periodically (``send_periodic``: canopen's
``network.send_periodic`` for a master's heartbeat or a SYNC producer).  python-can-remote
0.3 ends such a task only when its session's sending thread leaves its loop: a client that
died while that thread wrote to it (``BrokenPipeError``, ``ConnectionResetError``) killed the
thread instead, and the task went on sending for the dead master until the gateway stopped:
no heartbeat timeout, no AL150, no feed hold.  Here the session ends in a ``finally`` of its
own, whatever ends it (the client closes, dies, stops reading, the hub closes): its periodic
tasks stop and its bus shuts down.

The only module that knows ``can_remote``'s server; imports nothing of the gateway.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import sys
import threading
from typing import Any

from can_remote.server import ClientRequestHandler, RemoteServer, RemoteServerProtocol
from can_remote.websocket import WebSocket, get_accept_key

log = logging.getLogger("ncgate.canopen")
# How long a client has for its request line and headers (the WebSocket handshake): a client
# that sent half a request line held a thread reading it for ever, also after the gateway's
# close.  Once the session runs, reads wait as long as the client is silent.
HANDSHAKE_S = 10.0


class Session(RemoteServerProtocol):  # type: ignore[misc]  # (can_remote is untyped)
    """One hub client's bus and periodic tasks, ended by :meth:`end` when the client goes."""

    running: bool  # python-can-remote's: its two threads loop while it holds

    def __init__(self, config: dict[str, Any], websocket: WebSocket) -> None:
        self._end_lock = threading.Lock()
        self._ended = False
        self._socket: socket.socket = websocket.socket
        try:
            super().__init__(config, websocket)
        except BaseException:
            # The bus opened, then the answer could not be sent: nothing else would close it.
            if getattr(self, "bus", None) is not None:
                self.bus.shutdown()
            raise

    def run(self) -> None:
        try:
            super().run()
        except Exception as exc:  # gone mid-answer (python-can-remote's closing frame)
            log.info("CANopen hub: a client's session ends (%s: %s)", type(exc).__name__, exc)
        finally:
            self.end()

    def _send_to_client(self) -> None:
        """The bus's frames to the client (python-can-remote's loop), ending the session
        when a write fails: the receiving side is woken, and the session's ``finally``
        stops what the client started."""
        try:
            while self.running:
                msg = self.bus.recv(0.5)
                if msg is not None:
                    self.send_msg(msg)
        except Exception as exc:  # the client is gone (or the bus): its session ends
            log.info("CANopen hub: a client's session ends (%s: %s)", type(exc).__name__, exc)
        finally:
            self.running = False
            self._wake()

    def _wake(self) -> None:
        """The receiving side returns from its read (end of stream)."""
        with contextlib.suppress(OSError):  # closed already
            self._socket.shutdown(socket.SHUT_RDWR)

    def end(self) -> None:
        """Stop every periodic task the client started and shut its bus down; from any
        thread, any number of times (a task started meanwhile is stopped by the next)."""
        self.running = False
        with self._end_lock:
            for task in list(self._send_tasks.values()):
                task.stop()
            self._send_tasks.clear()
            self.bus.stop_all_periodic_tasks()
            if not self._ended:
                self._ended = True
                self._wake()
                self.bus.shutdown()


class _ClientHandler(ClientRequestHandler):  # type: ignore[misc]
    def setup(self) -> None:
        self.timeout = HANDSHAKE_S  # (StreamRequestHandler sets it on the socket)
        super().setup()

    def start_websocket(self) -> None:
        # python-can-remote 0.3's own, with a Session, removed from the hub's list however
        # it ends.
        log.info("CANopen hub: a client connects from %s", self.address_string())
        self.send_response(101)
        self.send_header("Upgrade", "WebSocket")
        self.send_header("Connection", "Upgrade")
        self.send_header("Sec-WebSocket-Accept",
                         get_accept_key(self.headers["Sec-WebSocket-Key"]))
        offered = self.headers.get("Sec-WebSocket-Protocol", "can.json.v1")
        protocols = [p.strip() for p in offered.split(",")]
        protocol = "can.binary+json.v1" if "can.binary+json.v1" in protocols else "can.json.v1"
        self.send_header("Sec-WebSocket-Protocol", protocol)
        self.end_headers()
        self.request.settimeout(None)  # the handshake is done: a master may be silent
        session = Session(self.server.config, WebSocket(None, protocol, sock=self.request))
        self.server.clients.append(session)
        try:
            session.run()
        finally:
            self.server.clients.remove(session)
            log.info("CANopen hub: the client from %s is gone", self.address_string())


class Hub(RemoteServer):  # type: ignore[misc]
    """The hub: python-can-remote's server with :class:`Session` for each client."""

    def __init__(self, host: str, port: int, **config: Any) -> None:
        super().__init__(host=host, port=port, **config)
        self.RequestHandlerClass = _ClientHandler

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A client's connection that failed (it went, it sent no request in time): one line,
        not socketserver's traceback on stderr (296 of them when 300 half-open clients went)."""
        exc = sys.exc_info()[1]
        if isinstance(exc, OSError | TimeoutError | ValueError):  # (the client's doing)
            log.info("CANopen hub: the client from %s: %s: %s", client_address[0],
                     type(exc).__name__, exc)
        else:  # (ours)
            log.exception("CANopen hub: the client from %s", client_address[0])

    def end_sessions(self) -> None:
        """The hub closes: every client's session ends (its tasks, its bus, its socket)."""
        for session in list(self.clients):
            session.end()
