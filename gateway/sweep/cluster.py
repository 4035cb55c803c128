"""A sweep on a Dask distributed cluster (``--scheduler tcp://HOST:8786``, ``ncgate[dask]``).

The variants go in chunks, one task each, so that the scheduler's cost per task (a few ms)
stays small beside the runs, and the last chunks leave no worker idle for long: about 24
chunks per worker thread, at most ``MAX_CHUNK`` variants each.  (bench/sweep.py's 1,260
variants on two workers, one loaded run: 8 chunks a thread 16.5 s, 16 14.4 s, 32 11.7 s;
the pool 15.5 s.)  A task returns its chunk's results; the client takes each chunk's once,
whichever worker ran it, so nothing is counted twice.  A worker that dies (``kill -9``) loses
its tasks to the scheduler, which runs them on another worker.  A chunk whose workers keep
dying (Dask gives up after ``distributed.scheduler.allowed-failures``) runs again variant by
variant.  Dask counts a death against every task the worker held, so a variant whose task still
fails may be innocent, beside the killer on its worker: each such runs once more at the end,
alone (nothing else of the sweep's in flight), and only the variant that kills its worker then
is a ``crash`` row.

A cluster with no worker left (each died or was retired, or none ever joined) would leave the
tasks pending at the scheduler for ever: while results are awaited, the scheduler's workers
are counted about once a second (``POLL_S``), and once it has had none for ``WORKERLESS_S``
in a row the sweep stops with :class:`ClusterLost` (docs/decisions.md: why 60 s).  A task's
future is waited for through a queue its done callback feeds, with a timeout, not
``as_completed``: that one's blocking ``next`` takes no timeout (its ``timeout`` is a deadline
for the whole iteration, distributed 2026.8), and a wait between its non-blocking batches
would be a sleep or its private condition.

The workers need ncgate installed (the same version) and the spec's files at the same paths:
a shared folder, or the same checkout on every machine.
"""

from __future__ import annotations

import logging
import math
import queue
import time
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from ncgate.gateway.errors import ClusterLost
from ncgate.gateway.sweep.pool import Runner
from ncgate.gateway.sweep.run import Result, _result, run_variant
from ncgate.gateway.sweep.spec import SpecError, Variant

MAX_CHUNK = 32
CHUNKS_PER_THREAD = 24
# A cluster may be restarting (its workers come back after the scheduler) or scaling up from
# none: a minute without a worker is not yet lost (docs/decisions.md).
WORKERLESS_S = 60.0
POLL_S = 1.0  # the workers are counted at most this often, and only while nothing comes
# A fetch of a finished task's results is given up (the workers counted) and begun again after
# this long: far beyond a chunk's few kB, so that a slow fetch is never cut short for ever.
FETCH_S = 10.0


def run_chunk(variants: Sequence[Variant], timeout_s: float | None,
              runner: Runner = run_variant) -> list[Result]:
    """A task: each variant of the chunk, run in the worker's thread."""
    return [runner(v, timeout_s) for v in variants]


def chunk_size(variants: int, threads: int) -> int:
    return max(1, min(MAX_CHUNK, math.ceil(variants / max(1, threads * CHUNKS_PER_THREAD))))


def connect(scheduler: str) -> Any:
    """A Dask client of the scheduler at ``scheduler``; one that cannot be reached (or no
    Dask installed) is a SpecError, exit 2."""
    try:
        from distributed import Client
    except ImportError:
        raise SpecError("--scheduler needs Dask: pip install 'ncgate[dask]'") from None
    try:
        return Client(scheduler, timeout=30, set_as_default=False)
    except (OSError, ValueError, TypeError) as exc:
        raise SpecError(f"--scheduler {scheduler}: {exc}") from None


def close(client: Any) -> None:
    """Close ``client``.  One whose scheduler went away is still reconnecting, and closing it
    cancels that: ``distributed.client`` logged the cancel as an ERROR with its traceback,
    after the one line that says why the sweep stopped.  Quieted then, and only then."""
    if client.status == "running":
        client.close()
        return
    logger = logging.getLogger("distributed.client")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        client.close()
    finally:
        logger.setLevel(level)


