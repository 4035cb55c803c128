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
