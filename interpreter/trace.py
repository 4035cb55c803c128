"""The trace (spec 4.4): every synchronisation event, in order.

Events are dicts with ``seq``, ``t`` (simulated seconds, rounded to 6 decimals), ``event``,
``proc`` and, where a block is involved, ``prog``, ``line``, ``n``; then the event's own
fields.  :func:`to_jsonl` renders one event as a JSON line with a fixed key order and ``t``
printed with exactly six decimals, so that two runs of one scenario give byte-identical files.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from typing import Any, TextIO

Event = dict[str, Any]
# Events that count on the fieldbus event counter (spec 3.2: input registers 2, 3).
COUNTED = frozenset({"start", "end", "wait", "resume", "snd", "alarm"})


class Trace:
    """Collects events; listeners see each event as it is recorded."""

    def __init__(self, keep: bool = True) -> None:
        self.events: list[Event] = []
        self.keep = keep
        self.seq = 0
        self.counter = 0  # the fieldbus event counter
        self._listeners: list[Callable[[Event], None]] = []

    def subscribe(self, listener: Callable[[Event], None]) -> Callable[[], None]:
        self._listeners.append(listener)
        return lambda: self._listeners.remove(listener)

    def record(self, t: float, event: str, proc: int, where: tuple[str, int, int | None] | None,
               fields: dict[str, Any]) -> Event:
        self.seq += 1
        entry: Event = {"seq": self.seq, "t": round(t, 6), "event": event, "proc": proc}
        if where is not None:
            entry["prog"], entry["line"], entry["n"] = where
        entry.update(fields)
        if event in COUNTED:
            self.counter = (self.counter + 1) & 0xFFFFFFFF
        if self.keep:
            self.events.append(entry)
        for listener in self._listeners:
            listener(entry)
        return entry


def to_jsonl(event: Event) -> str:
    rest = {k: v for k, v in event.items() if k not in ("seq", "t")}
    body = json.dumps(rest, separators=(", ", ": "), ensure_ascii=False)
    return f'{{"seq": {event["seq"]}, "t": {event["t"]:.6f}, {body[1:]}'


def write_jsonl(events: Iterable[Event], out: TextIO) -> None:
    for event in events:
        out.write(to_jsonl(event))
        out.write("\n")
