"""The IEC 61131-3 standard function blocks and functions for the soft PLC's Structured
Text: timers, edge detectors, counters, bistables; the numeric, selection and bit-shift
functions; integer wrap-around as on a PLC.

A function block instance keeps its state between calls.  Timers take the scan's time in
milliseconds (``now_ms``), which is the virtual clock's in ``sim`` and the wall clock's in
``run``: a TON in a 10 ms scan sees time move in 10 ms steps, as on a real PLC.

Definitions follow IEC 61131-3 (3rd ed., 6.6.3.5); where the standard's text and common
practice differ, ncgate follows the practice of CODESYS/TwinCAT and says so:

- F_TRIG gives no pulse on its first call when CLK is FALSE (the standard's literal
  definition, with M initially FALSE, would): it detects a TRUE -> FALSE transition only.
- TP's ET goes back to 0 only when the pulse is over and IN is FALSE.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

# ---- elementary integer types: (bits, signed) ----------------------------------------------

INTEGER_TYPES: dict[str, tuple[int, bool]] = {
    "SINT": (8, True), "INT": (16, True), "DINT": (32, True), "LINT": (64, True),
    "USINT": (8, False), "UINT": (16, False), "UDINT": (32, False), "ULINT": (64, False),
    "BYTE": (8, False), "WORD": (16, False), "DWORD": (32, False), "LWORD": (64, False),
    "TIME": (32, True),  # milliseconds
    "LTIME": (64, True),  # nanoseconds
    "DATE": (32, False), "DT": (32, False),  # seconds since 1970-01-01
    "TOD": (32, False),  # milliseconds since midnight (wraps at 24 h: see wrap_code)
}


def wrap(value: int, type_name: str) -> int:
    """An integer result stored in ``type_name``: it wraps around as on a PLC."""
    bits, signed = INTEGER_TYPES[type_name]
    value &= (1 << bits) - 1
    if signed and value >> (bits - 1):
        value -= 1 << bits
    return value


def limits(type_name: str) -> tuple[int, int]:
    bits, signed = INTEGER_TYPES[type_name]
    return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)


# ---- timers --------------------------------------------------------------------------------

# A timer call whose outputs depended on the time (it runs: its elapsed time is below PT)
# takes a number here.  A scan's end state can hide such a call -- a TON called twice with a
# long and a short PT ends every scan saturated by the short one, while the first call's Q
# waits for the time -- so the scan (plc/scan.py) asks whether any call took one, and such a
# scan is never judged still.  (``next`` on a count is atomic: several runtimes in threads
# only make each other's scans less often still, never wrongly.)
RUNNING = itertools.count()
# Such a call also leaves its time and when its Q will change (``_ran``, ``_due``: ms) in the
# instance -- not a member of the FB (RETAIN, the state compared, the debugger know nothing of
# them): ``sim`` leaps over the scans whose only change is a running timer's ET, up to the
# first due (plc/scan.py, a timed still scan).


@dataclass
class Timer:
    """The interface IEC gives TON, TOF and TP: IN and PT in, Q and ET out (ms)."""

    IN: bool = False
    PT: int = 0
    Q: bool = False
    ET: int = 0

    def __post_init__(self) -> None:
        self._ran: int | None = None  # (the time of the last call that ran, and its due)
        self._due = 0

    def catch_up(self, now_ms: int) -> None:
        """A running timer's ET as a call at ``now_ms`` before its due would leave it (the
        scans ``sim`` leapt over, or the last of them at the run's end)."""
        raise NotImplementedError


@dataclass
class TON(Timer):
    """On-delay: Q rises PT after IN rose, while IN stays TRUE; ET counts up to PT."""

    _start: int | None = None

    def __call__(self, now_ms: int) -> None:
        if not self.IN:
            self.Q, self.ET, self._start = False, 0, None
            return
        if self._start is None:
            self._start = now_ms
        self.ET = min(now_ms - self._start, self.PT)
        self.Q = self.ET >= self.PT
        if not self.Q:
            next(RUNNING)
            self._ran, self._due = now_ms, self._start + self.PT

    def catch_up(self, now_ms: int) -> None:
        if self.IN and self._start is not None and not self.Q:
            self.ET = min(now_ms - self._start, self.PT)


@dataclass
class TOF(Timer):
    """Off-delay: Q follows IN up at once and falls PT after IN fell; ET counts from the fall."""

    _start: int | None = None

    def __call__(self, now_ms: int) -> None:
        if self.IN:
            self.Q, self.ET, self._start = True, 0, None
            return
        if not self.Q:
            return  # off, ET stays where it ended (PT, or 0 if never on)
        if self._start is None:
            self._start = now_ms  # IN just fell
        self.ET = min(now_ms - self._start, self.PT)
        if self.ET >= self.PT:
            self.Q, self._start = False, None
        else:
            next(RUNNING)
            self._ran, self._due = now_ms, self._start + self.PT

    def catch_up(self, now_ms: int) -> None:
        if not self.IN and self.Q and self._start is not None:
            self.ET = min(now_ms - self._start, self.PT)


@dataclass
class TP(Timer):
    """Pulse: a rising IN starts a pulse of PT (Q TRUE); changes of IN during it are ignored."""

    _start: int = 0

    def __call__(self, now_ms: int) -> None:
        if not self.Q and self.IN and self.ET == 0:
            self.Q, self._start = True, now_ms
        if self.Q:
            self.ET = min(now_ms - self._start, self.PT)
            if self.ET >= self.PT:
                self.Q = False
            else:
                next(RUNNING)
                self._ran, self._due = now_ms, self._start + self.PT
        if not self.Q and not self.IN:
            self.ET = 0

    def catch_up(self, now_ms: int) -> None:
        if self.Q:
            self.ET = min(now_ms - self._start, self.PT)