class _Tasks:
    """The sweep's tasks on the cluster: each future as it finishes, and the watch on the
    scheduler's workers while none does.

    A future's done callback (run in Dask's callback thread) puts it in ``finished``; the
    sweep's thread waits on that queue at most until the next count of the workers is due.
    Results that keep coming need no count: a worker made them."""

    def __init__(self, client: Any, scheduler: str, threads: int) -> None:
        self.client = client
        self.scheduler = scheduler
        self.finished: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.unclaimed: dict[str, Any] = {}  # submitted, not yet taken by next(): by key
        self.checked = time.monotonic()
        self.workerless_since: float | None = None if threads else self.checked

    def submit(self, variants: list[Variant], timeout_s: float | None, runner: Runner,
               key: str, unfinished: Callable[[], int]) -> Any:
        try:
            future = self.client.submit(run_chunk, variants, timeout_s, runner, pure=False,
                                        key=key)
        except Exception as exc:  # (a client closed: its scheduler went away)
            self.gone(exc, unfinished)
            raise
        self.unclaimed[future.key] = future
        future.add_done_callback(self.finished.put)
        return future

    def next(self, unfinished: Callable[[], int]) -> Any:
        """The next task to finish; ClusterLost once the scheduler has had no worker for
        ``WORKERLESS_S`` (``unfinished()``: the variants it leaves not done)."""
        while True:
            try:
                future = self.finished.get(
                    timeout=max(0.0, self.checked + POLL_S - time.monotonic()))
            except queue.Empty:
                self.check(unfinished)
                continue
            if self.unclaimed.pop(future.key, None) is None:
                continue  # released before it finished (the sweep stopped)
            if future.status == "finished":
                self.workerless_since = None  # a worker ran it
            return future

    def result(self, future: Any, unfinished: Callable[[], int]) -> list[Result]:
        """``future``'s results.  Those of a worker that is gone by the time they are fetched
        are computed again, which waits for a worker as a pending task does."""
        while True:
            try:
                return future.result(timeout=FETCH_S)  # type: ignore[no-any-return]
            except TimeoutError:
                if future.status == "error":
                    raise  # the task's own (the wall timeout is a row, never this)
                self.check(unfinished)
            except Exception as exc:
                if future.status == "cancelled":  # (the sweep cancels nothing it waits for:
                    self.gone(exc, unfinished)  # the client did, its scheduler lost)
                raise

    def gone(self, exc: BaseException, unfinished: Callable[[], int]) -> None:
        """ClusterLost when the client lost its scheduler (``exc`` what said so): not a
        worker's death, which would make rows of variants that never ran."""
        if self.client.status != "running" or isinstance(exc, OSError) or (
                type(exc).__name__ in ("CancelledError", "FutureCancelledError",
                                       "ClosedClientError")):
            # One line: a FutureCancelledError's text has two (why, then Dask's advice).
            said = " ".join(str(exc).split())
            said = said if len(said) <= 120 else said[:117] + "..."
            raise ClusterLost(self.scheduler, unfinished(),
                              gone=f"{type(exc).__name__}: {said}") from None

    def check(self, unfinished: Callable[[], int]) -> None:
        now = time.monotonic()
        self.checked = now
        try:
            threads = sum(self.client.nthreads().values())
        except Exception as exc:  # (its scheduler cannot be reached)
            self.gone(exc, unfinished)
            raise
        if threads:
            self.workerless_since = None
        elif self.workerless_since is None:
            self.workerless_since = now
        elif now - self.workerless_since >= WORKERLESS_S:
            raise ClusterLost(self.scheduler, unfinished(), now - self.workerless_since)

    def release(self) -> None:
        """The tasks not taken, given up: the scheduler forgets them once no client holds
        them (a sweep stopped, or a cluster lost)."""
        for future in self.unclaimed.values():
            future.release()
        self.unclaimed.clear()


def run_dask(variants: Iterable[Variant], scheduler: str, timeout_s: float | None,
             runner: Runner = run_variant, client: Any = None) -> Iterator[tuple[Variant, Result]]:
    """Each variant's result as its chunk comes back; ``client``: one already connected (the
    caller closes it), else one of ``scheduler``'s, closed at the end.  ClusterLost when the
    scheduler has had no worker for ``WORKERLESS_S``: the results before it were yielded.

    Every variant is taken at the start: the chunks are all submitted at once (the
    scheduler shares them out), so the size of a chunk is known from their count."""
    taken = list(variants)
    if not taken:
        return
    own = client is None
    if own:
        client = connect(scheduler)
    tasks = None
    # The tasks' keys are this sweep's own: two sweeps of one spec on one cluster shared
    # them (a task is known by its key), and one's release or cancel was the other's.
    run = uuid.uuid4().hex[:12]
    try:
        threads = sum(client.nthreads().values())
        tasks = _Tasks(client, scheduler, threads)
        size = chunk_size(len(taken), threads)
        chunks: dict[str, list[Variant]] = {}
        for i in range(0, len(taken), size):
            chunk = taken[i:i + size]
            future = tasks.submit(chunk, timeout_s, runner,
                                  key=f"ncgate-sweep-{run}-{chunk[0].id}-{len(chunk)}-{i}",
                                  unfinished=lambda: len(taken))
            chunks[future.key] = chunk
        suspects: list[Variant] = []

        def unfinished() -> int:
            return sum(map(len, chunks.values())) + len(suspects)

        while chunks:
            future = tasks.next(unfinished)
            chunk = chunks[future.key]
            try:
                results = tasks.result(future, unfinished)
            except ClusterLost:
                raise
            except Exception:
                del chunks[future.key]
                if len(chunk) > 1:  # find the one that kills its worker: one task each
                    for v in chunk:
                        single = tasks.submit([v], timeout_s, runner,
                                              key=f"ncgate-sweep-{run}-{v.id}-alone",
                                              unfinished=unfinished)
                        chunks[single.key] = [v]
                else:  # it, or a task beside it on a worker that died, killed its workers
                    suspects.extend(chunk)
                continue
            finally:
                future.release()
            del chunks[future.key]
            yield from zip(chunk, results, strict=True)
        for n, v in enumerate(suspects):  # alone: a worker that dies now died of this one
            yield v, _alone(tasks, v, timeout_s, runner, len(suspects) - n, run)
    finally:
        if tasks is not None:
            tasks.release()
        if own:
            close(client)


def _alone(tasks: _Tasks, variant: Variant, timeout_s: float | None, runner: Runner,
           left: int, run: str) -> Result:
    """``variant`` run with nothing else of the sweep's in flight, so that Dask's count of the
    workers that died running a task is this variant's alone: its verdict is final.  ``left``:
    the variants not done, this one with them (for ClusterLost)."""
    future = tasks.submit([variant], timeout_s, runner,
                          key=f"ncgate-sweep-{run}-{variant.id}-isolated",
                          unfinished=lambda: left)
    try:
        tasks.next(lambda: left)
        return tasks.result(future, lambda: left)[0]
    except ClusterLost:
        raise
    except Exception as exc:
        return _result("crash", report=f"its Dask worker failed: "
                       f"{type(exc).__name__}: {str(exc)[:200]}")
    finally:
        future.release()
