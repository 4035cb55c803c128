"""What a TPDO or an SDO read of the image may map, as the asyncio loop last published it.

The loop owns the image and the processes (ARCHITECTURE.md, "The runtime"); python-can's
receive thread answers a SYNC with the synchronous TPDOs, and an SDO read of the image, at
once, without waiting for the loop.  So the node publishes a :class:`Snapshot`, frozen, and
swapped whole in one assignment; the receive thread reads only that.

- The image: inside every write, once all of its values are stored.
- A process's status record (state, wait, alarm, SND counts: the first eight of the cell
  view's record) and the last SND: noted by the node's state and trace listeners, and
  published once the loop's callback in which they changed is over (the engine's turn, the
  write), or sooner, before the loop builds a synchronous TPDO's frame from them; only while
  a TPDO is synchronous, since nothing else reads them off the loop (all of them are
  published when one becomes so).
- Sampled, as they change with every block and every scan without an event: a process's
  block N and source line (with its record), and the PLC status; the loop samples them again
  after each SYNC that sent them, so a SYNC sends them as of the SYNC before at the oldest.

Imports the dictionary's layout only; nothing of canopen, the engine or the image.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ncgate.gateway.canopen.dictionary import (
    COMMAND,
    LAST_SND,
    PLC_STATUS,
    STATUS_BASE,
    image_target,
)

STATUS_ENTRIES = 8  # 0x2500+k-1 sub 1..8: state, N, line, wait kind and target, alarm, SNDs
PLC_ENTRIES = 6  # 0x2700 sub 1..6


@dataclass(frozen=True, slots=True)
class Snapshot:
    """The values behind the mappable manufacturer objects, as of one moment of the loop."""

    sa: bytes = b""  # 0x2000
    k: bytes = b""  # 0x2100+j
    syvar: tuple[int, ...] = ()  # 0x2200+j
    status: tuple[tuple[int, ...], ...] = ()  # process k: [k - 1], sub-index s: [s - 1]
    last_snd: tuple[int, ...] = (0, 0, 0, 0)  # 0x2600 sub 1..4
    plc: tuple[int, ...] = (0,) * PLC_ENTRIES  # 0x2700 sub 1..6


def sampled(index: int, subindex: int) -> bool:
    """Whether an object's value changes without an event the node hears (a process's block
    N and source line, the PLC status): the loop samples it again after a SYNC sent it, and
    before a frame it builds itself."""
    return (STATUS_BASE <= index < LAST_SND and subindex in (2, 3)) or index == PLC_STATUS


def getter(index: int, subindex: int) -> Callable[[Snapshot], int]:
    """A readable mappable object's value in a snapshot (the dictionary says which are;
    :func:`ncgate.gateway.canopen.pdo.mapped_bits` refuses a mapping of any other)."""
    if index < COMMAND:
        area, i, _ = image_target(index, subindex)
        if area == "SA":
            return lambda s: s.sa[i]
        if area == "SK":
            return lambda s: s.k[i]
        return lambda s: s.syvar[i]
    j = subindex - 1
    if STATUS_BASE <= index < LAST_SND:
        k = index - STATUS_BASE
        return lambda s: s.status[k][j]
    if index == LAST_SND:
        return lambda s: s.last_snd[j]
    if index == PLC_STATUS:
        return lambda s: s.plc[j]
    raise ValueError(f"0x{index:04X}:{subindex} is not a mappable value")


def plc_record(registers: Sequence[int]) -> tuple[int, ...]:
    """0x2700 sub 1..6 from the PLC status block (``ncgate.gateway.plc.plc_registers``):
    the state, four 32-bit counters (high word first), the fault line."""
    return (registers[0], *(registers[2 * s - 3] << 16 | registers[2 * s - 2]
                            for s in range(2, PLC_ENTRIES)), registers[9])
