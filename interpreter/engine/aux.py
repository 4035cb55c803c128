"""Auxiliary functions: M, S, T and H words output to the PLC, with its handshake ([nc.aux];
docs/interfacing-a-plc.md).

Each process has, per letter, a value (a SYVAR or an SK word), a strobe and an acknowledge
(SA bits) -- :meth:`AuxSettings.place`.  The sequence of one code, FANUC's MF/FIN and
SINUMERIK's acknowledged auxiliary functions::

    1. NC   value, and strobe = 1 (one write)      trace: aux
    2. PLC  acknowledge = 1                        trace: aux_ack
    3. NC   strobe = 0 (inside the PLC's write)
    4. PLC  acknowledge = 0                        trace: resume (by "aux")
    5. NC   goes on

``none`` is step 1 without the strobe: nothing waits.  ``before_motion`` runs the sequence
before the block's motion, ``after_motion`` after it (the next block waits): each is a motion
queue item (``ItemKind.AUX``) that the interpolator reaches in motion order, and its wait is
an interpolator wait of kind AUX.

The NC watches each acknowledge for its edges, with a level-triggered image wait armed again
after every edge (the image wakes it inside the write that changed the bit, never by
polling).  An acknowledge that rises with no strobe of its place up is a PLC-side error: a
``hazard`` in the trace (and the run log), ignored, never a crash.  An acknowledge still up
when the next code is output was not dropped: the NC waits for it to rise again.

The engine owns one :class:`AuxInterface` when ``[nc.aux]`` is configured.  Stdlib only:
must not import ``plc``, ``gateway``, ``config`` or a front end (the front ends call
:func:`aux_items`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final, Protocol

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import RuntimeAlarm
from ncgate.interpreter.engine import events as ev
from ncgate.interpreter.engine.actions import ItemKind
from ncgate.interpreter.engine.process import Process, QueueItem
from ncgate.interpreter.engine.states import Stage, WaitKind, WaitRecord, Where
from ncgate.interpreter.settings import (
    AUX_LETTERS,
    AUX_NC_CODES,
    AuxSettings,
    Handshake,
)

if TYPE_CHECKING:
    from ncgate.interpreter.engine.ports import ImagePort
    from ncgate.interpreter.engine.timers import Timer

NONE, BEFORE, AFTER = Handshake.NONE, Handshake.BEFORE_MOTION, Handshake.AFTER_MOTION
_ACK, _DROP = "ack", "drop"  # what a pending handshake waits for: the rise, the fall
_IS: Final = (lambda v: v == 0, lambda v: v == 1)


@dataclass(frozen=True, slots=True)
class AuxOutput:
    """One auxiliary function to output: ``letter`` (M, S, T, H), its value, its handshake."""

    letter: str
    value: int
    handshake: Handshake

    @property
    def code(self) -> str:
        """As the trace names it: ``M8``, ``T5``, ``S1000``."""
        return f"{self.letter}{self.value}"

    @property
    def shown(self) -> str:
        """As people write it: ``M08`` (M codes with two digits), ``T5``, ``S1000``."""
        if self.letter == "M" and 0 <= self.value < 10:
            return f"M{self.value:02d}"
        return self.code


def aux_value(letter: str, value: float) -> int:
    """The value output for a word: T is the tool number (``T1.1``: tool 1, offset 1 -- the
    offset is the NC's), the others round half away from zero (spec 1.3)."""
    if letter == "T":
        return int(value)
    return int(abs(value) + 0.5) * (1 if value >= 0 else -1)


def aux_items(settings: AuxSettings | None, words: list[tuple[str, float]],
              where: Where) -> tuple[list[QueueItem], list[QueueItem]]:
    """The motion-queue items of a block's auxiliary words (in the order written): those to
    run before its motion (``none`` and ``before_motion``) and after it (``after_motion``).
    M00, M01, M02 and M30 keep the NC's meaning and are not output."""
    if settings is None:
        return [], []
    before: list[AuxOutput] = []
    after: list[AuxOutput] = []
    for letter, raw in words:
        if letter not in AUX_LETTERS:
            continue
        value = aux_value(letter, raw)
        if letter == "M" and raw == value and value in AUX_NC_CODES:
            continue
        handshake = settings.handshake_of(letter, value)
        (after if handshake is AFTER else before).append(AuxOutput(letter, value, handshake))
    return ([QueueItem(ItemKind.AUX, 0.0, where, None, before)] if before else [],
            [QueueItem(ItemKind.AUX, 0.0, where, None, after)] if after else [])


class AuxHost(Protocol):
    """What the interface needs of the engine (the :class:`~.engine.Engine` is one)."""

    @property
    def image(self) -> ImagePort: ...

    @property
    def now(self) -> float: ...

    def record(self, kind: type[ev.Event], proc: int, where: Where | None,
               *fields: object) -> None: ...

    def begin_wait(self, p: Process, stage: Stage, wait: WaitRecord) -> None: ...

    def finish_wait(self, p: Process, wait: WaitRecord, by: int | str) -> None: ...

    def alarm(self, p: Process, code: AlarmCode, message: str, where: Where | None) -> None: ...

    def call_at(self, t: float, callback: Callable[[], None]) -> Timer: ...

    def write_many(self, p: Process, changes: list[tuple[str, int, str, int]],
                   where: Where) -> None: ...


class _Slot:
    """One process's letter: its places, the acknowledge as last seen, the pending code."""

    __slots__ = ("ack", "letter", "level", "pending", "phase", "process", "strobe", "timer",
                 "value")

    def __init__(self, process: int, letter: str, value: tuple[str, int, str], strobe: int,
                 ack: int) -> None:
        self.process, self.letter = process, letter
        self.value, self.strobe, self.ack = value, strobe, ack
        self.level = 0
        self.pending: tuple[Process, WaitRecord, AuxOutput] | None = None
        self.phase = _ACK
        self.timer: Timer | None = None


class _Pending:
    """The handle of a handshake's wait: the engine cancels it on a reset or an alarm."""

    __slots__ = ("interface", "slot")

    def __init__(self, interface: AuxInterface, slot: _Slot) -> None:
        self.interface, self.slot = interface, slot

    def cancel(self) -> None:
        self.interface.withdraw(self.slot)


class AuxInterface:
    """The auxiliary functions of every process, and the watch on the acknowledges."""

    def __init__(self, host: AuxHost, settings: AuxSettings, processes: int) -> None:
        self.host = host
        self.settings = settings
        self.image = host.image
        self.slots: dict[tuple[int, str], _Slot] = {}
        self.last: dict[tuple[int, str], int] = {}  # the last value output (ST: NC.P[k].M)
        self._snapshot_places: dict[int, tuple[tuple[tuple[int, str], int], ...]] = {}
        for k in range(1, processes + 1):
            for letter in AUX_LETTERS:
                value, strobe, ack = settings.place(k, letter)
                slot = _Slot(k, letter, value, strobe, ack)
                slot.level = self.image.read("SA", ack, "bit")
                self.slots[(k, letter)] = slot
                self._watch(slot)

    # ---- the output (an action the interpolator performs) ---------------------------------

    def output(self, p: Process, stage: Stage, aux: AuxOutput, where: Where) -> bool:
        """Output one code: True when nothing waits (``none``), else the stage waits."""
        slot = self.slots[(p.number, aux.letter)]
        name = _name(slot.value)  # (of a 32-bit value, its high word's, the first)
        top = 0x7FFF if self.settings.words == 1 else 0x7FFF_FFFF
        if not -top - 1 <= aux.value <= top:
            raise RuntimeAlarm(AlarmCode.VALUE_OUT_OF_RANGE,
                               f"{aux.shown}: {name} holds {-top - 1}..{top}, not {aux.value}")
        handshake = aux.handshake
        changes = self.settings.value_words(slot.value, aux.value)
        strobe = None
        if handshake is not NONE:
            strobe = f"SA{slot.strobe}"
            changes.append(("SA", slot.strobe, "bit", 1))
        self.last[(p.number, aux.letter)] = aux.value
        self.host.record(ev.Aux, p.number, where, aux.code, handshake.value, name, strobe)
        if handshake is not NONE and slot.level:
            self.host.record(ev.Hazard, p.number, where,
                             f"PLC-side error: the acknowledge SA{slot.ack} of P{p.number}'s "
                             f"{aux.letter} functions was still 1 when {aux.shown} was output "
                             "(the PLC drops it after the strobe drops): the NC waits for it "
                             "to drop and rise again")
        self.host.write_many(p, changes, where)
        if handshake is NONE:
            return True
        wait = WaitRecord(WaitKind.AUX, 0, aux.shown, where, self.host.now, stage,
                          cond=f"SA{slot.ack}=1",
                          on=ev.AuxOn(aux.code, handshake.value, f"SA{slot.ack}", aux.shown),
                          text=functools.partial(self._reason, slot, aux))
        wait.handle = _Pending(self, slot)
        image, ack = self.image, slot.ack
        # The acknowledge as it is now (the console's and the status's why-record).
        wait.probe = lambda: (image.read("SA", ack, "bit"), image.last_writer("SA", ack, "bit"))
        slot.pending = (p, wait, aux)
        slot.phase = _ACK
        timeout = self.settings.timeout_s
        if timeout:
            slot.timer = self.host.call_at(self.host.now + timeout,
                                           functools.partial(self._timed_out, slot, wait))
        self.host.begin_wait(p, stage, wait)
        return False

    def _reason(self, slot: _Slot, aux: AuxOutput) -> str:
        strobe, ack = f"SA{slot.strobe}", f"SA{slot.ack}"
        if slot.phase == _DROP:
            dropped = (f"the NC dropped the strobe {strobe}, but {strobe} is still 1 (forced, "
                       "or set again by another writer)"
                       if self.image.read("SA", slot.strobe, "bit") else
                       f"the NC dropped the strobe {strobe}")
            return f"waits for the PLC to drop its acknowledge ({ack}=0, now 1; {dropped})"
        stale = (f"; {ack} is still 1 from before: the PLC must drop it first"
                 if slot.level else "")
        # The strobe as the image holds it: another writer (a fieldbus client, a force) may
        # have dropped the NC's, and then the PLC sees no function to acknowledge.
        if self.image.read("SA", slot.strobe, "bit"):
            shown = f"strobe {strobe}=1"
        else:
            by = self.image.last_writer("SA", slot.strobe, "bit")
            shown = (f"but the strobe {strobe} is 0, dropped by {by or 'someone'}: the PLC "
                     "sees no function")
        return (f"waits for the PLC to acknowledge it ({ack}=1, now {slot.level}; "
                f"{shown}){stale}")

    def snapshot_places(self, process: int) -> tuple[tuple[tuple[int, str], int], ...]:
        """For M, S, T and H of ``process``: the key of :attr:`last` (the value last output)
        and the strobe's SA bit -- what the PLC's snapshot of the NC reads every scan, looked
        up once."""
        places = self._snapshot_places.get(process)
        if places is None:
            places = self._snapshot_places[process] = tuple(
                ((process, letter), self.slots[(process, letter)].strobe)
                for letter in AUX_LETTERS)
        return places

    # ---- the acknowledge's edges -------------------------------------------------------

    def _watch(self, slot: _Slot) -> None:
        """Wait for the acknowledge's next edge (it may be there already)."""
        while True:
            handle = self.image.wait("SA", slot.ack, "bit", _IS[0 if slot.level else 1],
                                     functools.partial(self._edge, slot))
            if handle is not None:
                return
            self._flip(slot)

    def _edge(self, slot: _Slot) -> None:
        self._flip(slot)
        self._watch(slot)

    def _flip(self, slot: _Slot) -> None:
        slot.level ^= 1
        if slot.level:
            self._rose(slot)
        else:
            self._fell(slot)

    def _rose(self, slot: _Slot) -> None:
        by = self.image.last_writer("SA", slot.ack, "bit")
        pending = slot.pending
        if pending is None or slot.phase != _ACK:
            strobe = f"SA{slot.strobe}"
            if self.image.read("SA", slot.strobe, "bit"):  # set by another writer, not the NC
                setter = self.image.last_writer("SA", slot.strobe, "bit")
                asked = (f"with no function output ({strobe} is 1, set by "
                         f"{setter or 'someone'}, not by the NC)")
            else:
                asked = f"with no strobe up ({strobe} is 0)"
            self.host.record(ev.Hazard, slot.process, None,
                             f"PLC-side error: the acknowledge SA{slot.ack} of P{slot.process}'s "
                             f"{slot.letter} functions was set by {by or 'someone'} {asked}: "
                             "ignored (the PLC sets it only in answer to a strobe)")
            return
        p, wait, aux = pending
        self.host.record(ev.AuxAck, p.number, wait.where, aux.code, by)
        slot.phase = _DROP
        self.host.write_many(p, [("SA", slot.strobe, "bit", 0)], wait.where)

    def _fell(self, slot: _Slot) -> None:
        pending = slot.pending
        if pending is None or slot.phase != _DROP:
            return  # (a stale acknowledge dropped: the NC now waits for it to rise)
        p, wait, _ = pending
        self._forget(slot)
        wait.handle = None
        self.host.finish_wait(p, wait, "aux")

    # ---- the end of a handshake that did not finish -----------------------------------

    def _forget(self, slot: _Slot) -> None:
        slot.pending = None
        slot.phase = _ACK
        if slot.timer is not None:
            slot.timer.cancel()
            slot.timer = None

    def withdraw(self, slot: _Slot) -> None:
        """A reset or an alarm ended the wait: the NC drops its strobe (the PLC sees the
        function withdrawn)."""
        pending = slot.pending
        self._forget(slot)
        if pending is not None and self.image.read("SA", slot.strobe, "bit"):
            p, wait, _ = pending
            self.host.write_many(p, [("SA", slot.strobe, "bit", 0)], wait.where)

    def _timed_out(self, slot: _Slot, wait: WaitRecord) -> None:
        slot.timer = None
        pending = slot.pending
        if pending is None or pending[1] is not wait:
            return
        p, _, aux = pending
        self.host.alarm(p, AlarmCode.AUX_TIMEOUT,
                        f"the PLC did not acknowledge {aux.shown} within "
                        f"{self.settings.timeout_s:g} s (nc.aux.timeout_s): it "
                        f"{self._reason(slot, aux)}", wait.where)


def _name(var: tuple[str, int, str]) -> str:
    area, index, view = var
    if area == "SYVAR":
        return f"SYVAR{index}"
    return f"{area}{index}" + ("" if view == "bit" else f".{view}")
