"""The PLC scan: compiled Structured Text run cyclically against the I/O image.

One scan (IEC 61131-3's cyclic task):
1. inputs: a consistent copy of the image (SA, K, SYVARs) and of the NC's status;
2. the programs, in the configured order, on that copy;
3. outputs: what the programs changed in the copy is written to the image as **one atomic
   write by writer ``plc``** (spec 3.1) -- waits it satisfies see ``plc`` as their writer;
   then the NC commands whose output rose (NC.START, NC.HOLD, NC.RESET) and the queued
   NC.SEND calls.
Fieldbus writes between two scans apply to the image at once and are read by the next scan.

A runtime error (division by zero, an index out of range, the iteration guard) puts the PLC
in FAULT: the scan's outputs are dropped, the image keeps what the last good scan wrote,
no further scan runs, and the NC is told (an alarm with the statement's file:line:col).
:meth:`PlcRuntime.restart` (the NC's reset) starts it again with its initial values and
the RETAIN ones.

When a scan runs is the caller's business (``ncgate.gateway.plc`` puts it on the engine's
clock).  Stdlib only; the NC is reached through :class:`NcPort`.
"""

from __future__ import annotations

import enum
import functools
import logging
import math
import sqlite3
import struct
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from ncgate.commands import BY_NAME, plc_edges, plc_levels
from ncgate.errors import NcgateError
from ncgate.plc.image import IOImage, PlcError
from ncgate.plc.retain import RetainStore
from ncgate.plc.st.intrinsics import NC_OUTPUTS, NC_PROCESS_OUTPUTS
from ncgate.plc.st.logic import Logic, ProgramVar
from ncgate.plc.st.runtime import (
    REAL_OVERFLOW,
    REAL_OVERFLOW_MESSAGE,
    IterationGuard,
    PlcFault,
    to_real,
)
from ncgate.plc.st.stdlib import RUNNING, Timer
from ncgate.plc.st.types import ArrayOf, EnumOf, FbOf, limits

log = logging.getLogger("ncgate.plc")

# See compiler.NC_PROCESS: state, N, line, waiting, alarm, alarm code, idle, held, then the
# auxiliary functions' value and strobe for M, S, T, H.
NcSnapshot = tuple[int, ...]
# The NC outputs' slots (compiler.NC_OUTPUTS) and the command words they give, from the command
# table (ncgate.commands): (slot, word) acting on a rising edge; (slot, word of TRUE, word of
# FALSE) acting as a level changes; HOLD_LEVEL, which gives a feed hold as it rises.
_EDGES = tuple((NC_OUTPUTS[name], word) for name, word in plc_edges())
_LEVELS = tuple((NC_OUTPUTS[name], on, off) for name, on, off in plc_levels())
_HOLD_LEVEL = NC_OUTPUTS["HOLD_LEVEL"]
_FEED_HOLD = BY_NAME["feed_hold"].word
# NC.P[k]'s: its commands on a rising edge, and its auxiliary functions' acknowledges (levels).
_PROCESS_EDGES = tuple((NC_PROCESS_OUTPUTS[name], word) for name, word in plc_edges()
                       if name in NC_PROCESS_OUTPUTS)
_AUX_ACKS = tuple((NC_PROCESS_OUTPUTS[f"{letter}ACK"], letter) for letter in "MSTH")


class PlcState(enum.IntEnum):
    STOPPED = 0
    RUNNING = 1
    FAULT = 2


class NcPort(Protocol):
    """What the scan reads of the NC and how it acts on it (the gateway wires the engine)."""

    def snapshot(self) -> list[NcSnapshot]: ...

    def events(self) -> int: ...

    def last_snd(self) -> tuple[int, int, int]: ...  # sender, target, sequence

    # A command word (ncgate.commands: those an NC output gives), of the cell or of
    # ``process``; ``where``: FILE:LINE of the logic that gave it.  InputRefused when it
    # cannot go (said as a hazard).
    def command(self, word: int, where: str, process: int | None = None) -> None: ...

    # The feed override in percent, of the cell or of ``process``.
    def override(self, feed: int, where: str, process: int | None = None) -> None: ...

    # InputRefused when it cannot go (said as a hazard)
    def send(self, sender: int, target: int, where: str) -> None: ...

    # NC.P[k].MACK (SACK, TACK, HACK): the acknowledge of process k's auxiliary functions
    # of ``letter`` set to ``value``; InputRefused when it cannot go (said as a hazard).
    def aux_ack(self, process: int, letter: str, value: bool, where: str) -> None: ...

    def fault(self, message: str) -> None: ...

    def hazard(self, message: str) -> None: ...



class PlcPathError(PlcError, KeyError):
    """A PLC variable path that names nothing (:meth:`PlcRuntime.read`)."""

    def __str__(self) -> str:  # a KeyError would quote its message
        return str(self.args[0]) if self.args else ""


GUARD_CHUNK = 1024  # loop iterations between two looks at the limit and the watchdog
# At most this many scans between two reads of a state that moved at every read (PlcRuntime's
# still scans): logic that never stands still pays a read a 16th of its scans (bench/plc.py's
# typed cell: 8 us a read, 38 us a scan).
STILL_PAUSE_MAX = 16


class WatchdogExpired(IterationGuard):
    """The scan ran longer than ``plc.watchdog_ms``: raised inside the logic, so that the
    fault names the line it was executing."""

@dataclass
class PlcStatus:
    state: PlcState = PlcState.STOPPED
    scans: int = 0
    last_scan_us: int = 0
    max_scan_us: int = 0
    overruns: int = 0
    fault: PlcFault | None = None
    # How late the scans began against their due time (on the wall clock, in `run`).
    last_lateness_us: int = 0
    max_lateness_us: int = 0


