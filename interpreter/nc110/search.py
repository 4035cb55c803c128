"""Block search: start a program in the middle, at a label or an N number,
with the modal state the blocks before it would have set.

The blocks before the target are read in order, as the text has them, and nothing of them
acts: their G modes, feed, tool and end positions make the modal state the program starts
with; with calculation (``with_calc``) their E-parameter assignments are evaluated too.

A block search is refused, with the reason, in a program that holds an EXE, WAI or SND
anywhere (seed 000, section 4, note 4: "search is impossible on programs containing EXE, WAI,
SND"; ``nc.block_search_sync = "refuse"``, the default).  With ``"skipped"`` only the skipped
blocks count there.  Either way it is refused where the skipped blocks hold what cannot be
skipped without changing what the cell does: a synchronisation code (SND, WAI, EXE, REL), a
write of the image (SYVAR), a jump or a repeat (the text would not be the path the program
takes), or the program's end.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

from ncgate.interpreter.diagnostics import ProgramError, RuntimeAlarm
from ncgate.interpreter.motion import Modal, plan_move
from ncgate.interpreter.nc110.evaluate import compile_expr
from ncgate.interpreter.nc110.formatter import format_item
from ncgate.interpreter.nc110.nodes import (
    Assign,
    Branch,
    Display,
    Dwell,
    EndRepeat,
    Exe,
    InertCode,
    Jump,
    Rel,
    Repeat,
    Snd,
    VarKind,
    WaitCond,
    WaitProc,
    Word,
)
from ncgate.interpreter.nc110.parser import Program
from ncgate.interpreter.settings import BlockSearchSync, RuntimeSettings

_MOTION_WORDS = frozenset("XYZUVWABCIJKR")


class SearchRefused(ValueError):
    """The block search cannot start there; the message says why (file:line and the code)."""


def target_index(program: Program, at: str) -> int:
    """The 0-based line of ``at``: a label (``"START"``) or an N number (``N40``)."""
    text = at.strip()
    index = program.labels.get(text.upper().strip('"'))
    if index is not None:
        return index
    if text[:1] in "Nn" and text[1:].isdigit():
        n = int(text[1:])
        for i in range(len(program)):
            try:
                if program.block(i).number == n:
                    return i
            except ProgramError:
                continue
        raise SearchRefused(f"{program.file}: no block N{n}")
    raise SearchRefused(f"{program.file}: no label {text!r} (a label, or an N number: N40)")


def search(program: Program, at: str, modal: Modal, e_params: list[float],
           settings: RuntimeSettings, read: Callable[[str, int, str], int],
           with_calc: bool) -> tuple[int, Modal, list[float]]:
    """(the target's line index, the modal state, the E parameters) of a start at ``at``."""
    index = target_index(program, at)
    if settings.block_search_sync is BlockSearchSync.REFUSE:
        _refuse_sync(program)
    modal = copy.deepcopy(modal)
    e = list(e_params)
    for i in range(index):
        block = program.block(i)
        where = f"{program.file}:{i + 1}"
        axes: dict[str, float] = {}
        arc: dict[str, float] = {}
        for item in block.items:
            if isinstance(item, Word):
                value = item.value
                v = e[value.index] if not isinstance(value, float) else value
                if item.letter == "G":
                    modal.g_word(int(v))
                elif item.letter == "F" and v > 0:
                    modal.feed_mm_min = v
                elif item.letter == "T":
                    modal.tool = item.text
                elif item.letter == "M" and v in (2, 30):
                    raise SearchRefused(f"{where}: the program ends (M{int(v):02d}) before "
                                        f"{at}")
                elif item.letter in _MOTION_WORDS:
                    (arc if item.letter in "IJKR" else axes)[item.letter] = v
            elif isinstance(item, Assign):
                if item.target.kind is not VarKind.E:
                    raise SearchRefused(f"{where}: {format_item(item)} writes the image, which "
                                        "a block search would skip")
                if with_calc:
                    e[item.target.index] = compile_expr(item.expr)(e, read)
            elif isinstance(item, WaitProc | WaitCond | Snd | Exe | Rel):
                raise SearchRefused(f"{where}: {format_item(item)} is a synchronisation code: "
                                    "a block search cannot skip it (start before it)")
            elif isinstance(item, Jump | Branch | Repeat | EndRepeat):
                raise SearchRefused(f"{where}: {format_item(item)}: a block search reads the "
                                    "text in order, which is not the path a jump or a repeat "
                                    "takes")
            elif isinstance(item, Display | Dwell | InertCode):
                continue
        try:
            plan_move(modal, axes, arc, settings)
        except RuntimeAlarm as exc:
            raise SearchRefused(f"{where}: {exc}") from None
    return index, modal, e


def _refuse_sync(program: Program) -> None:
    """Seed 000, section 4, note 4: no block search in a program with EXE, WAI or SND (the
    first one named).  A block that does not parse is the start's own error, not this."""
    for i in range(len(program)):
        try:
            block = program.block(i)
        except ProgramError:
            continue
        for item in block.items:
            if isinstance(item, WaitProc | WaitCond | Snd | Exe):
                raise SearchRefused(
                    f"{program.file}:{i + 1}: {format_item(item)}: a block search is "
                    "impossible in a program with EXE, WAI or SND (seed 000, section 4, note "
                    '4); nc.block_search_sync = "skipped" refuses it only when the skipped '
                    "blocks hold one")
