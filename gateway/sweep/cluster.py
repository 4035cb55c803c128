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

The workers need ncgate installed (the same version) and the spec's files at the same paths:
a shared folder, or the same checkout on every machine.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any

from ncgate.gateway.sweep.pool import Runner
from ncgate.gateway.sweep.run import Result, _result, run_variant
from ncgate.gateway.sweep.spec import SpecError, Variant

MAX_CHUNK = 32
CHUNKS_PER_THREAD = 24


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


def run_dask(variants: Sequence[Variant], scheduler: str, timeout_s: float | None,
             runner: Runner = run_variant, client: Any = None) -> Iterator[tuple[Variant, Result]]:
    """Each variant's result as its chunk comes back; ``client``: one already connected (the
    caller closes it), else one of ``scheduler``'s, closed at the end."""
    from distributed import as_completed

    if not variants:
        return
    own = client is None
    if own:
        client = connect(scheduler)
    try:
        threads = sum(client.nthreads().values())
        size = chunk_size(len(variants), threads)
        chunks = {}
        futures = []
        for i in range(0, len(variants), size):
            chunk = list(variants[i:i + size])
            future = client.submit(run_chunk, chunk, timeout_s, runner, pure=False,
                                   key=f"ncgate-sweep-{chunk[0].id}-{len(chunk)}-{i}")
            chunks[future.key] = chunk
            futures.append(future)
        pending = as_completed(futures, loop=client.loop)
        suspects: list[Variant] = []
        for future in pending:
            chunk = chunks.pop(future.key)
            try:
                results: list[Result] = future.result()
            except Exception:
                if len(chunk) > 1:  # find the one that kills its worker: one task each
                    for v in chunk:
                        single = client.submit(run_chunk, [v], timeout_s, runner, pure=False,
                                               key=f"ncgate-sweep-{v.id}-alone")
                        chunks[single.key] = [v]
                        pending.add(single)
                else:  # it, or a task beside it on a worker that died, killed its workers
                    suspects.extend(chunk)
                continue
            finally:
                future.release()
            yield from zip(chunk, results, strict=True)
        for v in suspects:  # alone on the cluster: a worker that dies now died of this one
            yield v, _alone(client, v, timeout_s, runner)
    finally:
        if own:
            client.close()


def _alone(client: Any, variant: Variant, timeout_s: float | None, runner: Runner) -> Result:
    """``variant`` run with nothing else of the sweep's in flight, so that Dask's count of the
    workers that died running a task is this variant's alone: its verdict is final."""
    future = client.submit(run_chunk, [variant], timeout_s, runner, pure=False,
                           key=f"ncgate-sweep-{variant.id}-isolated")
    try:
        return future.result()[0]  # type: ignore[no-any-return]
    except Exception as exc:
        return _result("crash", report=f"its Dask worker failed: "
                       f"{type(exc).__name__}: {str(exc)[:200]}")
    finally:
        future.release()