class PlcRuntime:
    """Compiled logic + its program instances + the scan."""

    def __init__(self, logic: Logic, image: IOImage, nc: NcPort, order: Sequence[str],
                 loop_limit: int = 100_000, retain: RetainStore | None = None,
                 watchdog_ms: int = 0, writer: str = "plc") -> None:
        """``watchdog_ms``: a scan running longer (wall clock) is stopped: FAULT (0: off).
        ``writer``: whom its image writes are attributed to (``plant``: the plant's logic)."""
        self.writer = writer
        self.logic = logic
        self.image = image
        self.nc = nc
        self.order = [name.upper() for name in order]
        self.loop_limit = loop_limit
        self.watchdog_ms = watchdog_ms
        self._deadline_ns = 0  # this scan's watchdog deadline (perf_counter_ns; 0: none)
        # The wall clock the scan and its watchdog read (ns): an attribute, so that a test
        # can make a scan take as long as it needs to (CONTRIBUTING.md: inject a fault).
        self.clock_ns: Callable[[], int] = time.perf_counter_ns
        self._granted = 0  # loop iterations handed out to this scan so far
        self.retain = retain
        self.status = PlcStatus()
        self._sa = bytearray(image.sa)
        self._k = bytearray(image.k)
        self._sy = list(image.syvar)
        self._sends: list[tuple[int, int, str]] = []
        self._bind(logic.namespace)
        self._last_outputs = [False] * len(self._outputs)
        self._last_process_outputs = [[False] * len(o) for o in self._process_outputs]
        self._last_overrides = [100]
        self._last_process_overrides = [100] * len(self._process_overrides)
        self._retained = _retained_of(logic)
        self._saved: dict[str, tuple[str, Any]] | None = None
        self._save_failed = False
        self.programs: dict[str, Any] = {}
        self._runs: list[Any] = []
        # Called after every scan and on a fault (a watch waits on these, never polls).
        self.scan_listeners: list[Callable[[], None]] = []
        # Forcing: the forced variables by path, as given and as stored; told of
        # each value of the logic's that a force overrode (path, the value the logic left).
        self.forced: dict[str, tuple[str, Any]] = {}
        self._forced_types: dict[str, Any] = {}  # each force's type when it was set
        self.on_overridden: Callable[[str, Any], None] | None = None
        # A still scan (see scan): the programs' state as the last scan left it (None: not
        # known), whether that scan changed nothing, and what it read (the image's
        # generation when it began, the NC's status).
        self._state_of: Callable[[], Any] | None = None
        self._state: Any = None
        self._still = False
        self._still_generation = -1
        # The image's generation as far as the logic reads and writes it (a write the logic
        # neither reads nor would overwrite cannot change what a scan does).
        self._watch = image.watch(logic.image_keys, logic.image_areas)
        self._still_nc: tuple[list[NcSnapshot], int, tuple[int, int, int]] | None = None
        self._pause = 0  # scans before the state is read again (its last reads all moved)
        self._misses = 0  # reads in a row that found the state moved, or that went unused
        self._judged_at = -1  # status.scans after the last scan judged still
        # A timed still scan (``timed``: sim's leaps, see _judge_timed): how the state but
        # the timers' ETs is read (None: it cannot be, or not tried yet), that state as the
        # last scan left it (None: not known), every timer instance, and, after such a scan,
        # the time (ms) before which the scans that read the same do the same nothing, and
        # the timers that run until then.
        self.timed = False
        # With ``timed``: the time (ms) of the last scan a leap in progress has passed (the
        # scan driver's), for the ETs when something else ends the timed still state.
        self.leap_passed: Callable[[], int | None] | None = None
        self._timeless_of: Callable[[], Any] | None = None
        self._timeless_tried = False
        self._timeless: Any = None
        self._timers: list[Timer] = []
        self._until: int | None = None
        self._running: list[Timer] = []
        self.start()

    # -- life cycle ------------------------------------------------------------------------------

    def start(self) -> None:
        """(Re)create the program instances: initial values, then the RETAIN ones."""
        self.logic.reset_globals()
        self.programs = {key: self.logic.new_program(key) for key in self.logic.programs}
        self._runs = [self.programs[key] for key in self.order]
        self._outputs[:] = [False] * len(self._outputs)
        self._last_outputs = [False] * len(self._outputs)
        for outputs in self._process_outputs:
            outputs[:] = [False] * len(outputs)
        self._last_process_outputs = [[False] * len(o) for o in self._process_outputs]
        self._overrides[:] = [100]
        self._last_overrides = [100]
        self._process_overrides[:] = [100] * len(self._process_overrides)
        self._last_process_overrides = [100] * len(self._process_overrides)
        self._sends.clear()
        if self.retain is not None:
            self._apply_retained(self.retain.load())
        self._read_state()
        self.status.state = PlcState.RUNNING
        self.status.fault = None

    def restart(self) -> None:
        """The NC's reset: a PLC in FAULT starts again (a running one is left alone)."""
        if self.status.state is PlcState.FAULT:
            log.info("PLC restarted after its fault")
            self.start()

    def stop(self) -> None:
        self.status.state = PlcState.STOPPED

    def _read_state(self) -> None:
        """How the programs' state is read (after a start, a reload), and read it now."""
        logic = self.logic
        globals_state = logic.globals_state()
        programs = [(logic.program_state(key), self.programs[key]) for key in self.order]
        self._still = False
        self._pause = self._misses = 0
        self._timeless_of, self._timeless, self._until = None, None, None
        self._timeless_tried = False
        if globals_state is None or any(state is None for state, _ in programs):
            self._state_of = self._state = None  # (a member of a type it cannot read)
            return
        ns = self._ns
        pairs = [(state, program) for state, program in programs if state is not None]
        if len(pairs) == 1 and not logic.globals:  # the common case, read in one call
            only, program = pairs[0]
            self._state_of = functools.partial(only, program)
        else:

            def read() -> Any:
                return globals_state(ns["_G"]), [state(program) for state, program in pairs]

            self._state_of = read
        self._state = self._state_of()

    def _changed_state(self) -> None:
        """Something other than a scan changed the programs' state (a force)."""
        self._leave_timed()
        self._still = False
        self._state = self._timeless = None

    def _leave_timed(self) -> None:
        """The timed still state ends other than by a scan (a force, a reload, a restart):
        the running timers' ETs first as the scans a leap passed left them."""
        if self._until is not None and self.leap_passed is not None:
            passed = self.leap_passed()
            if passed is not None:
                self.catch_up(passed)
        self._until = None

    def _judge(self, quiet: bool, generation: int,
               nc_read: tuple[list[NcSnapshot], int, tuple[int, int, int]] | None) -> None:
        """Whether the scan just run was still: ``quiet`` (it wrote nothing, gave the NC
        nothing, nothing is forced), and the programs' state is as it began.  The state is
        read only after a quiet scan; logic whose state moves on every scan (a counter, a
        running timer) is read less and less often (every 2nd, 4th, .. STILL_PAUSE_MAX-th
        scan), so that it pays a read now and then, not every scan."""
        assert self._state_of is not None
        self._still = False
        self._timeless = None
        if not quiet or self._pause:
            self._pause = max(0, self._pause - 1)
            self._state = None  # (unknown: the next quiet scan reads it, the one after tells)
            return
        state = self._state_of()
        if self._state is not None:
            if state == self._state:  # (misses count on: only a skip shows it was worth it)
                self._still = True
                self._still_generation, self._still_nc = generation, nc_read
            else:
                self._missed()
        self._state = state

    def _missed(self) -> None:
        """A read of the state found it moved, or it was for nothing: read it less and less
        often while that goes on (every 2nd, 4th, .. STILL_PAUSE_MAX-th scan)."""
        self._pause = min(STILL_PAUSE_MAX, 1 << self._misses)
        self._misses += 1

    def _judge_timed(self, running: int, now_ms: int, generation: int,
                     nc_read: tuple[list[NcSnapshot], int, tuple[int, int, int]] | None
                     ) -> None:
        """Whether the scan just run, quiet but for ``running`` calls of timers whose Q waits
        for the time, was *timed still*: the programs' state is as it began but for the
        timers' ETs.  Then, as long as what it reads stays the same, every scan before the
        first of those calls' dues does the same nothing (and moves the ETs on): the logic
        reads no ET (``Logic.reads_et``), so it sees the time only as a running timer's Q,
        FALSE until its due, and a timer recomputes its ET from its start.  ``sim`` leaps
        over those scans (gateway/plc.py) -- the leap lands on the due, or on whatever other
        input comes first.  Read as seldom as :meth:`_judge` reads."""
        self._still = False
        self._state = None
        if self._pause:
            self._pause -= 1
            self._timeless = None
            return
        if not self._timeless_tried:
            self._timeless_tried = True
            self._timeless_of = self._timeless_reader()
        if self._timeless_of is None:
            return
        state = self._timeless_of()
        if self._timeless is not None:
            ran = [timer for timer in self._timers if timer._ran == now_ms] if (
                state == self._timeless) else None
            # Each call that ran is one timer's (a timer called twice, or a call of another
            # runtime's in another thread, leaves the counts apart: no leap).
            if ran is not None and len(ran) == running:
                self._until = min(timer._due for timer in ran)
                self._running = ran
                self._still_generation, self._still_nc = generation, nc_read
            else:
                self._missed()
        self._timeless = state

    def _timeless_reader(self) -> Callable[[], Any] | None:
        """How the state but the timers' ETs is read, and every timer instance found
        (None: the state cannot be told, or there are too many objects to look through)."""
        logic = self.logic
        globals_state = logic.globals_state(timeless=True)
        pairs = [(logic.program_state(key, timeless=True), self.programs[key])
                 for key in self.order]
        timers = _timers_in([logic.namespace["_G"], *self.programs.values()])
        if globals_state is None or timers is None:
            return None
        self._timers = timers
        ns, states = self._ns, [(state, program) for state, program in pairs
                                if state is not None]
        if len(states) < len(pairs):
            return None

        def read() -> Any:
            return globals_state(ns["_G"]), [state(program) for state, program in states]

        return read

    @property
    def still_until(self) -> int | None:
        """After a timed still scan (:meth:`_judge_timed`): the time (ms) before which every
        scan that reads the same does the same nothing; else None."""
        return self._until

    def catch_up(self, now_ms: int) -> None:
        """The running timers' ETs as the scans leapt over up to ``now_ms`` left them."""
        if self._until is not None and now_ms < self._until:
            for timer in self._running:
                timer.catch_up(now_ms)

    def _bind(self, ns: dict[str, Any]) -> None:
        """The generated module's globals: the scan's copy of the image, the NC's outputs
        (lists the logic writes in place), NC.SEND and the loop guard."""
        self._ns = ns
        ns["_SA"], ns["_SK"], ns["_SY"] = self._sa, self._k, self._sy
        ns["_NC_SEND"] = lambda sender, target, where: self._sends.append(
            (sender, target, where))
        self._outputs: list[bool] = ns["_NCO"]
        self._outputs_at: list[str] = ns["_NCW"]
        self._process_outputs: list[list[bool]] = ns["_NCP"]
        self._process_outputs_at: list[list[str]] = ns["_NCPW"]
        self._overrides: list[int] = ns["_NCV"]
        self._overrides_at: list[str] = ns["_NCVW"]
        self._process_overrides: list[int] = ns["_NCPV"]
        self._process_overrides_at: list[str] = ns["_NCPVW"]
        ns["_guard"] = self._guard

    def _output_lists(self) -> tuple[list[Any], ...]:
        return (self._outputs, self._outputs_at, self._process_outputs,
                self._process_outputs_at, self._overrides, self._overrides_at,
                self._process_overrides, self._process_overrides_at)

    def reload(self, logic: Logic, order: Sequence[str]) -> Reloaded:
        """Online change: run ``logic`` from the next scan on (call it between two scans).

        Every variable whose path and type are the same in both keeps its value, and every
        function block instance kept keeps its state (a TON's time goes on running); a new or
        retyped variable starts from its initial value, RETAIN too (the store holds only the
        running logic's values), and one that is gone is dropped.  VAR_GLOBALs likewise.
        The NC outputs keep their last levels, so an NC.START held TRUE across the change is
        no new edge.  A PLC in FAULT runs again."""
        self._leave_timed()  # (the ETs carried over are the scans' before it)
        old_logic, old_programs = self.logic, self.programs
        carry = _Carry(old_logic, logic)
        programs = {key: logic.new_program(key) for key in logic.programs}
        # VAR_GLOBALs live in the module (_G), by their own names.
        carry.instance(old_logic.namespace["_G"], logic.namespace["_G"], old_logic.globals,
                       logic.globals, "")
        for key, new in programs.items():
            name = logic.display[key]
            if key in old_programs:
                carry.instance(old_programs[key], new, old_logic.programs[key],
                               logic.programs[key], name)
            else:
                carry.initial.append(name)
        carry.dropped += [old_logic.display[k] for k in old_programs if k not in programs]
        outputs = self._output_lists()
        self._bind(logic.namespace)
        for old, new in zip(outputs, self._output_lists(), strict=True):
            for i, value in enumerate(old[:len(new)]):
                new[i] = value[:] if isinstance(value, list) else value
        self.logic = logic
        self._watch.keys, self._watch.areas = logic.image_keys, logic.image_areas
        self._watch.generation += 1
        self.order = [name.upper() for name in order]
        self.programs = programs
        self._runs = [programs[key] for key in self.order]
        self._retained = _retained_of(logic)
        self._saved = None  # the store is rewritten at the next scan: what is gone goes
        self._read_state()
        if self.status.state is PlcState.FAULT:
            self.status.state = PlcState.RUNNING
            self.status.fault = None
        return Reloaded(carry.kept, tuple(carry.initial), tuple(carry.dropped))

    # -- the scan ----------------------------------------------------------------------------------

    def scan(self, now_ms: int) -> None:
        status = self.status
        if status.state is not PlcState.RUNNING:
            return
        started = self.clock_ns()
        image, ns = self.image, self._ns
        generation = self._watch.generation
        nc_read = None
        if self.logic.reads_nc:
            nc = self.nc
            nc_read = (nc.snapshot(), nc.events() & 0xFFFFFFFF, nc.last_snd())
        if self._still and generation == self._still_generation and (
                nc_read == self._still_nc) and self._state_of is not None and (
                self._state_of() == self._state):
            # The last scan changed nothing -- not the programs' state (their variables,
            # their timers' and edges' memory), not the image, not the NC -- and what it read
            # and the state are the same now: this one would do exactly the same nothing.
            # Its time cannot matter: the logic reads the time only through TON, TOF and TP,
            # and the last scan made no call of one that was running (stdlib.RUNNING) -- one
            # that stood still with the same inputs stands still for good.  The state is
            # read again, not trusted: a test or a debugger may set a variable between
            # scans (and a scan that did not start from the state the last one left is
            # never judged still: below).
            status.scans += 1
            self._misses = 0
            self._timed(started)
            for listener in self.scan_listeners:
                listener()
            return
        until = self._until
        if until is not None and now_ms < until and generation == self._still_generation and (
                nc_read == self._still_nc) and not self.scan_listeners and (
                self._timeless_of is not None and self._timeless_of() == self._timeless):
            # The last scan was a timed still one (_judge_timed) and what it read is the
            # same: this one would do the same nothing but move the running timers' ETs on.
            self.catch_up(now_ms)
            status.scans += 1
            self._misses = 0
            self._timed(started)
            return
        if (self._still or until is not None) and status.scans == self._judged_at:
            # Judged still, and the very next scan reads something new (a value the plant
            # moves at every step): reading the state was for nothing.
            self._missed()
        self._still = False
        self._until = None
        if not self._pause and self._state_of is not None:
            # Set between scans (a debugger, a test): this scan does not start from the
            # state the last one left, so its end says nothing of whether it was still.
            # (Read only when a judge will compare: while paused it forgets the state.)
            if self._state is not None and self._state_of() != self._state:
                self._state = None
            if self._timeless is not None and self._timeless_of is not None and (
                    self._timeless_of() != self._timeless):
                self._timeless = None
        # The programs work on a copy.  Nothing writes the image while they run (the scan
        # is one call on the loop), so the image itself stays the scan's inputs to diff
        # against.
        self._sa[:] = image.sa
        self._k[:] = image.k
        self._sy[:] = image.syvar
        if nc_read is not None:
            ns["_NCS"], ns["_NCE"], ns["_NCL"] = nc_read
        ns["_NOW"] = now_ms
        # Loop iterations are handed out GUARD_CHUNK at a time: between chunks the guard
        # looks at the iteration limit and the watchdog's clock.
        self._granted = min(GUARD_CHUNK, self.loop_limit)
        ns["_LEFT"] = self._granted
        self._deadline_ns = (started + self.watchdog_ms * 1_000_000 if self.watchdog_ms
                             else 0)
        self._sends.clear()
        if self.forced:
            self._apply_forces(False)
        timers = next(RUNNING)
        try:
            for program in self._runs:
                program()
        except Exception as exc:  # any error of the logic is a FAULT, never a
            self._timed(started)   # crash of the loop that serves the fieldbus
            self._fault(exc)
            return
        # The guard looks at the clock only between loop chunks: straight-line code (74 to
        # 644 ms of it, found in the field) never reaches it.  Whatever the code looks like,
        # a scan that ran over is a FAULT, its outputs dropped.
        ran_ns = self.clock_ns() - started
        if self.watchdog_ms and ran_ns > self.watchdog_ms * 1_000_000:
            self._timed(started)
            self._fault(WatchdogExpired(f"the scan ran {ran_ns // 1_000_000} ms"))
            return
        if self.forced:
            self._apply_forces(True)
        changes = self._changes(image.sa, image.k, image.syvar)
        acts = self._acts()
        if changes:
            image.write(changes, self.writer)
        if acts:
            self._act()
        if self._retained:
            self._save_retained()
        if self._state_of is not None:
            quiet = not changes and not acts and not self.forced and (
                self.retain is None or not self._retained)
            running = next(RUNNING) - timers - 1
            if quiet and running and self.timed and not self.logic.reads_et:
                self._judge_timed(running, now_ms, generation, nc_read)
            else:
                self._judge(quiet and not running, generation, nc_read)
        status.scans += 1
        if self._still or self._until is not None:
            self._judged_at = status.scans
        self._timed(started)
        for listener in self.scan_listeners:
            listener()

    def _timed(self, started: int) -> None:
        """The scan's time in the status (a faulted scan's too: its time is the news)."""
        status = self.status
        elapsed = (self.clock_ns() - started) // 1000
        status.last_scan_us = elapsed
        if elapsed > status.max_scan_us:
            status.max_scan_us = elapsed

    def _changes(self, sa: bytearray, k: bytearray, sy: list[int]
                 ) -> list[tuple[str, int, str, int]]:
        out: list[tuple[str, int, str, int]] = []
        new_sa, new_k, new_sy = self._sa, self._k, self._sy
        if new_sa != sa:
            for byte, (old, new) in enumerate(zip(sa, new_sa, strict=True)):
                flipped = old ^ new
                while flipped:
                    bit = (flipped & -flipped).bit_length() - 1
                    flipped &= flipped - 1
                    out.append(("SA", byte * 8 + bit, "bit", new >> bit & 1))
        if new_k != k:
            out += [("SK", i, "BY", new) for i, (old, new) in enumerate(zip(k, new_k,
                                                                           strict=True))
                    if old != new]
        if new_sy != sy:
            out += [("SYVAR", i, "IN", new) for i, (old, new) in enumerate(zip(sy, new_sy,
                                                                              strict=True))
                    if old != new]
        return out

    @property
    def still(self) -> bool:
        """The last scan changed nothing (the programs' state, the image, the NC) and the
        next one, if what it reads is the same, will be skipped as the same nothing."""
        return self._still

    @property
    def hold_level(self) -> bool:
        """NC.HOLD_LEVEL as the last scan left it: while TRUE the NC refuses a cycle start."""
        return bool(self._last_outputs[_HOLD_LEVEL]) and self.status.state is PlcState.RUNNING

    def _acts(self) -> bool:
        """Whether :meth:`_act` has something to do: an NC output changed, a send."""
        return bool(self._sends) or self._outputs != self._last_outputs or (
            self._process_outputs != self._last_process_outputs) or (
            self._overrides[0] != self._last_overrides[0]) or (
            self._process_overrides != self._last_process_overrides)

    def _act(self) -> None:
        outputs, last = self._outputs, self._last_outputs
        if outputs != last:
            for i, word in _EDGES:
                if outputs[i] and not last[i]:  # NC.START/HOLD/RESET act on a rising edge
                    self._command(word, self._outputs_at[i])
            for i, on, off in _LEVELS:  # OPT_STOP, BLOCK_SKIP: levels
                if bool(outputs[i]) != bool(last[i]):
                    self._command(on if outputs[i] else off, self._outputs_at[i])
            if outputs[_HOLD_LEVEL] and not last[_HOLD_LEVEL]:  # holds as it rises
                self._command(_FEED_HOLD, self._outputs_at[_HOLD_LEVEL])
            self._last_outputs = [bool(o) for o in outputs]
        if self._process_outputs == self._last_process_outputs:
            pass  # the common scan: no process output changed (one comparison, not k)
        else:
            self._act_processes()
        if self._overrides[0] != self._last_overrides[0]:
            self._last_overrides[0] = value = self._overrides[0]
            self._override(value, self._overrides_at[0], None)
        if self._process_overrides != self._last_process_overrides:
            for k, value in enumerate(self._process_overrides):
                if value != self._last_process_overrides[k]:
                    self._last_process_overrides[k] = value
                    self._override(value, self._process_overrides_at[k], k + 1)
        if self._sends:
            for sender, target, where in self._sends:
                try:
                    self.nc.send(sender, target, where)
                except NcgateError as exc:
                    self.nc.hazard(f"PLC NC.SEND({sender}, {target}): {exc}")
            self._sends.clear()

    def _act_processes(self) -> None:
        """The per-process outputs that changed: NC.P[k].START .. on their rising edge, the
        acknowledges (MACK ..) as levels."""
        for k, (now, before) in enumerate(zip(self._process_outputs,
                                              self._last_process_outputs, strict=True)):
            if now != before:
                for i, word in _PROCESS_EDGES:
                    if now[i] and not before[i]:
                        self._command(word, self._process_outputs_at[k][i], k + 1)
                for i, letter in _AUX_ACKS:  # MACK ..: levels, on a change
                    if bool(now[i]) != bool(before[i]):
                        self._aux_ack(k + 1, letter, bool(now[i]),
                                      self._process_outputs_at[k][i])
                self._last_process_outputs[k] = [bool(o) for o in now]

    def _command(self, word: int, where: str, process: int | None = None) -> None:
        try:
            self.nc.command(word, where, process)
        except NcgateError as exc:  # refused (an interlock, ...): said, the scan goes on
            self.nc.hazard(f"PLC command {word} at {where}: {exc}")

    def _aux_ack(self, process: int, letter: str, value: bool, where: str) -> None:
        try:
            self.nc.aux_ack(process, letter, value, where)
        except NcgateError as exc:
            self.nc.hazard(f"PLC NC.P[{process}].{letter}ACK at {where}: {exc}")

    def _override(self, feed: int, where: str, process: int | None) -> None:
        try:
            self.nc.override(feed, where, process)
        except NcgateError as exc:
            self.nc.hazard(f"PLC FEED_OVERRIDE at {where}: {exc}")

    def _guard(self) -> None:
        """Called by the compiled logic when its loop iterations ran out: the iteration
        limit and the watchdog are checked, then another chunk is handed out."""
        if self._deadline_ns and self.clock_ns() > self._deadline_ns:
            raise WatchdogExpired("the scan watchdog expired")
        if self._granted >= self.loop_limit:
            raise IterationGuard("the loop iteration guard ran out")
        chunk = min(GUARD_CHUNK, self.loop_limit - self._granted)
        self._granted += chunk
        self._ns["_LEFT"] = chunk - 1  # the iteration that called is one of them

    def _fault(self, exc: BaseException) -> None:
        span, line = self.logic.locate(exc.__traceback__)
        message = str(exc)
        if isinstance(exc, WatchdogExpired):
            ran = f"{message}, " if message.startswith("the scan ran ") else "the scan ran "
            message = (f"{ran}longer than the watchdog's {self.watchdog_ms} ms "
                       "(plc.watchdog_ms)")
        elif isinstance(exc, IterationGuard):
            message = (f"more than {self.loop_limit} loop iterations in one scan "
                       "(plc.loop_limit)")
        elif isinstance(exc, RecursionError):
            message = "calls nested too deep"
        elif isinstance(exc, ZeroDivisionError) and "MOD" not in message:
            message = "division by zero"
        elif isinstance(exc, OverflowError) and message == REAL_OVERFLOW:
            message = REAL_OVERFLOW_MESSAGE
        fault = PlcFault(message, span, line)
        self.status.state = PlcState.FAULT
        self.status.fault = fault
        log.error("%s fault: %s", "plant logic" if self.writer == "plant" else "PLC", fault)
        self.nc.fault(str(fault))
        for listener in self.scan_listeners:
            listener()

    # -- RETAIN ------------------------------------------------------------------------------------

    def _holder(self, program: str) -> Any:
        """Where a RETAIN variable lives: its program's instance, or the VAR_GLOBALs."""
        return self._ns["_G"] if program == GLOBALS else self.programs[program]

    def retained_values(self) -> dict[str, tuple[str, Any]]:
        out = {}
        for program, var in self._retained:
            value = getattr(self._holder(program), f"v_{var.key}")
            out[f"{program}.{var.key}"] = (str(var.type), self.logic.dump(value, var.type))
        return out

    def _save_retained(self) -> None:
        values = self.retained_values()
        if values != self._saved and self.retain is not None:
            try:
                self.retain.save(values)
            except sqlite3.Error as exc:  # a full or vanished disk: the PLC scans on
                if not self._save_failed:
                    log.error("RETAIN values not saved to %s: %s (the PLC goes on; saving "
                              "is retried on the next change)", self.retain.path, exc)
                self._save_failed = True
                return
            if self._save_failed:
                log.info("RETAIN values saved again to %s", self.retain.path)
            self._save_failed = False
            self._saved = values

    def _apply_retained(self, stored: dict[str, tuple[str, Any]]) -> None:
        used = set()
        for program, var in self._retained:
            name = f"{program}.{var.key}"
            found = stored.get(name)
            if found is None:
                continue
            type_name, value = found
            if type_name != str(var.type) or not self.logic.fits(value, var.type):
                log.warning("RETAIN %s: the stored %s no longer fits %s; initial value "
                            "used, and the stored value dropped", name, type_name, var.type)
                continue
            setattr(self._holder(program), f"v_{var.key}", self.logic.restore(value, var.type))
            used.add(name)
        for name in sorted(set(stored) - {f"{p}.{v.key}" for p, v in self._retained}):
            log.warning("RETAIN %s: no such RETAIN variable now; its stored value is dropped",
                        name)
        self._saved = self.retained_values()
        if used != set(stored):
            # Rewrite the store now: an old row left there would come back the day the
            # variable has its old type again -- a value from two versions earlier.
            self._saved = None
            self._save_retained()

    # -- watching ---------------------------------------------------------------------------

    def read(self, path: str) -> Any:
        """A variable's value by its path: ``"main.t1.ET"``, ``"main.counts[3]"``
        (case-insensitive).  PlcPathError (a KeyError) with the names there are when a part
        is unknown."""
        obj = self._get(*self._place(path, members=True)[:2])
        return list(obj) if isinstance(obj, list) else obj

    # -- forcing (docs/decisions.md, "Forcing") -----------------------------------------------

    def forceable(self, path: str) -> Any:
        """The type of the variable at ``path``; PlcPathError (a KeyError) for no such
        variable, ValueError for one a force cannot set."""
        _, _, t = self._place(path)
        if not isinstance(t, str) or t not in _FORCEABLE:
            raise ValueError(f"{path}: a force sets a variable of an elementary type (BOOL, "
                             f"an integer, REAL, LREAL, TIME), not {t}")
        return t

    def check_force(self, path: str, value: Any) -> Any:
        """The value ``path`` would be forced to, as the logic stores it; PlcPathError (a
        KeyError) for no such variable, ValueError for a value it cannot hold."""
        t = self.forceable(path)
        if t == "BOOL" and value in (0, 1) and not isinstance(value, float):
            value = bool(value)
        if isinstance(value, bool) and t != "BOOL":
            raise ValueError(f"{path} is {t}: not {value!r}")
        try:  # (a REAL beyond IEEE single is an OverflowError, past a double struct.error)
            stored = _as_stored(value, t)
            if t == "LREAL" and isinstance(stored, int):
                stored = float(stored)  # the LREAL the logic holds, not an int
        except (OverflowError, struct.error):
            raise ValueError(f"{path} is {t}: it cannot hold {value!r}") from None
        if not _fits(stored, t):  # (forceable: an elementary type, no subrange)
            raise ValueError(f"{path} is {t}: it cannot hold {value!r}")
        return stored

    def force(self, path: str, stored: Any) -> None:
        """Keep ``path`` at ``stored`` (from :meth:`check_force`): set now, then at the start
        and at the end of every scan (the logic may change it inside a scan)."""
        key = self._key(path)
        parent, attr, t = self._place(path)
        self.forced[key] = (path, stored)
        self._forced_types[key] = t
        self._assign(parent, attr, stored)
        self._changed_state()

    def unforce(self, path: str | None = None) -> None:
        """Release one forced variable (None: every one); its value stays."""
        if path is None:
            self.forced.clear()
            self._forced_types.clear()
        else:
            self.forced.pop(self._key(path), None)
            self._forced_types.pop(self._key(path), None)

    def is_forced(self, path: str) -> bool:
        """Whether the variable at ``path`` (a valid one) is forced."""
        return self._key(path) in self.forced

    @staticmethod
    def _key(path: str) -> str:
        """One key per variable, however its path is spelled (``main.a[01]`` is
        ``MAIN.A[1]``): a valid path, as :meth:`_place` takes it."""
        program, _, rest = "".join(path.split()).upper().partition(".")
        return program + "".join(f"[{p}]" if isinstance(p, int) else f".{p}"
                                 for p in _split(rest))

    def _apply_forces(self, after: bool) -> None:
        types = self._forced_types
        for name, (path, stored) in list(self.forced.items()):
            try:
                parent, key, t = self._place(path)
            except PlcPathError:
                continue  # gone with an online change: kept, set again if it comes back
            if t != types.get(name):
                continue  # retyped by one: the value is not its type's; likewise kept
            current = self._get(parent, key)
            if current != stored or type(current) is not type(stored):
                if after and self.on_overridden is not None:
                    self.on_overridden(path, current)
                self._assign(parent, key, stored)

    @staticmethod
    def _get(parent: Any, key: str | int) -> Any:
        return parent[key] if isinstance(key, int) else getattr(parent, key)

    @staticmethod
    def _assign(parent: Any, key: str | int, value: Any) -> None:
        if isinstance(key, int):
            parent[key] = value
        else:
            setattr(parent, key, value)

    def _place(self, path: str, members: bool = False) -> tuple[Any, str | int, Any]:
        """Where ``path`` lives: its container, the attribute or index in it, its type (None
        for a standard FB's member, which only ``members`` admits: a reader may look at a
        TON's Q, a force may not set it)."""
        program, _, rest = path.partition(".")
        key = program.upper()
        if key not in self.programs:
            raise PlcPathError(f"no program {program!r} (programs: "
                               f"{', '.join(self.logic.display[k] for k in self.programs)})")
        try:
            parts = _split(rest)
        except ValueError:
            raise PlcPathError(f"{path!r}: not a variable's path") from None
        if not parts:
            raise PlcPathError(f"{path!r}: name a variable of {program}")
        obj: Any = self.programs[key]
        table: dict[str, ProgramVar] | None = self.logic.programs[key]
        t: Any = None
        for i, part in enumerate(parts):
            last = i == len(parts) - 1
            if isinstance(part, int):
                if not isinstance(t, ArrayOf) or not t.lo <= part <= t.hi:
                    raise PlcPathError(f"{path!r}: [{part}] is not an index of {t}")
                if last:
                    return obj, part - t.lo, t.element
                obj, t = obj[part - t.lo], t.element
                table = self.logic.members_of(t)
                continue
            name = part.upper()
            if isinstance(t, FbOf) and t.std:
                if not members:
                    # A standard FB's members are its outputs and state: the logic's to set.
                    raise PlcPathError(f"{path!r}: {t.name}.{part} is not forced (force the "
                                       "variable it feeds)")
                if not hasattr(obj, name) or name.startswith("_"):
                    raise PlcPathError(f"{path!r}: {t.name} has no {part}")
                if last:
                    return obj, name, None
                obj, t = getattr(obj, name), None
                continue
            if table is None or name not in table:
                known = ", ".join(v.display for v in (table or {}).values())
                raise PlcPathError(f"{path!r}: no {part} here ({known})")
            var = table[name]
            if last:
                return obj, f"v_{name}", var.type
            obj, t = getattr(obj, f"v_{name}"), var.type
            table = self.logic.members_of(t)
        raise PlcPathError(f"{path!r}: not a variable's path")  # not reached


