"""Motion planning: how long a block's motion takes (spec 2.4).

G0 at the rapid rate, G1/G2/G3 at the modal feed (mm/min), arcs by their true length from
I/J/K (or R) in the active plane, with a helical component along the third axis.  G90/G91
absolute/incremental, G17/G18/G19 planes.  Positions are in mm.

A move is checked where it is decoded, as a control checks its soft limits: an end point past
an axis's travel limit is AL131 and a move that would take longer than a block may is AL132
(``RuntimeSettings.travel_limits``, ``block_limit_s``; docs/runtime.md).  Nothing absurd
reaches the queue, the clock or the fieldbus.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ncgate.interpreter.codes import AlarmCode
from ncgate.interpreter.diagnostics import RuntimeAlarm, fmt_number
from ncgate.interpreter.settings import AXES, RuntimeSettings

# An I/J/K arc's end must lie on the circle through its start (as LinuxCNC and real controls
# check): the two radii may differ by this much, absolute or relative, whichever is larger.
ARC_TOLERANCE_MM = 0.002
ARC_TOLERANCE_REL = 0.001
AXIS_INDEX = {a: i for i, a in enumerate(AXES)}
PLANES = {17: (0, 1, 2, "I", "J"), 18: (2, 0, 1, "K", "I"), 19: (1, 2, 0, "J", "K")}


@dataclass(slots=True)
class Modal:
    motion: int = 0  # 0 1 2 3
    feed_mm_min: float | None = None
    absolute: bool = True
    plane: int = 17
    tool: str = ""
    position: list[float] = field(default_factory=lambda: [0.0] * len(AXES))

    def g_word(self, g: int, planes: bool = True) -> None:
        """A G word's modal effect: G0..G3 motion, G90/G91 absolute/incremental, and (where
        the dialect has them) G17/G18/G19 planes; other G words change nothing here."""
        if g in (0, 1, 2, 3):
            self.motion = g
        elif g == 90:
            self.absolute = True
        elif g == 91:
            self.absolute = False
        elif planes and g in (17, 18, 19):
            self.plane = g

    def feed(self, mm_min: float) -> None:
        """An F word: the modal feed, which must be positive."""
        if mm_min <= 0:
            raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT,
                               f"F{fmt_number(mm_min)}: a feed must be positive")
        self.feed_mm_min = mm_min


@dataclass(frozen=True, slots=True)
class Move:
    start: tuple[float, ...]
    end: tuple[float, ...]
    length_mm: float
    duration_s: float
    rapid: bool = False  # G0: the rapid override applies, not the feed override


def plan_move(modal: Modal, axes: dict[str, float], arc: dict[str, float],
              settings: RuntimeSettings) -> Move | None:
    """The move a block's axis words make from the modal state (updates the position);
    RuntimeAlarm AL131 past a soft travel limit, AL132 for a move longer than a block may
    take."""
    start = tuple(modal.position)
    end = list(start)
    limits = settings.travel_limits
    for letter, value in axes.items():
        i = AXIS_INDEX[letter]
        end[i] = value if modal.absolute else start[i] + value
        lo, hi = limits[i]
        if not lo <= end[i] <= hi:  # NaN too
            raise RuntimeAlarm(AlarmCode.SOFT_LIMIT,
                               f"{letter}{fmt_number(end[i])} is past the soft travel limit "
                               f"{letter}{fmt_number(lo if end[i] < lo else hi)} "
                               f"(nc.limits.{letter})")
    is_arc = modal.motion in (2, 3) and (arc or axes)
    if not axes and not is_arc:
        return None
    if modal.motion in (2, 3):
        length = _arc_length(modal, start, end, arc)
    else:
        length = math.dist(start[:6], end[:6]) or math.dist(start[6:], end[6:])
    if modal.motion == 0:
        rate = settings.rapid_mm_min
    else:
        if not modal.feed_mm_min:
            raise RuntimeAlarm(AlarmCode.NO_FEED,
                               f"G{modal.motion} move with no feed (F) programmed")
        rate = modal.feed_mm_min
    duration = length / rate * 60.0
    if not math.isfinite(duration):  # coordinates near the limits of a double
        raise RuntimeAlarm(AlarmCode.VALUE_OUT_OF_RANGE, "the move is too long to represent")
    check_duration(duration, settings, f"the move ({fmt_number(length)} mm at "
                   f"{fmt_number(rate)} mm/min)")
    modal.position = end
    return Move(start, tuple(end), length, duration, modal.motion == 0)


def check_duration(seconds: float, settings: RuntimeSettings, what: str) -> None:
    """AL132 when one block's motion or dwell would take longer than ``block_limit_s``."""
    if not seconds <= settings.block_limit_s:
        raise RuntimeAlarm(AlarmCode.BLOCK_TOO_LONG,
                           f"{what} would take {fmt_number(seconds)} s, more than "
                           f"nc.limits.block_s = {fmt_number(settings.block_limit_s)} s")


def _arc_length(modal: Modal, start: tuple[float, ...], end: list[float],
                arc: dict[str, float]) -> float:
    a, b, c, ia, ib = PLANES[modal.plane]
    sa, sb, ea, eb = start[a], start[b], end[a], end[b]
    helix = end[c] - start[c]
    clockwise = modal.motion == 2
    if "R" in arc:
        radius = abs(arc["R"])
        chord = math.hypot(ea - sa, eb - sb)
        if radius == 0 or chord > 2 * radius + 1e-9:
            raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT,
                               f"arc radius {arc['R']:g} cannot reach the end point")
        sweep = 2 * math.asin(min(1.0, chord / (2 * radius)))
        if arc["R"] < 0:
            sweep = 2 * math.pi - sweep
    else:
        ca, cb = sa + arc.get(ia, 0.0), sb + arc.get(ib, 0.0)
        radius = math.hypot(sa - ca, sb - cb)
        if radius == 0:
            raise RuntimeAlarm(AlarmCode.BAD_ARGUMENT, "arc with no radius (I/J/K missing)")
        end_radius = math.hypot(ea - ca, eb - cb)
        if abs(end_radius - radius) > max(ARC_TOLERANCE_MM, ARC_TOLERANCE_REL * radius):
            raise RuntimeAlarm(
                AlarmCode.BAD_ARGUMENT,
                f"arc end point is not on its circle: radius {radius:.4f} mm at the start, "
                f"{end_radius:.4f} mm at the end")
        a0 = math.atan2(sb - cb, sa - ca)
        a1 = math.atan2(eb - cb, ea - ca)
        sweep = (a0 - a1) if clockwise else (a1 - a0)
        sweep %= 2 * math.pi
        if sweep < 1e-12:  # end on start: a full circle
            sweep = 2 * math.pi
    return math.hypot(radius * sweep, helix)
