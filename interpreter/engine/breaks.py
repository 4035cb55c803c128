"""Breakpoints: where the engine stops a cell being brought up.

A breakpoint is written as an engineer says it:

    PROG92:8        the block on line 8 of PROG92 (the file's stem), in any process
    N40             any block N40, in any process
    P2 PROG92:8     (P2 N40) the same, in process 2 only
    P2 wait         process 2 entering any wait; ``P2 wait WAI`` (EXE, SND, COND, SIGNAL,
                    FLUSH): a wait of that kind
    wait            any process entering any wait
    sync            run to sync: the next EXE/WAI/SND/REL/#SIGNAL/#WAIT of any process
                    (one-shot: it clears itself when hit)

A hit stops the cell with feed-hold semantics, resumable: the process that reached a block
breakpoint stops before that block (STEP), every other process holds; a cycle start goes on.
The trace gets a ``break`` event naming the breakpoint and the process.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final

from ncgate.interpreter.engine.states import WaitKind

# ASCII digits only, and a bounded count (a process, a line, an N number).
_PROCESS: Final = re.compile(r"P([0-9]{1,3})\s+(.*)$", re.IGNORECASE)
_LINE: Final = re.compile(r"([^\s:]+):([0-9]{1,9})$")
_N: Final = re.compile(r"N([0-9]{1,9})$", re.IGNORECASE)
MAX_BREAKPOINTS: Final = 256  # set at once: a commissioning session needs a handful
# A wait's kind as written after "wait": the WaitKind, or the dialect's signal wait.
WAIT_KINDS: Final = {"WAI": WaitKind.PROC, "PROC": WaitKind.PROC, "COND": WaitKind.COND,
                     "SND": WaitKind.SND, "EXE": WaitKind.EXE, "FLUSH": WaitKind.FLUSH,
                     "SIGNAL": WaitKind.PROC}


@dataclass(frozen=True, slots=True)
class Breakpoint:
    text: str  # as written, normalised: what the trace's ``break`` event names
    process: int | None = None  # None: any process
    program: str | None = None  # a block breakpoint: the file's stem (upper case) and line
    line: int | None = None
    n: int | None = None  # a block breakpoint by N number
    wait: bool = False  # a wait breakpoint
    wait_kind: WaitKind | None = None  # None: any wait
    sync: bool = False  # run to sync (one-shot)

    @property
    def at_block(self) -> bool:
        return self.line is not None or self.n is not None

    def matches_block(self, process: int, file: str, line: int, n: int | None) -> bool:
        if self.process is not None and self.process != process:
            return False
        if self.n is not None:
            return n == self.n
        stem = file.replace("\\", "/").rsplit("/", 1)[-1].rsplit(".", 1)[0].upper()
        return line == self.line and stem == self.program

    def matches_wait(self, process: int, kind: WaitKind) -> bool:
        if not self.wait or (self.process is not None and self.process != process):
            return False
        return self.wait_kind is None or self.wait_kind is kind


def parse_breakpoint(text: str) -> Breakpoint:
    """The breakpoint ``text`` names; ValueError saying what is wrong."""
    if not isinstance(text, str) or not text.strip():
        raise ValueError("a breakpoint: PROG92:8, N40, P2 wait, sync, ...")
    rest = " ".join(text.split())
    process = None
    m = _PROCESS.match(rest)
    if m is not None:
        process = int(m.group(1))
        if process < 1:
            raise ValueError(f"{text!r}: processes count from 1")
        rest = m.group(2)
    prefix = f"P{process} " if process is not None else ""
    if rest.lower() == "sync":
        if process is not None:
            raise ValueError(f"{text!r}: run to sync stops the whole cell (write 'sync')")
        return Breakpoint("sync", sync=True)
    words = rest.split()
    if words and words[0].lower() == "wait":
        if len(words) == 1:
            return Breakpoint(f"{prefix}wait", process, wait=True)
        kind = WAIT_KINDS.get(words[1].upper()) if len(words) == 2 else None
        if kind is None:
            raise ValueError(f"{text!r}: a wait of kind {', '.join(WAIT_KINDS)}")
        return Breakpoint(f"{prefix}wait {words[1].upper()}", process, wait=True,
                          wait_kind=kind)
    m = _N.match(rest)
    if m is not None:
        return Breakpoint(f"{prefix}N{int(m.group(1))}", process, n=int(m.group(1)))
    m = _LINE.match(rest)
    if m is not None and int(m.group(2)) >= 1:
        stem = m.group(1).rsplit(".", 1)[0].upper()
        return Breakpoint(f"{prefix}{stem}:{int(m.group(2))}", process, program=stem,
                          line=int(m.group(2)))
    raise ValueError(f"{text!r}: a breakpoint is PROG:LINE, N<number>, wait [KIND] (each "
                     "optionally after P<k>), or sync")
