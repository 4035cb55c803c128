"""The Modbus RTU server: a serial line and an RTU-over-TCP listener, each a :class:`RtuLink`.

A link is the transport-free part of one line: its ``RtuFramer`` (the frame format, CRC and
all), the timer that tells it the line fell silent, its counters and its fault state.  What
it receives comes from the serial port's reader (:class:`SerialLine`, a file descriptor on
the event loop: no thread) or from a TCP connection (:class:`_TcpConnection`); what it
answers goes back the same way.  The rules are Modbus over Serial Line V1.02's:

- a frame is cut by its function code's length, as libmodbus does, and answered as soon as
  it is whole and its CRC is right; a frame whose code does not give its length ends at the
  line's silence of 3.5 characters (``silence_s``: 11 bits a character, 1.75 ms above
  19200 bit/s, 2.5.1.1); what was begun and is not whole at the silence is dropped and
  counted (``partial``); a bad CRC is dropped and counted (``crc_errors``) with the rest of
  its burst, and never answered (2.5.1.2);
- unit 0 is the broadcast: a write is applied and not answered, anything else is ignored
  (2.1); an address that is not ours is not answered (``other_units``);
- every other request is answered by the TCP server's ``RequestHandler``, so the exception
  codes, the door and the refusal table are the same as on TCP; its source is
  ``modbus-rtu <device>`` on a serial line and ``modbus-rtu <peer>`` over TCP;
- the plant's Modbus faults (docs/plant.md) apply: ``exception`` answers that code and
  executes nothing, ``delay`` answers late (what follows waits behind it), ``no_reply``
  silences the line until the fault table changes (a serial line has no connection to
  close; a master meets the silence with its timeout, as it would a dead device).

The serial port's settings (baud rate, parity, stop bits) are pyserial's to put on the
device; a pseudo-terminal takes them and ignores them, which is how the tests run without a
cable (``socat`` pty pairs, ``tests/integration/rtu/``).
"""

from __future__ import annotations

import asyncio
import errno
import logging
import os
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final, cast

from ncgate.config import ModbusConfig, Parity
from ncgate.gateway.errors import ListenError, listen_error
from ncgate.gateway.modbus.faults import FaultTable, ModbusFault, held_delay, row_status
from ncgate.gateway.modbus.framer import Request, RtuFramer, exception_pdu
from ncgate.gateway.modbus.map import ModbusMap
from ncgate.gateway.modbus.server import (
    ORPHANS_MAX,
    WRITES,
    RequestHandler,
    allow_list,
    allowed,
)
from ncgate.gateway.ratelimit import RateLimitedLog
from ncgate.gateway.wiring import Backend
from ncgate.inputs import Source, SourceKind

log = logging.getLogger("ncgate.modbus.rtu")

BROADCAST: Final = 0
# Frames one link answers in one loop turn before the others get theirs (an RTU-over-TCP
# client may send many at once; a serial line at 19,200 bit/s brings a few a second).
FRAMES_PER_TURN: Final = 16
# Bytes waiting in a TCP link's framer above which its reading pauses (and below which it
# resumes): a client that pipelines cannot make us buffer for it.
BACKLOG_HIGH: Final = 16 * 1024
BACKLOG_LOW: Final = 4 * 1024
WRITE_HIGH_WATER: Final = 64 * 1024
# How early a loop timer may come (uvloop rounds its delays to whole milliseconds).
EARLY_S: Final = 0.0005
REOPEN_S: Final = 1.0  # a serial port that went away is looked for again this often
# Answers a serial line's driver has not taken above which its requests are no longer read,
# and below which reading resumes (a master that never reads cannot make us buffer for it).
PENDING_HIGH: Final = 64 * 1024
PENDING_LOW: Final = 16 * 1024
READ_SIZE: Final = 512  # a serial line's read: two of the longest frames (19,200 bit/s: 0.27 s)
# The most a serial line keeps unsent: the high-water mark, then the answers to the frames
# read before reading stopped (at most a backlog of READ_SIZE and one more read, of
# requests of 8 bytes whose answers are at most 256).
PENDING_MOST: Final = PENDING_HIGH + 2 * READ_SIZE // 8 * 256
COUNTERS: Final = ("frames", "answered", "crc_errors", "partial", "exceptions", "broadcasts",
                   "other_units", "silenced")


