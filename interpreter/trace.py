"""The trace (spec 4.4): every synchronisation event, in order.

Events are dicts with ``seq``, ``t`` (simulated seconds, rounded to 6 decimals), ``event``,
``proc`` and, where a block is involved, ``prog``, ``line``, ``n``; then the event's own
fields.  :func:`to_jsonl` renders one event as a JSON line with a fixed key order and ``t``
printed with exactly six decimals, so that two runs of one scenario give byte-identical files.

Recording is on the hot path of every SND and WAI, so an event is kept as a compact tuple and
turned into its dict only when someone reads :attr:`Trace.events` (or a listener is
subscribed, which gets the dict at once).

How much is kept is the owner's choice: everything (``ncgate sim``, a bounded batch run that
writes its trace at the end), or only the latest ``keep`` events (``ncgate run``, which runs
for a shift: memory must not grow with the number of events; listeners -- the trace file, the
log -- see every one).
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any, TextIO

Event = dict[str, Any]
Where = tuple[str, int, int | None]
_Raw = tuple[int, float, str, int, Where | None, dict[str, Any]]
# Events that count on the fieldbus event counter (spec 3.2: input registers 2, 3).
COUNTED = frozenset({"start", "end", "wait", "resume", "snd", "alarm"})


def _as_dict(raw: _Raw) -> Event:
    seq, t, event, proc, where, fields = raw
    if where is None:
        return {"seq": seq, "t": round(t, 6), "event": event, "proc": proc, **fields}
    return {"seq": seq, "t": round(t, 6), "event": event, "proc": proc, "prog": where[0],
            "line": where[1], "n": where[2], **fields}


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
        self._ring: deque[_Raw] = deque(maxlen=keep)  # keep=n
        self._all: list[_Raw] = []  # keep=None
        self._dicts: list[Event] = []  # cached dicts of _all
        self._append = self._ring.append if keep is not None else self._all.append
        self._listeners: list[Callable[[Event], None]] = []

    @property
    def events(self) -> list[Event]:
        """The events kept (every one, or the latest ``keep``), as dicts in event order."""
        if self.keep is not None:
            return [_as_dict(raw) for raw in self._ring]
        done = len(self._dicts)
        if done < len(self._all):
            self._dicts.extend(_as_dict(raw) for raw in self._all[done:])
        return self._dicts

    def subscribe(self, listener: Callable[[Event], None]) -> Callable[[], None]:
        self._listeners.append(listener)
        return lambda: self._listeners.remove(listener)

    def record(self, t: float, event: str, proc: int, where: Where | None,
               fields: dict[str, Any]) -> None:
        self.seq += 1
        raw = (self.seq, t, event, proc, where, fields)
        if event in COUNTED:
            self.counter = (self.counter + 1) & 0xFFFFFFFF
        self._append(raw)
        if self._listeners:
            entry = _as_dict(raw)
            for listener in self._listeners:
                listener(entry)


def to_jsonl(event: Event) -> str:
    rest = {k: v for k, v in event.items() if k not in ("seq", "t")}
    body = json.dumps(rest, separators=(", ", ": "), ensure_ascii=False)
    return f'{{"seq": {event["seq"]}, "t": {event["t"]:.6f}, {body[1:]}'


def write_jsonl(events: Iterable[Event], out: TextIO) -> None:
    for event in events:
        out.write(to_jsonl(event))
        out.write("\n")
