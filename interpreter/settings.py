"""What the engine is told by its owner: :class:`RuntimeSettings` and the choices in it.

A leaf module (stdlib only): ``ncgate.config`` reads the user's TOML into these same types, so a
choice such as :class:`SndPolicy` is defined here once.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Final

AXES: Final = "XYZUVWABC"  # the axis words, in the order of a position
# The soft travel limits of every axis unless configured: +-100 m (A, B, C: +-100,000 degrees).
# Far past any machine, so a program's real moves never meet them; what they stop is a typo or
# a runaway value (X1E300, TAN(90)) that would otherwise "run" and show nonsense positions.
TRAVEL_MM: Final = (-100_000.0, 100_000.0)
# The longest one block's motion, dwell or tool change may take unless configured: a day.  A
# real block takes seconds to hours; F0.0000001 would take two centuries.
BLOCK_S: Final = 86_400.0


class SndPolicy(enum.Enum):
    """What an SND does when its target does not wait for it yet (spec 2.2.4)."""

    RENDEZVOUS = "rendezvous"  # the sender waits (WAIT_SND) until the target waits for it
    LATCHED = "latched"  # never blocks: a token per sender->target pair (TwinCAT-style)


class BlockSearchSync(enum.Enum):
    """Which programs a block search refuses for their synchronisation codes."""

    # Seed 000, section 4, note 4: "search is impossible on programs containing EXE, WAI,
    # SND" -- anywhere in the program, before the target or after it.
    REFUSE = "refuse"
    # Only when the blocks the search skips hold one (ncgate's rule before): the codes after
    # the target run as written.
    SKIPPED = "skipped"


class Dialect(enum.Enum):
    """The language of the part programs (spec 5.1)."""

    NC110 = "nc110"  # NC-110/NC-200: (EXE,…) (WAI,…) (SND,…), rendezvous SND
    ISG = "isg"  # TwinCAT CNC / ISG: channels, #SIGNAL / #WAIT / #FLUSH, stored signals


class Handshake(enum.Enum):
    """How an auxiliary function (M, S, T, H) meets the PLC ([nc.aux]; FANUC's MF/FIN,
    SINUMERIK's auxiliary functions with their acknowledgement)."""

    NONE = "none"  # the value is output; nothing waits for the PLC
    BEFORE_MOTION = "before_motion"  # value + strobe; the block's motion waits for the ack
    AFTER_MOTION = "after_motion"  # output when the motion ends; the next block waits


AUX_LETTERS: Final = "MSTH"  # the auxiliary words, in the order of their places
# M codes that keep the NC's own meaning and are not output: stop, optional stop, ends.
AUX_NC_CODES: Final = frozenset({0, 1, 2, 30})


@dataclass(frozen=True, slots=True)
class AuxSettings:
    """The auxiliary-function interface ([nc.aux]): where each process's values, strobes and
    acknowledges are in the image, and which handshake each code has.  Process k's letter
    i (``AUX_LETTERS``) is at the base + 4(k-1) + i (an SK word: + 2 bytes each)."""

    handshake: Handshake = Handshake.NONE
    codes: tuple[tuple[str, Handshake], ...] = ()  # "M8" (a code) or "T" (a letter's codes)
    timeout_s: float = 0.0  # 0: no timeout; else an alarm (AL145)
    value: tuple[str, int, str] = ("SYVAR", 192, "IN")  # P1's M value (SYVAR or SK .IN)
    strobe: int = 896  # the SA bit of P1's M strobe
    ack: int = 960  # the SA bit of P1's M acknowledge
    words: int = 1  # a value's words: 1 (16-bit) or 2 (32-bit, the high word first)

    def handshake_of(self, letter: str, value: int) -> Handshake:
        found = dict(self.codes)
        return found.get(f"{letter}{value}", found.get(letter, self.handshake))

    def place(self, process: int, letter: str) -> tuple[tuple[str, int, str], int, int]:
        """Process ``process``'s ``letter``: its value's variable, strobe bit, ack bit."""
        offset = 4 * (process - 1) + AUX_LETTERS.index(letter)
        area, index, view = self.value
        step = (2 if area == "SK" else 1) * self.words
        return (area, index + step * offset, view), self.strobe + offset, self.ack + offset

    def value_words(self, place: tuple[str, int, str], value: int) -> list[tuple[str, int, str,
                                                                                   int]]:
        """The image writes that put ``value`` at a value's ``place``: one int16 word, or
        two (the high word first, as a 32-bit value goes in two Modbus registers)."""
        area, index, view = place
        if self.words == 1:
            return [(area, index, view, value)]
        high, low = value >> 16, value & 0xFFFF
        return [(area, index, view, high),
                (area, index + (2 if area == "SK" else 1), view,
                 low - 0x10000 if low & 0x8000 else low)]


@dataclass(frozen=True, slots=True)
class RuntimeSettings:
    """The engine's settings; the names are those of ``[nc]`` in the config."""

    processes: int = 5
    external: frozenset[int] = frozenset()
    lookahead: int = 16
    snd: SndPolicy = SndPolicy.RENDEZVOUS
    sync_reads: bool = False
    rapid_mm_min: float = 10000.0
    tool_change_s: float = 2.0
    wait_timeout_s: float = 0.0
    e_params: int = 1000
    optional_skip: bool = False
    main: str | None = None
    # The program a cycle start of one process starts, for processes 2 up ([[nc.process]]
    # main); process 1's is ``main``.
    mains: tuple[tuple[int, str], ...] = ()
    feed_override: int = 100  # percent, every process's at start
    # The I/O names of [symbols], by variable: what a why-record shows beside the variable
    # ("waits for door_closed (SA10=1)").
    names: tuple[tuple[tuple[str, int, str], str], ...] = ()
    # Closed simulation: nothing outside can start a program (orphan-wait detection).
    closed: bool = True
    # Which programs a block search refuses for their EXE, WAI, SND (BlockSearchSync).
    block_search_sync: BlockSearchSync = BlockSearchSync.REFUSE
    # Blocks one process decodes before the others (and, under run, the fieldbus) get a turn.
    slice_blocks: int = 10_000
    # Blocks a process may decode without time passing before it is a runaway (0: no limit).
    runaway_blocks: int = 100_000
    # Processing time of each block, in milliseconds (0: blocks take no time).
    block_time_ms: float = 0.0
    # Soft travel limits, (min, max) for each axis of AXES in order, in mm (A, B, C: degrees):
    # a block that would move an axis past one is an alarm at decode (AL131).
    travel_limits: tuple[tuple[float, float], ...] = (TRAVEL_MM,) * len(AXES)
    # A block whose motion, dwell or tool change would take longer is an alarm (AL132).
    block_limit_s: float = BLOCK_S
    # The interpolator takes a block only from a full buffer (lookahead blocks), or once the
    # decoder has reached the end, a flush or a synchronous read: ISG's buffer effect.
    buffered: bool = False
    # The auxiliary-function interface ([nc.aux]); None: M, S, T and H words are not output
    # (no [nc.aux] table: today's behaviour).
    aux_interface: AuxSettings | None = None
