"""Deadlock and orphan-wait search (spec 2.3), as pure functions of the processes' state.

The wait-for graph has an edge k -> n for every WAIT_PROC, WAIT_SND and WAIT_EXE of process k
on process n, and for an ISG signal wait one to each channel whose signal it still needs (a
condition or flush wait has no edge: anyone may write the image, and a flush waits on its own
interpolator, whose waits have their own edges).  A process is *stuck* when it cannot move by
itself: it has a program, no alarm, no hold, its decoder is held, and its interpolator is in a
wait, has nothing left to run, or -- ISG's buffer effect -- will not take a block until the
decoder fills its buffer.  A cycle of stuck processes is a
deadlock; the engine alarms every member with one message naming each blocking block.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

from ncgate.interpreter.engine.actions import Execute
from ncgate.interpreter.engine.ports import ProgramText
from ncgate.interpreter.engine.process import Process
from ncgate.interpreter.engine.states import WaitKind, WaitRecord

_NO_EDGE = (WaitKind.COND, WaitKind.FLUSH)


def edges(p: Process) -> list[tuple[int, WaitRecord]]:
    """The wait-for edges out of ``p``: (the process waited for, the wait)."""
    out: list[tuple[int, WaitRecord]] = []
    for w in p.waits():
        if w.kind in _NO_EDGE:
            continue
        if w.targets is not None:
            out.extend((t, w) for t in w.targets)
        elif w.target:
            out.append((w.target, w))
    return out


def stuck(p: Process) -> bool:
    if p.loaded is None or p.alarm is not None or p.held or p.external:
        return False
    if p.dec_block is None or p.int_timer is not None:
        return False
    return p.int_wait is not None or not p.queue or p.starved


def find_cycle(start: Process,
               processes: Mapping[int, Process]) -> list[tuple[Process, WaitRecord]] | None:
    """A cycle of stuck processes through ``start``, as (process, its blocking wait) in
    order, or None."""
    if not stuck(start):
        return None
    # Most waits are on a process that can still move: no cycle through it.  (Spelled out:
    # this runs on every WAI and SND that waits.  A condition wait's target is 0.)
    for wait in (start.dec_wait, start.int_wait):
        if wait is None or wait.kind in _NO_EDGE:
            continue
        targets = wait.targets
        if targets is None:
            if wait.target and stuck(processes[wait.target]):
                break
        elif any(stuck(processes[t]) for t in targets):
            break
    else:
        return None
    path: list[tuple[Process, WaitRecord]] = []
    on_path = {start.number}

    def walk(p: Process) -> bool:
        for target, wait in edges(p):
            path.append((p, wait))
            if target == start.number:
                return True
            q = processes[target]
            if target not in on_path and stuck(q):
                on_path.add(target)
                if walk(q):
                    return True
                on_path.discard(target)
            path.pop()
        return False

    return path if walk(start) else None


def describe_cycle(start: Process, cycle: list[tuple[Process, WaitRecord]]) -> str:
    """``deadlock: P1 A.nc:2 N2 (WAI,2) -> P2 B.nc:1 N7 (WAI,1) -> P1``"""
    parts = [wait.describe(p.number) for p, wait in cycle]
    message = "deadlock: " + " -> ".join(parts) + f" -> P{start.number}"
    notes = [note for _, wait in cycle if wait.note is not None and (note := wait.note())]
    return "; ".join([message, *dict.fromkeys(notes)])


Scan = tuple[frozenset[int], bool, frozenset[tuple[int, str]]]  # targets, dynamic, calls


def can_be_started(n: int, waiter: Process, processes: Mapping[int, Process],
                   queued: Iterable[ProgramText], outside: Callable[[int], bool],
                   scan: Callable[[ProgramText], Scan],
                   load: Callable[[str, int], ProgramText | None]) -> bool:
    """Whether anything can still start a program in idle process ``n``:

    - the outside (``outside(n)``: an operator's start, a script's, the PLC's cycle start);
    - an EXE of ``n`` already in the waiter's motion queue (a ``#`` EXE it passed);
    - a program that runs in another process, or waits in an EXE queue (``queued``), and
      starts ``n`` -- or starts a program that does, and so on: the EXE chains are
      followed through the programs they name (``load``; None: not loadable);
    - such a program that names a process by a variable (it may be any).
    """
    if outside(n):
        return True
    for item in (waiter.int_item, *waiter.queue):
        if item is not None and item.actions and any(
                isinstance(a, Execute) and a.process == n for a in item.actions):
            return True
    todo = [q.loaded.program for q in processes.values()
            if q is not waiter and q.loaded is not None and q.alarm is None]
    todo.extend(queued)
    followed: set[tuple[int, str]] = set()
    while todo:
        targets, dynamic, calls = scan(todo.pop())
        if dynamic or n in targets:
            return True
        for k, name in calls:
            key = (k, name.upper())
            if key in followed:
                continue
            followed.add(key)
            program = load(name, k)
            if program is not None:
                todo.append(program)
    return False


def orphan_message(waiter: Process, wait: WaitRecord, target: int | None = None) -> str:
    target = wait.target if target is None else target
    return (f"orphan wait: {wait.describe(waiter.number)} waits for P{target}, which runs "
            f"no program, which no running or queued program can start (their EXEs "
            f"followed), and which nothing outside may start")