def silence_s(baudrate: int, parity: Parity, stopbits: int) -> float:
    """The 3.5-character silence that ends an RTU frame (Modbus over Serial Line 2.5.1.1): a
    character is a start bit, 8 data bits, the parity bit if any and the stop bits; above
    19,200 bit/s the spec fixes it at 1.75 ms."""
    if baudrate > 19200:
        return 0.00175
    bits = 1 + 8 + (0 if parity is Parity.NONE else 1) + stopbits
    return 3.5 * bits / baudrate


@dataclass
class Counters:
    """What one port saw, since the gateway started: ``frames`` whole with a right CRC,
    ``answered``, ``crc_errors``, ``partial`` (begun and cut by a silence, or noise),
    ``exceptions`` answered, ``broadcasts`` applied, ``other_units`` (frames for another
    address, not answered) and ``silenced`` (requests a no_reply fault left unanswered)."""

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(COUNTERS, 0))

    def add(self, framer: RtuFramer, counts: dict[str, int] | None = None) -> None:
        """A framer's drops, when its link ends (a TCP connection closed), into these counts
        (or ``counts``)."""
        counts = self.counts if counts is None else counts
        counts["crc_errors"] += framer.crc_errors
        counts["partial"] += framer.partial

    def now(self, links: list[RtuLink]) -> dict[str, int]:
        """The counts with what the links still serving have dropped so far."""
        counts = dict(self.counts)
        for link in links:
            self.add(link.framer, counts)
        return counts


