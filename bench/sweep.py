"""``ncgate sweep``: variants per second on 1 and 2 local workers, and on a Dask cluster.

Load: every runnable example (its scenarios each a run) x both SND policies x ``--depths``
look-ahead depths x ``--feeds`` feed overrides, run three ways, one after the other:

- the local pool with 1 worker, then with 2 (``--workers``): the scaling of the pool;
- a Dask ``LocalCluster`` of 2 worker processes of 1 thread each, on loopback, started here
  (its start is not timed; the client's connection and the chunks are): the cost of the
  cluster's scheduling against the pool on the same two cores.

Each way's time runs from the first variant submitted to the last result in (the pool's
workers' start included); the rows are checked to be the same every way.  The three ways
take turns ``--rounds`` times and each keeps its best time: the machine is shared, and a
neighbour's load that falls on one way only would decide a single round.  Targets: 2 workers
>= 1.7x the variants/s of 1 (on the two-core machine), the Dask cluster's time <= 1.3x the
2-worker pool's.

    .venv/bin/python bench/sweep.py [--depths N] [--feeds N] [--rounds N]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from ncgate.gateway.sweep.main import Options, execute
from ncgate.gateway.sweep.spec import Spec, load_spec


def spec_of(folder: Path, depths: int, feeds: int) -> Spec:
    lookaheads = [0, 1, 2, 4, 8, 16, 32, 64][:depths]
    overrides = [50 + round(100 * i / max(1, feeds - 1)) for i in range(feeds)]
    path = folder / "bench.toml"
    path.write_text('[sweep]\nexamples = ["*"]\n[grid]\n"nc.snd" = ["rendezvous", "latched"]\n'
                    f'"nc.lookahead" = {lookaheads}\n"nc.feed_override" = {overrides}\n')
    return load_spec(path)


def timed(spec: Spec, options: Options) -> tuple[float, dict[str, object]]:
    start = time.perf_counter()
    results = {v.id: r for v, r in execute(spec.variants, options)}
    return time.perf_counter() - start, results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--depths", type=int, default=6, help="look-ahead depths (max 8)")
    parser.add_argument("--feeds", type=int, default=5, help="feed overrides, 50..150 %%")
    parser.add_argument("--rounds", type=int, default=2, help="turns of the three ways")
    args = parser.parse_args()
    from distributed import LocalCluster

    best: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp, LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
            dashboard_address=None) as cluster:
        folder = Path(tmp)
        spec = spec_of(folder, args.depths, args.feeds)
        n = len(spec.variants)
        print(f"{n} variants (the examples x 2 SND policies x {args.depths} look-ahead depths "
              f"x {args.feeds} feed overrides), {args.rounds} rounds")
        ways = {"local pool, 1 worker": Options(folder / "x.csv", workers=1),
                "local pool, 2 workers": Options(folder / "x.csv", workers=2),
                "Dask, 2 workers": Options(folder / "x.csv",
                                           scheduler=cluster.scheduler_address)}
        base = None
        for i in range(args.rounds):
            for name, options in ways.items():
                took, results = timed(spec, options)
                base = base or results
                assert results == base, f"{name}: the rows differ from the first way's"
                print(f"round {i + 1}, {name + ':':23} {took:7.2f} s  {n / took:7.1f} variants/s")
                best[name] = min(best.get(name, took), took)
    one, two, dask = best.values()
    print(f"best of each: {one:.2f} s, {two:.2f} s, {dask:.2f} s")
    print(f"2 workers / 1 worker: {one / two:.2f}x the variants/s (target >= 1.7x)")
    print(f"Dask / pool (2 workers): {dask / two:.2f}x the time (target <= 1.3x)")


if __name__ == "__main__":
    main()
