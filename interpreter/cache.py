"""The table of a program's parsed (or compiled) blocks: every block of a program of up to
BIG_LINES lines, the last CACHED_BLOCKS used of a longer one.

A parsed block is a few dozen objects the garbage collector walks in every full collection:
with 20,000 blocks of a 10 MB program parsed, one took 89 ms (4,096 blocks: 10 ms; 1,024:
4 ms), and a program run for a shift parses all of its 489,000.  A long program's blocks are
parsed and compiled again when they run again, as a control that streams a program from
disk reads it again: about 27 µs a block, so a loop over more than CACHED_BLOCKS blocks of
a long program decodes about half as fast as with every block kept (its trace the same).
"""

from __future__ import annotations

from typing import TypeVar

T = TypeVar("T")

BIG_LINES = 65_536  # longer programs keep only their last CACHED_BLOCKS blocks
CACHED_BLOCKS = 1_024


class BlockCache(dict[int, T]):
    """Line index -> block, None for a block not (or no longer) kept, at most ``limit``
    blocks: the oldest goes when a new one comes (insertion order)."""

    __slots__ = ("limit",)

    def __init__(self, limit: int = CACHED_BLOCKS) -> None:
        super().__init__()
        self.limit = limit

    def __missing__(self, key: int) -> None:
        return None

    def __setitem__(self, key: int, value: T) -> None:
        if len(self) >= self.limit and key not in self:
            del self[next(iter(self))]
        super().__setitem__(key, value)


def block_table(lines: int) -> list[T | None] | BlockCache[T]:
    """The table for a program of ``lines`` lines: indexed alike, ``table[i]`` is the block
    or None; only a short program's is a list of them all."""
    return [None] * lines if lines <= BIG_LINES else BlockCache(CACHED_BLOCKS)