_FORCEABLE = frozenset(("BOOL", "SINT", "INT", "DINT", "LINT", "USINT", "UINT", "UDINT",
                        "ULINT", "BYTE", "WORD", "DWORD", "LWORD", "REAL", "LREAL", "TIME"))


@dataclass(frozen=True, slots=True)
class Reloaded:
    """What an online change kept: how many variables kept their value (each member of a
    function block instance counted), the paths that start from their initial value (new or
    retyped) and those that are gone."""

    kept: int
    initial: tuple[str, ...]
    dropped: tuple[str, ...]


class _Carry:
    """Moves the state of the old logic's instances into the new logic's, variable by
    variable, where path and type are unchanged."""

    def __init__(self, old: Logic, new: Logic) -> None:
        self.old, self.new = old, new
        self.kept = 0
        self.initial: list[str] = []
        self.dropped: list[str] = []

    def instance(self, old_obj: Any, new_obj: Any, old_table: dict[str, ProgramVar],
                 new_table: dict[str, ProgramVar], path: str) -> None:
        for key, var in new_table.items():
            here = f"{path}.{var.display}" if path else var.display
            if var.constant:  # its declaration's value, the one the code uses (inlined)
                continue
            before = old_table.get(key)
            if before is None or not self.same(before.type, var.type):
                self.initial.append(here)
                continue
            attr = f"v_{key}"
            started = len(self.initial)
            setattr(new_obj, attr, self.value(getattr(old_obj, attr), getattr(new_obj, attr),
                                              var.type, here))
            if len(self.initial) == started:  # (an enumeration's value may not carry)
                self.kept += 1
        self.dropped += [f"{path}.{v.display}" if path else v.display
                         for k, v in old_table.items() if k not in new_table]

    def value(self, old: Any, new: Any, t: Any, path: str) -> Any:
        if isinstance(t, ArrayOf):
            return [self.value(o, n, t.element, f"{path}[{getattr(t, 'lo', 0) + i}]")
                    for i, (o, n) in enumerate(zip(old, new, strict=True))]
        if isinstance(t, EnumOf):  # by its value's name: a value added before it renumbers
            name = next((k for k, v in self.old.enums[t.name].values.items() if v == old),
                        None)
            values = self.new.enums[t.name].values
            if name is None or name not in values:  # its value is gone from the type
                self.initial.append(path)
                return new
            return values[name]
        members = self.new.members_of(t)  # a user FB instance or a structure
        if members is not None:
            self.instance(old, new, self.old.members_of(t) or {}, members, path)
            return new
        # A number, a string, or a standard FB instance: its class is the standard
        # library's, the same in both logics, so the instance itself moves over.
        return old

    def same(self, a: Any, b: Any) -> bool:
        """The same declared type in both logics: a user FB or a structure by its name (its
        members are then compared one by one), an enumeration by its name (each value is
        then carried by its name), a subrange by its limits too."""
        if type(a) is not type(b) or a != b:
            return False
        if isinstance(a, str):  # a subrange is its base's name with limits
            return (getattr(a, "lo", None), getattr(a, "hi", None)) == (
                getattr(b, "lo", None), getattr(b, "hi", None))
        if isinstance(a, ArrayOf):
            return self.same(a.element, b.element)
        if isinstance(a, EnumOf):
            return a.name in self.old.enums and b.name in self.new.enums
        return True