class RtuLink:
    """One RTU line, without its transport: ``received`` takes what came, ``write`` (given)
    sends an answer, ``pause``/``resume`` (given, optional) hold the transport's reading
    while a backlog waits.  Requests are answered in order; a delay fault holds the rest of
    the line behind it."""

    def __init__(self, server: RtuServer, source: Source, write: Callable[[bytes], None],
                 silence: float, counters: Counters, *, reading: Callable[[bool], None]
                 | None = None, backlog: tuple[int, int] = (BACKLOG_HIGH, BACKLOG_LOW)
                 ) -> None:
        self.server = server
        self.source = source
        self.write = write
        self.silence = silence
        self.counters = counters
        self.reading = reading
        self.backlog_high, self.backlog_low = backlog
        self.framer = RtuFramer()
        self.loop = asyncio.get_running_loop()
        # The line's clock is the monotonic clock, not the loop's: uvloop's counts whole
        # milliseconds, cached at each loop pass, and its timers may come half a millisecond
        # early -- a silence timer armed again for that half came a millisecond later.
        self.last_byte = time.monotonic()
        self.gap_timer: asyncio.TimerHandle | None = None
        self.turn: asyncio.Handle | None = None
        self.held: tuple[Request, asyncio.Handle] | None = None  # a delay fault's
        self.orphan = False  # closed with a held request, which acts at its time
        self.held_since = 0.0  # when the held request came
        self.silent = False  # a no_reply fault caught a request: nothing is answered
        self.backlogged = False
        self.closed = False

    def received(self, data: bytes) -> None:
        self.last_byte = time.monotonic()
        framer = self.framer
        if framer.idle and self.turn is None and self.held is None:
            # The common case, one whole frame in one read: answered without the buffer's
            # bookkeeping (a bad CRC is not whole: fed below, dropped and counted there).
            request = framer.whole(data)
            if request is not None:
                self._serve(request)
                return
        framer.feed(data)
        if self.turn is None:
            self._process()
        self._watch_silence()

    def _watch_silence(self) -> None:
        """Arm the silence timer while the framer has something the silence decides: a
        frame begun, or a burst being dropped."""
        if self.gap_timer is None and not self.framer.idle:
            self._arm_silence()

    def _arm_silence(self) -> None:
        delay = self.last_byte + self.silence - time.monotonic()
        self.gap_timer = self.loop.call_later(max(0.0, delay), self._silence)

    def _silence(self) -> None:
        self.gap_timer = None
        if self.closed:
            return
        # Bytes came since it was armed: the silence is later.  (A timer up to EARLY_S
        # early is the silence: a pause past 1.5 characters already breaks a frame,
        # Modbus over Serial Line 2.5.1.1.)
        if time.monotonic() < self.last_byte + self.silence - EARLY_S:
            self._arm_silence()
            return
        if self.turn is not None or self.held is not None:
            return  # whole frames wait their turn: the silence counts after them
        request = self.framer.gap()
        if request is not None:
            self._serve(request)

    def _process(self) -> None:
        """Answer the whole frames buffered, in order, at most FRAMES_PER_TURN in one loop
        turn; a delayed request holds the rest until it is answered."""
        self.turn = None
        if self.closed:
            return
        framer = self.framer
        taken = 0
        while self.held is None:
            if taken >= FRAMES_PER_TURN:
                self.turn = self.loop.call_soon(self._process)
                break
            request = framer.next_request()
            if request is None:
                break
            taken += 1
            self._serve(request)
        if self.reading is not None:
            backlogged = framer.buffered > (self.backlog_low if self.backlogged
                                            else self.backlog_high)
            if backlogged != self.backlogged:
                self.backlogged = backlogged
                self.reading(not backlogged)
        if self.turn is None and self.held is None:
            self._watch_silence()

    def _serve(self, request: Request) -> None:
        unit, pdu, _ = request
        counts = self.counters.counts
        counts["frames"] += 1
        server = self.server
        if unit != BROADCAST and unit not in server.unit_ids:
            counts["other_units"] += 1  # another slave's: not ours to answer
            return
        if self.silent:
            counts["silenced"] += 1
            server._faults.counts["silenced"] += 1  # (fault_counts, as TCP's say it)
            return
        table = server.fault_table
        fault = table.match(unit, pdu) if table is not None else None
        if fault is not None:
            if fault.kind == "exception":  # not executed
                self._answer(request, exception_pdu(pdu[0], fault.code))
                return
            if fault.kind == "no_reply":  # (counted as no_reply; those after: silenced)
                self.silent = True
                server.chatter.note(f"{self.source}: no answers any more (a no_reply fault)")
                return
            timer = self.loop.call_later(fault.ms / 1000, self._release)
            self.held = (request, timer)
            self.held_since = time.monotonic()
            return
        self._execute(request)

    def _execute(self, request: Request, answered: bool = True) -> None:
        """Execute and answer ``request`` (``answered`` False: its client is gone -- a write
        acts, unanswered; a read is nothing)."""
        unit, pdu, _ = request
        if unit == BROADCAST:
            if pdu[0] in WRITES:  # applied, never answered (2.1); a broadcast read is nothing
                answer = self.server.handler.handle(self.server.any_unit, pdu, self.source)
                if not answer[0] & 0x80:  # refused (read-only, a bad value): not applied
                    self.counters.counts["broadcasts"] += 1
            return
        if not answered:
            if pdu[0] in WRITES:
                self.server.handler.handle(unit, pdu, self.source)
            return
        self._answer(request, self.server.handler.handle(unit, pdu, self.source))

    def _answer(self, request: Request, answer: bytes) -> None:
        if request[0] == BROADCAST:
            return
        counts = self.counters.counts
        counts["answered"] += 1
        if answer[0] & 0x80:
            counts["exceptions"] += 1
        self.write(self.framer.encode(request, answer))

    def _release(self) -> None:
        """A delayed request's time has come: execute and answer it, then the rest (its
        client gone: it acts, unanswered)."""
        if self.held is None or (self.closed and not self.orphan):
            return
        request, _ = self.held
        self.held = None
        if self.orphan:
            self.orphan = False
            self._execute(request, answered=False)
            return
        self._execute(request)
        self._process()

    def faults_changed(self, table: FaultTable | None) -> None:
        """A new fault table: a silenced line answers again (the next request meets the new
        table), and a request a delay holds that no delay of it matches any more is answered
        now."""
        self.silent = False
        if self.held is None:
            return
        request, timer = self.held
        wait = self.held_since + held_delay(table, request[0], request[1]) - time.monotonic()
        timer.cancel()  # (at the arrival plus the longest delay that matches now)
        self.held = (request, self.loop.call_later(wait, self._release) if wait > 0
                     else self.loop.call_soon(self._release))

    def close(self, gone: bool = False) -> None:
        """``gone``: the client left (not the gateway stopping): a write a delay holds acts
        at its time all the same (docs/plant.md); what was not taken yet goes with it."""
        self.closed = True
        self.orphan = gone and self.held is not None
        for timer in (self.gap_timer, self.turn,
                      self.held[1] if self.held and not self.orphan else None):
            if timer is not None:
                timer.cancel()
        self.gap_timer = None
        self.turn = None
        if not self.orphan:
            self.held = None


