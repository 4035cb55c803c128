"""Bulk work without the cyclic collector: a parse of a large program, a closed simulation.

Both allocate many objects that hold no reference cycles and live to the end; the collections
those allocations trigger would scan the growing heap for nothing.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

from ncgate.interpreter import heap


@contextmanager
def gc_paused() -> Iterator[None]:
    """Pause the cyclic collector while a bulk parse allocates.

    A parse keeps every node alive, so each collection the allocations trigger scans the whole
    growing tree for nothing (nodes hold no reference cycles): on CPython 3.11 that tripled the
    cost of parsing a large program.  Reference counting still frees everything as usual.
    Nested uses are fine: only the outermost one re-enables the collector.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            # Promote what the parse built straight to the oldest generation (freeze then
            # unfreeze: two list splices), so the first young collection after this does not
            # traverse the whole new tree once more.  Full collections still see it.
            gc.freeze()
            if not heap.kept():  # else the heap stays frozen until the kept parse goes
                gc.unfreeze()
            gc.enable()
