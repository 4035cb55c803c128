"""The trace (spec 4.4): every synchronisation event, in order, as typed events
(:mod:`ncgate.interpreter.engine.events`).

:meth:`Trace.record` numbers an event and keeps it; :attr:`Trace.events` renders the kept ones
as the dicts of spec 4.4, and :func:`to_jsonl` one dict as a JSON line with a fixed key order
and ``t`` printed with exactly six decimals, so that two runs of one scenario give
byte-identical files.  Listeners get the typed event itself, as it is recorded.

How much is kept is the owner's choice: everything (``ncgate sim``, a bounded batch run that
writes its trace at the end), or only the latest ``keep`` events (``ncgate run``, which runs
for a shift: memory must not grow with the number of events; listeners -- the trace file, the
log -- see every one).
"""

from __future__ import annotations

import json
import logging
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, TextIO

from ncgate.interpreter.engine.events import COUNTED, Event, as_dict
from ncgate.interpreter.engine.states import Where

EventDict = dict[str, Any]
_new = tuple.__new__
Listener = Callable[[Event], None]
log = logging.getLogger("ncgate.trace")
FAILURE_LOG_S = 60.0  # a listener that keeps failing: its count logged at most this often


@dataclass(slots=True)
class ListenerFailures:
    """A listener that raised: its name, how often, when that was last logged, and the count
    said then."""

    name: str
    count: int
    logged_at: float
    said: int


class Trace:
    """Collects events; listeners see each event as it is recorded.

    ``keep=None`` keeps every event; ``keep=n`` only the latest n (a ring).
    """

    def __init__(self, keep: int | None = None) -> None:
        if keep is not None and keep < 0:
            raise ValueError(f"keep: expected None or a count >= 0, got {keep}")
        self.keep = keep
        self.seq = 0
        self.counter = 0  # the fieldbus event counter
        self._ring: deque[Event] = deque(maxlen=keep)  # keep=n
        self._all: list[Event] = []  # keep=None
        self._dicts: list[EventDict] = []  # cached dicts of _all
        self._append = self._ring.append if keep is not None else self._all.append
        # A tuple, swapped whole by subscribe and unsubscribe: a listener that unsubscribes
        # itself (or another) while an event is delivered does not make the next miss it.
        self._listeners: tuple[Listener, ...] = ()
        # Listeners that raised, by the listener's id.  An entry goes with its listener's
        # unsubscribe, which says a count not said yet (a burst that stopped within the minute).
        self.listener_failures: dict[int, ListenerFailures] = {}

    @property
    def events(self) -> list[EventDict]:
        """The events kept, as the dicts of spec 4.4."""
        if self.keep is not None:
            return [as_dict(e) for e in self._ring]
        done = len(self._dicts)
        if done < len(self._all):
            self._dicts.extend(as_dict(e) for e in self._all[done:])
        return self._dicts

    def subscribe(self, listener: Listener) -> Callable[[], None]:
        """Add a listener; returns its unsubscribe (a second call does nothing)."""
        self._listeners = (*self._listeners, listener)
        done = False

        def unsubscribe() -> None:
            nonlocal done
            if done:
                return
            done = True
            listeners = list(self._listeners)
            for i, other in enumerate(listeners):
                if other is listener:
                    del listeners[i]
                    break
            self._listeners = tuple(listeners)
            failures = self.listener_failures.pop(id(listener), None)
            if failures is not None and failures.count > failures.said:
                log.error("trace listener %s failed %d times in all", failures.name,
                          failures.count)
        return unsubscribe

    def record(self, kind: type[Event], t: float, proc: int, where: Where | None,
               *fields: Any) -> None:
        """Record an event of type ``kind`` (e.g. ``events.Snd``) with its own fields."""
        self.seq += 1
        # tuple.__new__ builds the NamedTuple without its generated __new__: this is on the
        # path of every SND and WAI.
        event = _new(kind, (self.seq, t, proc, where, *fields))
        if kind in COUNTED:
            self.counter = (self.counter + 1) & 0xFFFFFFFF
        self._append(event)
        for listener in self._listeners:
            try:
                listener(event)
            except Exception:
                self._failed(listener, event)

    def _failed(self, listener: Listener, event: Event) -> None:
        """A listener raised: the event is recorded all the same, the other listeners get it,
        and the engine's step goes on (a listener is an adapter -- the trace file, the CANopen
        node, the console -- and one that fails must not stop the cell: it once left the
        engine's turn halfway through an SND, and the clock never ran again).  Logged with
        its traceback the first time, then counted and said at most once a minute."""
        failures = self.listener_failures.get(id(listener))
        now = time.monotonic()
        if failures is None:
            name = getattr(listener, "__qualname__", None) or type(listener).__qualname__
            self.listener_failures[id(listener)] = ListenerFailures(name, 1, now, 1)
            log.exception("trace listener %s failed on event %d (%s); the cell goes on",
                          name, event.seq, type(event).__name__)
            return
        failures.count += 1
        if now - failures.logged_at >= FAILURE_LOG_S:
            log.error("trace listener %s has failed %d times", failures.name, failures.count)
            failures.logged_at, failures.said = now, failures.count


def to_jsonl(event: EventDict) -> str:
    rest = {k: v for k, v in event.items() if k not in ("seq", "t")}
    body = json.dumps(rest, separators=(", ", ": "), ensure_ascii=False)
    return f'{{"seq": {event["seq"]}, "t": {event["t"]:.6f}, {body[1:]}'


def write_jsonl(events: Iterable[EventDict], out: TextIO) -> None:
    for event in events:
        out.write(to_jsonl(event))
        out.write("\n")
