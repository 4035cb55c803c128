"""The one rate-limited log every adapter uses for what a client can make happen at any rate
(refusals, evictions, RPDOs not applied, commands refused after their answer) and for the run
log's sync lines.

At most ``burst`` lines per ``interval_s``; the lines held back are counted, and the count is
said with the next line -- or, when the flood stops, on its own once the interval has passed
(on the loop that logged; :meth:`flush` says it at close).  Safe from any thread.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from typing import Any


class RateLimitedLog:
    def __init__(self, logger: logging.Logger, interval_s: float = 1.0,
                 level: int = logging.WARNING, burst: int = 1,
                 held: str = "%d more like: %s") -> None:
        """``held``: how a count said on its own reads (``%d``, then the last line held)."""
        self.logger = logger
        self.interval_s = interval_s
        self.level = level
        self.burst = burst
        self.held_format = held
        self.window = float("-inf")  # when the current interval began
        self.used = 0
        self.held = 0
        self._last_held = ""
        self._lock = threading.Lock()
        self._timer: asyncio.TimerHandle | None = None

    def take(self) -> bool:
        """May a line go out now?  False: it is counted as held back."""
        now = time.monotonic()
        with self._lock:
            if now - self.window >= self.interval_s:
                self.window, self.used = now, 0
            if self.used < self.burst:
                self.used += 1
                return True
            self.held += 1
        self._arm(now)
        return False

    def note(self, line: str) -> None:
        """Log ``line`` if the budget allows (with the count held back before it)."""
        if not self.take():
            self._last_held = line
            return
        with self._lock:
            held, self.held = self.held, 0
        more = f" (and {held} more like it)" if held else ""
        self.logger.log(self.level, "%s%s", line, more)

    def _arm(self, now: float) -> None:
        if self._timer is not None:
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # another thread: said with the next line or at flush()
            return
        self._timer = loop.call_later(max(0.0, self.window + self.interval_s - now) + 0.001,
                                      self._tick)

    def _tick(self) -> None:
        self._timer = None
        self.flush()

    def flush(self) -> None:
        """Say how many lines were held back since the last one, if any."""
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
            held, self.held = self.held, 0
        if held:
            if "%s" in self.held_format:
                self.logger.log(self.level, self.held_format, held, self._last_held)
            else:
                self.logger.log(self.level, self.held_format, held)


class LogFlood(logging.Filter):
    """The same budget for the lines of a library that logs for itself (asyncua logs an ERROR
    for every request it refuses: 40,000 abusive requests gave 40,000 lines).  Put on a
    handler: each kind of line (its logger and message template) gets at most ``burst`` lines
    per ``interval_s``; the count held back is said with the next line of its kind, and by
    :meth:`flush` (at the process's end)."""

    MAX_KINDS = 256  # templates are the library's code: past this, the counts start again

    def __init__(self, interval_s: float = 10.0, burst: int = 5) -> None:
        super().__init__()
        self.interval_s = interval_s
        self.burst = burst
        self._kinds: dict[tuple[str, object], list[Any]] = {}  # [window, used, held, last]
        self._lock = threading.Lock()

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, record.msg if isinstance(record.msg, str) else type(record.msg))
        now = time.monotonic()
        with self._lock:
            kind = self._kinds.get(key)
            if kind is None:
                if len(self._kinds) >= self.MAX_KINDS:
                    self._kinds.clear()
                kind = self._kinds[key] = [float("-inf"), 0, 0, ""]
            if now - kind[0] >= self.interval_s:
                kind[0], kind[1] = now, 0
            if kind[1] >= self.burst:
                kind[2] += 1
                kind[3] = record.getMessage()
                return False
            kind[1] += 1
            held, kind[2] = kind[2], 0
        if held:
            record.msg, record.args = f"{record.getMessage()} (and {held} more like it)", None
        return True

    def flush(self, logger: logging.Logger) -> None:
        """Say each count held back since its kind's last line, on ``logger``."""
        with self._lock:
            held = [(kind[2], kind[3]) for kind in self._kinds.values() if kind[2]]
            for kind in self._kinds.values():
                kind[2] = 0
        for count, last in held:
            logger.warning("%d more like: %s", count, last)