def _errno_of(exc: BaseException) -> int | None:
    """A termios.error's errno: its first argument (it is no OSError)."""
    number = exc.args[0] if exc.args else None
    return number if isinstance(number, int) else None


def is_pty(device: str) -> bool:
    """``device`` (or what its link names) is a Unix 98 pseudo-terminal's slave (Linux:
    majors 136-143, /dev/pts/N)."""
    try:
        rdev = os.stat(device).st_rdev
    except OSError:
        return False
    return 136 <= os.major(rdev) <= 143


class SerialLine:
    """A serial port on the event loop: pyserial opens and configures the device, then its
    file descriptor is read by the loop (no thread) and written without blocking (what the
    driver does not take at once goes when it can).  A port that goes away (a USB adapter
    pulled, the other end of a pty closed) is logged once and looked for again every
    REOPEN_S."""

    def __init__(self, server: RtuServer) -> None:
        self.server = server
        rtu = server.config.rtu
        assert rtu.port is not None
        self.device = rtu.port
        self.counters = Counters()
        self.silence = silence_s(rtu.baudrate, rtu.parity, rtu.stopbits)
        self.serial: Any = None
        self.link: RtuLink | None = None
        self.pending = bytearray()  # answers the driver has not taken yet
        self.paused = False  # reading stopped: too many answers wait (PENDING_HIGH)
        self.backlogged = False  # reading stopped: frames wait their turns
        self.error: str | None = None
        self.reopen: asyncio.TimerHandle | None = None
        self._said_pty = False  # "a pseudo-terminal that refuses parity": said once
        self._said_reopen = False  # an unexpected error reopening: logged once
        self.no_parity = False  # a pty that refuses parity was opened without
        # Set each time the port opens or goes away, and its reading stops or resumes.
        self.changed = asyncio.Event()

    def open(self) -> None:
        """Open the device (ListenError naming modbus.rtu.port if it cannot be)."""
        import termios  # (POSIX, as the loop's reading of the device's descriptor)

        import serial  # pyserial: imported only when a serial line is served

        rtu = self.server.config.rtu
        parity = {Parity.EVEN: serial.PARITY_EVEN, Parity.ODD: serial.PARITY_ODD,
                  Parity.NONE: serial.PARITY_NONE}[rtu.parity]

        def opened(parity: str) -> Any:
            return serial.Serial(self.device, baudrate=rtu.baudrate, bytesize=rtu.bytesize,
                                 parity=parity, stopbits=rtu.stopbits, timeout=0,
                                 exclusive=True)

        no_parity = False
        try:
            try:
                port = opened(parity)
            except termios.error as exc:
                # The device refused the line's settings (tcsetattr).  Linux 6.x refuses
                # parity without input parity checking on a pseudo-terminal once it had
                # parity set (pyserial sets it without): a socat pair served once was
                # refused by the next `ncgate run`.  A pty carries no parity bit; it is
                # opened without (the inter-frame silence still counts the configured one).
                if not (_errno_of(exc) == errno.EINVAL and parity != serial.PARITY_NONE
                        and is_pty(self.device)):
                    raise
                port = opened(serial.PARITY_NONE)
                no_parity = True
                if not self._said_pty:
                    self._said_pty = True
                    log.info("modbus-rtu %s: a pseudo-terminal that refuses parity %s: "
                             "opened without (a pty carries no parity bit)", self.device,
                             parity)
        except termios.error as exc:
            number = _errno_of(exc)
            raise ListenError(number or errno.EINVAL, f"modbus.rtu.port: cannot open "
                              f"{self.device}: it refuses the line's settings ("
                              f"{rtu.baudrate} {rtu.bytesize}{parity}{rtu.stopbits}): "
                              f"{os.strerror(number) if number else exc}") from None
        except (serial.SerialException, OSError, ValueError) as exc:
            number = getattr(exc, "errno", None)
            if number in (errno.EAGAIN, errno.EWOULDBLOCK):  # pyserial's exclusive lock
                raise ListenError(number, f"modbus.rtu.port: cannot open {self.device}: "
                                  "another program has it open") from None
            if isinstance(number, int) and number:
                raise ListenError(number, f"modbus.rtu.port: cannot open {self.device}: "
                                  f"{os.strerror(number)}") from None
            raise ListenError(f"modbus.rtu.port: cannot open {self.device}: {exc}") from None
        self.serial = port
        self.no_parity = no_parity  # (the status says so)
        self.error = None
        fd = port.fileno()
        loop = asyncio.get_running_loop()
        self.link = RtuLink(self.server, Source(SourceKind.MODBUS_RTU, self.device),
                            self._write, self.silence, self.counters, reading=self._backlog,
                            backlog=(READ_SIZE, READ_SIZE // 2))
        self.backlogged = False
        loop.add_reader(fd, self._readable)
        self.changed.set()

    @property
    def is_open(self) -> bool:
        return self.serial is not None

    def _readable(self) -> None:
        try:
            # A few frames at a time (READ_SIZE): what one read brings is answered even
            # while the line does not take the answers, so it bounds what may wait.
            data = os.read(self.serial.fileno(), READ_SIZE)
        except BlockingIOError:
            return
        except OSError as exc:
            self._lost(exc.strerror or str(exc))
            return
        if not data:
            self._lost("end of file")
            return
        assert self.link is not None
        self.link.received(data)

    def _write(self, data: bytes) -> None:
        if self.serial is None:
            return
        if not self.pending:
            try:
                sent = os.write(self.serial.fileno(), data)
            except BlockingIOError:
                sent = 0
            except OSError as exc:
                self._lost(exc.strerror or str(exc))
                return
            if sent == len(data):
                return
            data = data[sent:]
            asyncio.get_running_loop().add_writer(self.serial.fileno(), self._writable)
        self.pending += data
        if len(self.pending) > PENDING_HIGH and not self.paused:
            # The line does not take our answers (a master that stopped reading, a pty
            # nobody reads): no more requests are read until they have gone, so what waits
            # stays bounded; the master's requests wait in the driver meanwhile.
            self.paused = True
            self._reading()
            self.changed.set()

    def _backlog(self, on: bool) -> None:
        """The link's frames wait their turns (more than READ_SIZE of them): read no more
        until they are answered, so that what is read is what the answers may bound."""
        self.backlogged = not on
        self._reading()

    def _reading(self) -> None:
        if self.serial is None:
            return
        loop, fd = asyncio.get_running_loop(), self.serial.fileno()
        if self.paused or self.backlogged:
            loop.remove_reader(fd)
        else:
            loop.add_reader(fd, self._readable)

    def _writable(self) -> None:
        try:
            sent = os.write(self.serial.fileno(), self.pending)
        except BlockingIOError:
            return
        except OSError as exc:
            self._lost(exc.strerror or str(exc))
            return
        del self.pending[:sent]
        loop = asyncio.get_running_loop()
        if self.paused and len(self.pending) < PENDING_LOW:
            self.paused = False
            self._reading()
            self.changed.set()
        if not self.pending:
            loop.remove_writer(self.serial.fileno())

    def _lost(self, why: str) -> None:
        log.warning("modbus-rtu %s: the port went away (%s); looking for it again every "
                    "%g s", self.device, why, REOPEN_S)
        self.error = why
        self._close_port()
        self.changed.set()
        self.reopen = asyncio.get_running_loop().call_later(REOPEN_S, self._try_reopen)

    def _try_reopen(self) -> None:
        self.reopen = None
        try:
            self.open()
        except Exception as exc:  # ListenError, or a library's surprise: it must not end
            # the looking for the port (a termios.error did, and the line stayed closed)
            why = str(exc) if isinstance(exc, ListenError) else f"{type(exc).__name__}: {exc}"
            if why != self.error:  # (the status says why it is closed now, not at first)
                self.error = why
                self.changed.set()
            if not isinstance(exc, ListenError) and not self._said_reopen:
                self._said_reopen = True
                log.exception("modbus-rtu %s: reopening failed; trying again every %g s",
                              self.device, REOPEN_S)
            self.reopen = asyncio.get_running_loop().call_later(REOPEN_S, self._try_reopen)
            return
        self._said_reopen = False
        log.info("modbus-rtu %s: open again", self.device)

    def _close_port(self) -> None:
        if self.link is not None:
            self.counters.add(self.link.framer)
            self.link.close()
            self.link = None
        if self.serial is not None:
            loop = asyncio.get_running_loop()
            fd = self.serial.fileno()
            loop.remove_reader(fd)
            loop.remove_writer(fd)
            self.pending.clear()
            self.paused = False
            self.serial.close()
            self.serial = None

    def close(self) -> None:
        if self.reopen is not None:
            self.reopen.cancel()
            self.reopen = None
        self._close_port()

    def status(self) -> dict[str, Any]:
        rtu = self.server.config.rtu
        counts = self.counters.now([self.link] if self.link is not None else [])
        return {"port": self.device, "open": self.is_open, "error": self.error,
                "unsent": len(self.pending), "reading": self.is_open and not self.paused,
                "settings": f"{rtu.baudrate} {rtu.bytesize}{rtu.parity.value}{rtu.stopbits}"
                + (" (a pty: opened without parity)" if self.no_parity else ""),
                **counts}


class _TcpConnection(asyncio.Protocol):
    """One RTU-over-TCP client: a link whose bytes come from and go to its socket.  The
    Modbus TCP server's guards hold here too: ``modbus.allow``, at most ``max_clients``
    connections (a newcomer past it is refused: a serial device server keeps its one
    connection, there is no idle one to make room), a connection silent ``idle_timeout_s``
    is closed, and reading pauses while the client does not read its answers or a backlog
    of frames waits."""

    def __init__(self, listener: RtuTcpListener) -> None:
        self.listener = listener
        self.transport: asyncio.Transport | None = None
        self.link: RtuLink | None = None
        self.loop = asyncio.get_running_loop()
        self.last_activity = self.loop.time()
        self.timer: asyncio.TimerHandle | None = None
        self.write_paused = False  # the client does not read its answers
        self.backlogged = False  # frames wait their turn

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)
        peer = transport.get_extra_info("peername") or ("?", 0)
        listener, server = self.listener, self.listener.server
        who = f"modbus-rtu {peer[0]}:{peer[1]}"
        if not server.allowed(str(peer[0])):
            server.refusals.note(f"{who} refused: not in the allow-list")
            self.transport.abort()
            return
        if len(listener.connections) >= server.config.max_clients:
            server.refusals.note(f"{who} refused: {len(listener.connections)} RTU-over-TCP "
                                 "clients already (max_clients)")
            self.transport.abort()
            return
        self.transport.set_write_buffer_limits(high=WRITE_HIGH_WATER)
        self.link = RtuLink(server, Source(SourceKind.MODBUS_RTU, f"{peer[0]}:{peer[1]}"),
                            self.transport.write, listener.silence, listener.counters,
                            reading=self._backlog)
        listener.connections.add(self)
        server.chatter.note(f"{self.link.source} connected (RTU over TCP)")
        self._arm(server.config.idle_timeout_s)

    def _arm(self, delay: float) -> None:
        self.timer = self.loop.call_later(delay, self._check_idle)

    def _check_idle(self) -> None:
        self.timer = None
        if self.transport is None or self.transport.is_closing():
            return
        idle = self.listener.server.config.idle_timeout_s
        left = self.last_activity + idle - self.loop.time()
        if left <= 0:
            self.listener.server.chatter.note(f"{self.link.source if self.link else '?'} "
                                              f"closed: idle for {idle:g} s")
            self.transport.abort()
            return
        self._arm(left)

    def _backlog(self, on: bool) -> None:
        self.backlogged = not on
        self._reading()

    def _reading(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            if self.write_paused or self.backlogged:
                self.transport.pause_reading()
            else:
                self.transport.resume_reading()

    def pause_writing(self) -> None:
        self.write_paused = True
        self._reading()

    def resume_writing(self) -> None:
        self.write_paused = False
        self._reading()

    def data_received(self, data: bytes) -> None:
        self.last_activity = self.loop.time()
        assert self.link is not None
        self.link.received(data)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        listener = self.listener
        if self not in listener.connections:
            return  # refused at once: it never counted
        listener.connections.discard(self)
        if self.link is not None:
            if self.link.framer.buffered:  # a frame begun when the client went away
                self.link.framer.partial += 1
            listener.counters.add(self.link.framer)
            listener.server.chatter.note(f"{self.link.source} disconnected")
            gone = not listener.closing and len(listener.orphans) < ORPHANS_MAX
            self.link.close(gone=gone)
            if self.link.orphan:
                listener.orphans.add(self.link)
        if not listener.connections:
            listener.all_closed.set()

    def close(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.abort()


class RtuTcpListener:
    """RTU frames on a TCP listener (``[modbus.rtu_tcp]``)."""

    def __init__(self, server: RtuServer) -> None:
        self.server = server
        self.counters = Counters()
        self.silence = server.config.rtu_tcp.gap_ms / 1000
        self.connections: set[_TcpConnection] = set()
        self.all_closed = asyncio.Event()
        self.address: tuple[str, int] | None = None
        self._server: asyncio.Server | None = None
        self.closing = False
        # Links whose client left while a delay held a write, which acts at its time (each
        # kept by its timer alone: gone from here once it fired).
        self.orphans: weakref.WeakSet[RtuLink] = weakref.WeakSet()

    async def start(self) -> None:
        config = self.server.config.rtu_tcp
        assert config.port is not None
        loop = asyncio.get_running_loop()
        try:
            self._server = await loop.create_server(lambda: _TcpConnection(self), config.host,
                                                    config.port, reuse_address=True)
        except OSError as exc:
            raise listen_error(exc, "modbus.rtu_tcp.port", config.host, config.port) from None
        host, port = self._server.sockets[0].getsockname()[:2]
        self.address = (host, port)

    def links(self) -> list[RtuLink]:
        return [c.link for c in self.connections if c.link is not None]

    async def close(self) -> None:
        if self._server is None:
            return
        self.closing = True
        for link in list(self.orphans):  # the gateway stops: nothing acts after it
            link.orphan = False
            link.close()
        self._server.close()
        if self.connections:
            self.all_closed.clear()
            for connection in list(self.connections):
                connection.close()
            await self.all_closed.wait()
        await self._server.wait_closed()
        self._server = None

    def status(self) -> dict[str, Any]:
        counts = self.counters.now(self.links())
        return {"port": "tcp {}:{}".format(*self.address) if self.address else None,
                "address": list(self.address) if self.address else None,
                "clients": sorted(str(link.source.detail) for link in self.links()),
                **counts}


class RtuServer:
    """Modbus RTU on ``[modbus.rtu]``'s serial port and ``[modbus.rtu_tcp]``'s listener,
    whichever are set; the map and the door of Modbus TCP."""

    def __init__(self, config: ModbusConfig, mmap: ModbusMap, backend: Backend) -> None:
        self.config = config
        rtu = config.rtu
        units = config.rtu_unit_ids
        assert units, "the config's checks refuse an RTU with no serial address"
        self.unit_ids = frozenset(units)
        self.any_unit = min(units)  # what a broadcast is handled as
        self.handler = RequestHandler(mmap, backend, self.unit_ids, strict_unit_id=True)
        self.chatter = RateLimitedLog(log, level=logging.INFO, burst=10)
        self.refusals = RateLimitedLog(log)
        self._allow = allow_list(config)
        self._faults = FaultTable()
        self.fault_table: FaultTable | None = None
        self.serial = SerialLine(self) if rtu.port is not None else None
        self.tcp = RtuTcpListener(self) if config.rtu_tcp.port is not None else None

    async def start(self) -> None:
        if self.serial is not None:
            self.serial.open()
        if self.tcp is not None:
            try:
                await self.tcp.start()
            except BaseException:
                if self.serial is not None:
                    self.serial.close()
                raise

    async def close(self) -> None:
        self.chatter.flush()
        self.refusals.flush()
        if self.serial is not None:
            self.serial.close()
        if self.tcp is not None:
            await self.tcp.close()

    def allowed(self, host: str) -> bool:
        """``modbus.allow``: an RTU-over-TCP client's address is checked as a Modbus TCP
        client's is."""
        return allowed(self._allow, host)

    def links(self) -> list[RtuLink]:
        out = [self.serial.link] if self.serial is not None and self.serial.link else []
        return out + (self.tcp.links() if self.tcp is not None else [])

    def set_faults(self, faults: list[ModbusFault]) -> None:
        """The plant's Modbus faults in force (``ModbusServer.set_faults``'s rows).  The
        same table again (another fieldbus's fault changed) changes nothing: a silenced line
        stays silent until the Modbus faults change."""
        if tuple(faults) == self._faults.rows:
            return
        self._faults.set(faults)
        self.fault_table = self._faults if self._faults.rows else None
        orphans = list(self.tcp.orphans) if self.tcp is not None else []
        for link in [*self.links(), *orphans]:  # (a clear reaches a left client's write too)
            link.faults_changed(self.fault_table)

    @property
    def faults(self) -> tuple[ModbusFault, ...]:
        return self._faults.rows

    def status(self) -> dict[str, Any]:
        ports = []
        if self.serial is not None:
            ports.append(self.serial.status())
        if self.tcp is not None:
            ports.append(self.tcp.status())
        totals = {name: sum(p[name] for p in ports) for name in COUNTERS}
        return {**totals, "unit_ids": sorted(self.unit_ids), "ports": ports,
                "faults": [row_status(f) for f in self.faults],
                "fault_counts": dict(self._faults.counts)}
