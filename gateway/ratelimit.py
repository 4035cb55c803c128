"""The one rate-limited log line every adapter uses for what a client can make happen at any
rate (refusals, evictions, RPDOs not applied, commands refused after their answer).

At most one line per ``interval_s``; the lines held back are counted, and the count is said
with the next line -- or, when the flood stops, on its own once the interval has passed (on
the loop that logged; :meth:`flush` says it at close).  Safe from any thread.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time


class RateLimitedLog:
    def __init__(self, logger: logging.Logger, interval_s: float = 1.0,
                 level: int = logging.WARNING) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self.level = level
        self.last = float("-inf")
        self.held = 0
        self._last_held = ""
        self._lock = threading.Lock()
        self._timer: asyncio.TimerHandle | None = None

    def note(self, line: str) -> None:
        now = time.monotonic()
        with self._lock:
            if now - self.last < self.interval_s:
                self.held += 1
                self._last_held = line
                self._arm(now)
                return
            more = f" (and {self.held} more like it)" if self.held else ""
            self.held = 0
            self.last = now
        self.logger.log(self.level, "%s%s", line, more)

    def _arm(self, now: float) -> None:
        if self._timer is not None:
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # another thread: said with the next line or at flush()
            return
        self._timer = loop.call_later(max(0.0, self.last + self.interval_s - now) + 0.001,
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
            held, last = self.held, self._last_held
            self.held = 0
            self.last = time.monotonic()
        if held:
            self.logger.log(self.level, "%d more like: %s", held, last)
