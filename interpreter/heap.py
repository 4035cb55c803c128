"""A big parse kept whole, out of the garbage collector's full collections.

The ISG reader keeps a file parsed whole (its sections share one parse): about 19 tracked
objects a line, 9 million for 10 MB.  A full collection walks every tracked object while it
holds the interpreter's lock, so every thread -- the event loop serving the fieldbus, the
CAN receive thread -- waits for it.  While such a file was parsed in a reading thread, the
collector ran a full collection each time the heap had grown by a quarter: 0.25 s, then
0.4, ... 2.6 s for 10 MB, and the loop stood still each time; once the parse was kept, every
later full collection walked it again.

So, for a parse of at least :data:`BIG_BYTES`:

- :func:`building` postpones full collections while it is built (the young generations are
  collected as usual);
- :func:`keep` then freezes the heap (``gc.freeze``: everything alive moves to the permanent
  generation, which no collection walks) and, when the last parse so kept is freed, hands
  the permanent generation back to the collector (``gc.unfreeze``).

A frozen object that dies is still freed by its reference count; only a reference cycle
among frozen objects waits for the unfreeze.  The parse itself has no cycles (a test says
so), so a kept file that is replaced or dropped is freed at once, and whatever cyclic
garbage was frozen with it (the PLC logic a reload replaced meanwhile) is collected after
the last one goes: nothing is kept for ever.  The thresholds are the process's: a program
that changes them while a big parse is built gets its own back only when it ends.
"""

from __future__ import annotations

import gc
import threading
import weakref
from collections.abc import Iterator
from contextlib import contextmanager

BIG_BYTES = 512 * 1024  # as the NC-110 reader's child (interpreter/nc110/dialect.py)
# gc's third threshold: how many collections of the middle generation come before a full
# one is considered.  This many never come while a parse is built.
POSTPONED = 1 << 30

_lock = threading.RLock()  # RLock: a finalizer may run on a thread inside one of these
_building = 0
_saved: tuple[int, int, int] | None = None
_kept = 0


@contextmanager
def building() -> Iterator[None]:
    """No full collection while the body runs (in any thread: one may build, the loop run)."""
    global _building, _saved
    with _lock:
        if _building == 0:
            _saved = gc.get_threshold()
            gc.set_threshold(_saved[0], _saved[1], POSTPONED)
        _building += 1
    try:
        yield
    finally:
        with _lock:
            _building -= 1
            if _building == 0 and _saved is not None:
                gc.set_threshold(*_saved)
                _saved = None


def keep(parse: object) -> None:
    """``parse`` (weak-referenceable) was just built and is kept: freeze the heap until the
    last parse kept this way is freed."""
    global _kept
    with _lock:
        _kept += 1
        gc.freeze()
    weakref.finalize(parse, _released)


def _released() -> None:
    global _kept
    with _lock:
        _kept -= 1
        if _kept == 0:
            gc.unfreeze()


def kept() -> int:
    """How many kept parses are alive (the heap is frozen while there is one)."""
    return _kept