# ---- edge detectors ------------------------------------------------------------------------

@dataclass
class R_TRIG:
    """Q is TRUE for the one call in which CLK went FALSE -> TRUE (also on the first call)."""

    CLK: bool = False
    Q: bool = False
    _m: bool = False

    def __call__(self, now_ms: int = 0) -> None:
        self.Q = self.CLK and not self._m
        self._m = self.CLK


@dataclass
class F_TRIG:
    """Q is TRUE for the one call in which CLK went TRUE -> FALSE."""

    CLK: bool = False
    Q: bool = False
    _m: bool = False  # CLK of the last call

    def __call__(self, now_ms: int = 0) -> None:
        self.Q = not self.CLK and self._m
        self._m = self.CLK


# ---- counters (INT: CV stops at the type's limits) -----------------------------------------

@dataclass
class CTU:
    CU: bool = False
    R: bool = False
    PV: int = 0
    Q: bool = False
    CV: int = 0
    _cu: R_TRIG = field(default_factory=R_TRIG)  # IEC: CU is edge-triggered

    def __call__(self, now_ms: int = 0) -> None:
        edge = _rise(self._cu, self.CU)
        if self.R:
            self.CV = 0
        elif edge and limits("INT")[1] > self.CV:
            self.CV += 1
        self.Q = self.CV >= self.PV


@dataclass
class CTD:
    CD: bool = False
    LD: bool = False
    PV: int = 0
    Q: bool = False
    CV: int = 0
    _cd: R_TRIG = field(default_factory=R_TRIG)

    def __call__(self, now_ms: int = 0) -> None:
        edge = _rise(self._cd, self.CD)
        if self.LD:
            self.CV = self.PV
        elif edge and limits("INT")[0] < self.CV:
            self.CV -= 1
        self.Q = self.CV <= 0


@dataclass
class CTUD:
    CU: bool = False
    CD: bool = False
    R: bool = False
    LD: bool = False
    PV: int = 0
    QU: bool = False
    QD: bool = False
    CV: int = 0
    _cu: R_TRIG = field(default_factory=R_TRIG)
    _cd: R_TRIG = field(default_factory=R_TRIG)

    def __call__(self, now_ms: int = 0) -> None:
        up, down = _rise(self._cu, self.CU), _rise(self._cd, self.CD)
        lo, hi = limits("INT")
        if self.R:
            self.CV = 0
        elif self.LD:
            self.CV = self.PV
        elif not (up and down):
            if up and hi > self.CV:
                self.CV += 1
            elif down and lo < self.CV:
                self.CV -= 1
        self.QU = self.CV >= self.PV
        self.QD = self.CV <= 0


def _rise(trig: R_TRIG, clk: bool) -> bool:
    trig.CLK = clk
    trig()
    return trig.Q


# ---- bistables -----------------------------------------------------------------------------

@dataclass
class SR:
    """Set dominant: Q1 := S1 OR (NOT R AND Q1)."""

    S1: bool = False
    R: bool = False
    Q1: bool = False

    def __call__(self, now_ms: int = 0) -> None:
        self.Q1 = self.S1 or (not self.R and self.Q1)


@dataclass
class RS:
    """Reset dominant: Q1 := NOT R1 AND (S OR Q1)."""

    S: bool = False
    R1: bool = False
    Q1: bool = False

    def __call__(self, now_ms: int = 0) -> None:
        self.Q1 = not self.R1 and (self.S or self.Q1)


FUNCTION_BLOCKS = {cls.__name__: cls for cls in (TON, TOF, TP, R_TRIG, F_TRIG, CTU, CTD, CTUD,
                                                 SR, RS)}


# ---- functions -----------------------------------------------------------------------------

def LIMIT(mn: float, value: float, mx: float) -> float:
    return min(max(value, mn), mx)


def SEL(g: bool, in0: object, in1: object) -> object:
    return in1 if g else in0


def MUX(k: int, *inputs: object) -> object:
    if not 0 <= k < len(inputs):
        raise IndexError(f"MUX selector {k} outside 0..{len(inputs) - 1}")
    return inputs[k]


def SHL(value: int, n: int, type_name: str = "DWORD") -> int:
    bits = INTEGER_TYPES[type_name][0]
    return (value << n) & ((1 << bits) - 1)


def SHR(value: int, n: int, type_name: str = "DWORD") -> int:
    bits = INTEGER_TYPES[type_name][0]
    return (value & ((1 << bits) - 1)) >> n


def ROL(value: int, n: int, type_name: str = "DWORD") -> int:
    bits = INTEGER_TYPES[type_name][0]
    mask, n = (1 << bits) - 1, n % bits
    value &= mask
    return ((value << n) | (value >> (bits - n))) & mask


def ROR(value: int, n: int, type_name: str = "DWORD") -> int:
    bits = INTEGER_TYPES[type_name][0]
    return ROL(value, bits - n % bits, type_name)


def convert(value: float | bool, to: str) -> float | int | bool:
    """``<FROM>_TO_<TO>``: to a REAL the value as it is; to an integer type rounded to the
    nearest (halves to even, as IEC 61131-3 says for REAL_TO_INT) and wrapped; to BOOL, not 0."""
    if to in ("REAL", "LREAL"):
        return float(value)
    if to == "BOOL":
        return value != 0
    return wrap(round(value), to)
