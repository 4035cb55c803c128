"""The local pool: one worker process per core, one variant at a time each.

The parent knows which variant each worker runs, so a worker that dies (killed, a crash of
the interpreter) costs only its variant, which runs again on a new worker; one that kills its
worker twice is a ``crash`` row.  A worker that does not answer within its variant's wall
timeout and a grace (stuck outside Python code, where the worker's own timer cannot stop it)
is killed, and the variant is a ``timeout`` row.  Workers are forked from a server that has
imported the simulator once (``forkserver``), so a new one is cheap.
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any

from ncgate.gateway.sweep.run import Result, _result, run_variant
from ncgate.gateway.sweep.spec import Variant

GRACE_S = 5.0  # past the wall timeout, before the parent kills a silent worker
DEATHS = 2  # a variant whose worker died this often is a crash


Runner = Callable[[Variant, float | None], Result]  # run_variant, or a test's stand-in


def _serve(conn: Connection, timeout_s: float | None, runner: Runner) -> None:
    """A worker: variants in, results out, until the pipe closes."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    while True:
        try:
            variant = conn.recv()
        except (EOFError, OSError):  # the parent closed the pipe (done, or stopped)
            return
        result = runner(variant, timeout_s)
        try:
            conn.send(result)
        except OSError:  # the parent stopped (Ctrl-C) while this one ran: nobody to tell
            return


@dataclass
class _Worker:
    process: Any  # multiprocessing's Process of the chosen context
    conn: Connection
    variant: Variant | None = None
    since: float = 0.0


def default_workers() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)


def run_local(variants: Iterable[Variant], workers: int, timeout_s: float | None,
              runner: Runner = run_variant) -> Iterator[tuple[Variant, Result]]:
    """Each variant's result, in the order they finish.  ``variants`` are taken one at a
    time, as a worker is free (a spec's are made as they are taken), and are not counted:
    the first ``workers`` of them say how many workers start.  ``runner`` (a module-level
    function, for the workers to import) runs one variant."""
    rest = iter(variants)
    # The first ones, then a dead worker's variant given back: it runs again first.
    todo: deque[Variant] = deque(itertools.islice(rest, max(1, workers)))
    if not todo:
        return
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["ncgate.gateway.sweep.worker_signals",
                                    "ncgate.gateway.sweep.run", "ncgate.gateway.sim"])
    deaths: dict[str, int] = {}
    pool: list[_Worker] = []

    def spawn() -> _Worker:
        parent, child = context.Pipe()
        process = context.Process(target=_serve, args=(child, timeout_s, runner), daemon=True)
        process.start()
        child.close()
        return _Worker(process, parent)

    def give(worker: _Worker) -> None:
        worker.variant = None
        variant = todo.popleft() if todo else next(rest, None)
        if variant is None:
            return
        try:
            worker.conn.send(variant)
        except OSError:  # it died after its last answer: the variant goes to a new one
            todo.appendleft(variant)
            bury(worker)
            fresh = spawn()
            pool.append(fresh)
            give(fresh)
            return
        worker.variant = variant
        worker.since = time.monotonic()

    def bury(worker: _Worker) -> None:
        worker.conn.close()
        if worker.process.is_alive():
            worker.process.kill()
        worker.process.join()
        pool.remove(worker)

    try:
        for _ in range(len(todo)):
            pool.append(spawn())
        for worker in pool:
            give(worker)
        while any(w.variant is not None for w in pool):
            busy = [w for w in pool if w.variant is not None]
            wait_s = None
            if timeout_s:
                deadline = min(w.since for w in busy) + timeout_s + GRACE_S
                wait_s = max(0.0, deadline - time.monotonic())
            ready = wait([x for w in busy for x in (w.conn, w.process.sentinel)], wait_s)
            now = time.monotonic()
            for worker in busy:
                variant = worker.variant
                assert variant is not None
                if worker.conn in ready:
                    try:
                        result = worker.conn.recv()
                    except (EOFError, OSError):
                        result = None
                    if result is not None:
                        yield variant, result
                        give(worker)
                        continue
                if worker.conn in ready or worker.process.sentinel in ready:
                    # The worker died with the variant: it runs again, on a new worker.
                    bury(worker)
                    code = worker.process.exitcode
                    deaths[variant.id] = deaths.get(variant.id, 0) + 1
                    if deaths[variant.id] >= DEATHS:
                        yield variant, _result("crash", report=f"its worker process died "
                                               f"{DEATHS} times (exit status {code})")
                    else:
                        todo.appendleft(variant)
                    fresh = spawn()
                    pool.append(fresh)
                    give(fresh)
                elif timeout_s and now - worker.since > timeout_s + GRACE_S:
                    bury(worker)
                    yield variant, _result("timeout", signature="timeout wall",
                                           report=f"its worker did not answer "
                                           f"within the wall timeout of {timeout_s:g} s and "
                                           "was killed")
                    fresh = spawn()
                    pool.append(fresh)
                    give(fresh)
    finally:
        for worker in list(pool):
            bury(worker)