GLOBALS = "VAR_GLOBAL"  # the store's name of the globals' RETAIN rows (no POU has it)


def _retained_of(logic: Logic) -> list[tuple[str, ProgramVar]]:
    """The RETAIN variables: (program, variable) of the programs, (GLOBALS, ...) of the
    VAR_GLOBAL RETAINs."""
    return [(p, v) for p, table in logic.programs.items() for v in table.values()
            if v.retain] + [(GLOBALS, v) for v in logic.globals.values() if v.retain]


def _split(rest: str) -> list[str | int]:
    parts: list[str | int] = []
    for piece in rest.split("."):
        name, _, tail = piece.partition("[")
        if name:
            parts.append(name)
        while tail:
            index, _, tail = tail.partition("]")
            parts.append(int(index))
            tail = tail.removeprefix("[")
    return parts


def _as_stored(value: Any, t: Any) -> Any:
    """A REAL as the logic holds it: IEEE single (a store written before REALs were single
    may hold doubles)."""
    if isinstance(t, ArrayOf):
        return [_as_stored(v, t.element) for v in value]
    return to_real(value) if t == "REAL" else value


def _fits(value: Any, t: Any) -> bool:
    if isinstance(t, ArrayOf):
        return isinstance(value, list) and len(value) == t.length and all(
            _fits(v, t.element) for v in value)
    if t == "BOOL":
        return isinstance(value, bool)
    if t in ("REAL", "LREAL"):
        if not isinstance(value, float | int) or isinstance(value, bool):
            return False
        try:
            return math.isfinite(to_real(value) if t == "REAL" else float(value))
        except OverflowError:
            return False
    if not isinstance(value, int) or isinstance(value, bool):
        return False
    lo, hi = limits("DINT" if t == "TIME" else t)
    return lo <= value <= hi


# The most objects :func:`_timers_in` looks through (beyond: no timed still scans).
TIMERS_SEARCH_MAX = 100_000


def _timers_in(roots: list[Any]) -> list[Timer] | None:
    """Every TON, TOF and TP instance held by ``roots`` (generated classes' instances, their
    FB instances and arrays), or None when there are more than TIMERS_SEARCH_MAX objects."""
    found: list[Timer] = []
    stack = list(roots)
    for _ in range(TIMERS_SEARCH_MAX):
        if not stack:
            return found
        item = stack.pop()
        if isinstance(item, Timer):
            found.append(item)
        elif isinstance(item, list):
            stack.extend(item)
        else:  # (a generated class's instance; a number or a string has no __slots__)
            stack.extend(getattr(item, slot, None)
                         for slot in getattr(type(item), "__slots__", ()))
    return None
