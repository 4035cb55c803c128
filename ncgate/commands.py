"""The command words (spec 3.2), in one table: a new command is one row here.

Everything that names a command word reads :data:`COMMANDS`: ``ncgate.inputs.CommandKind``
(checked against it at import), the door's refusal message, its cell-only commands and
switches and the words with an N number (``gateway/door.py``), the Modbus map's row for the
command word (``gateway/modbus/map.py``), the console's command names and lane buttons
(``gateway/web/console.py``, ``/api/commands``), the PLC's NC outputs and the words they give
(``plc/st/compiler.py``'s ``NC_OUTPUTS``, ``plc/scan.py``), the sim script's and the record's
command names (``CommandKind.label``), and the table in docs/interfacing-a-plc.md
(:func:`command_table_markdown`; tests/unit/test_commands.py fails when it differs).

A leaf: imports only the standard library, so that ``ncgate.plc`` may import it
(tests/test_layering.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final


@dataclass(frozen=True, slots=True)
class CommandWord:
    """One value of the command word's low byte (the high byte names a process).

    ``name`` is the command's name everywhere a program or a person writes one (the
    console's ``"command"``, a script's ``command``, the record's, ``CommandKind.label``);
    ``title`` its words in a message (``cycle start``); ``help`` a sentence for the docs.
    ``cell_only``: a process in it is refused (the cell's).  ``with_n``: it carries an N
    number written beside it (Modbus holding command+3, CANopen 0x2400:4) and becomes
    other inputs (a start, a breakpoint), not a ``CommandKind``.  ``switch``: an operator's
    switch it turns ``on`` or off (``single_block``; the engine's own for the cell-only
    ones).  ``plc``: the NC output of the PLC logic that gives it (``NC.START``, a rising
    edge; a switch's output is a level: TRUE gives the ``on`` word, FALSE the other).
    ``button``: the text of its button on a process's lane in the console."""

    word: int
    name: str
    title: str
    help: str
    cell_only: bool = False
    with_n: bool = False
    switch: str | None = None
    on: bool = False
    plc: str | None = None
    button: str | None = None


COMMANDS: Final[tuple[CommandWord, ...]] = (
    CommandWord(1, "cycle_start", "cycle start",
                "resumes a feed hold (then starts nothing, however idle a process is), or "
                "starts the main program (`nc.main`; a process's `[[nc.process]] main`); "
                "refused while an interlock input is set", plc="START", button="Start"),
    CommandWord(2, "feed_hold", "feed hold", "motion stops where it is, until a cycle start",
                plc="HOLD", button="Hold"),
    CommandWord(3, "reset", "reset",
                "alarms cleared, queues, waits and tokens discarded, every process to IDLE "
                "(of the cell: a faulted PLC, or plant logic, restarts too)", plc="RESET",
                button="Reset"),
    CommandWord(4, "restart_plc", "restart the PLC",
                "the PLC logic (and the plant's, [plant] logic) starts again after a FAULT; "
                "the NC is untouched",
                cell_only=True),
    CommandWord(5, "step", "step",
                "exactly one more block, then stop (state STEP); refused while an interlock "
                "input is set", button="Step"),
    CommandWord(6, "single_block_on", "single block on",
                "stop after each block until a cycle start or a step", switch="single_block",
                on=True),
    CommandWord(7, "single_block_off", "single block off", "single block ends",
                switch="single_block"),
    CommandWord(8, "optional_stop_on", "optional stop on", "M01 stops", cell_only=True,
                switch="optional_stop", on=True, plc="OPT_STOP"),
    CommandWord(9, "optional_stop_off", "optional stop off", "M01 does nothing",
                cell_only=True, switch="optional_stop", plc="OPT_STOP"),
    CommandWord(10, "block_skip_on", "block skip on", "blocks marked `/` are skipped",
                cell_only=True, switch="block_skip", on=True, plc="BLOCK_SKIP"),
    CommandWord(11, "block_skip_off", "block skip off", "blocks marked `/` run",
                cell_only=True, switch="block_skip", plc="BLOCK_SKIP"),
    CommandWord(12, "run_to_sync", "run to sync",
                "the cell stops at the next EXE, WAI, SND, REL, #SIGNAL or #WAIT of any "
                "process", cell_only=True),
    CommandWord(13, "block_search", "block search",
                "starts the process's main program (0: process 1's `nc.main`) by block "
                "search at the N number", with_n=True),
    CommandWord(14, "breakpoint", "breakpoint",
                "a breakpoint at the N number, of the process (0: of any)", with_n=True),
    CommandWord(15, "clear_breakpoints", "clear breakpoints",
                "clears every breakpoint (the N number is not read)", with_n=True),
    CommandWord(16, "reload_plc", "reload the PLC logic",
                "online change: `[plc] logic` read again and swapped in between two scans",
                cell_only=True),
)

BY_WORD: Final = {c.word: c for c in COMMANDS}
BY_NAME: Final = {c.name: c for c in COMMANDS}


def summary(words: tuple[CommandWord, ...] = COMMANDS) -> str:
    """The words in one line, as a refusal or a map's row says them: ``1 cycle start, 2 feed
    hold, ...``."""
    return ", ".join(f"{c.word} {c.title}" for c in words)


def plc_edges() -> tuple[tuple[str, int], ...]:
    """The PLC's NC outputs that give a command on a rising edge: (output, word)."""
    return tuple((c.plc, c.word) for c in COMMANDS if c.plc is not None and c.switch is None)


def switches() -> dict[str, tuple[CommandWord, CommandWord]]:
    """Each operator's switch by its name: (the word that turns it on, the one that turns it
    off)."""
    return {c.switch: (c, next(o for o in COMMANDS if o.switch == c.switch and not o.on))
            for c in COMMANDS if c.switch is not None and c.on}


def plc_levels() -> tuple[tuple[str, int, int], ...]:
    """The PLC's NC outputs that are a switch's level: (output, the word of TRUE, of
    FALSE)."""
    return tuple((on.plc, on.word, off.word) for on, off in switches().values()
                 if on.plc is not None)


def command_table_markdown() -> str:
    """The table of the command words for docs/interfacing-a-plc.md."""
    rows = ["| word | name | what it does | of |", "|---|---|---|---|"]
    for c in COMMANDS:
        of = "the cell" if c.cell_only else "the cell, or the process in the high byte"
        if c.with_n:
            of += "; the N number beside it"
        if c.plc is None:
            plc = ""
        elif c.switch is not None:  # a level
            plc = f" (ST: `NC.{c.plc}` {'TRUE' if c.on else 'FALSE'})"
        elif c.cell_only:
            plc = f" (ST: `NC.{c.plc}` rising)"
        else:
            plc = f" (ST: `NC.{c.plc}`, `NC.P[k].{c.plc}` rising)"
        rows.append(f"| {c.word} | `{c.name}` | {c.title}: {c.help}{plc} | {of} |")
    return "\n".join(rows) + "\n"
