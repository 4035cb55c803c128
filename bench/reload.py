"""Online change of a big PLC program: does the scan stay on time (issue 29, item 5)?

Load: ``bench/plc.py``'s generated 1,000-statement program (100 TONs, a FOR loop, IFs) as
``[plc] logic`` of a running gateway (``plc.scan_ms`` 10, the interpreter as ``run`` tunes it),
reloaded ``--reloads`` times in each of three phases, side by side in one run:

- quiet: no reload, the scan alone (the baseline);
- off the loop: ``Gateway.reload_plc``, as every door does it -- read and compiled in a
  thread, then swapped in between two scans;
- on the loop: the same command applied to the door directly, so that the compile runs on
  the loop thread (what ``reload_plc`` would cost without the thread).

It prints each phase's worst scan lateness (how late a scan began against its due time,
the PLC status's max lateness) and the ratio of the two reload phases to the quiet one.
Target: off the loop, a reload holds no scan back by more than a few scan periods, where on
the loop one compile (~1 s for this program) holds it back by the whole compile.

Then big logic (``--big`` statements, 20,000: ~0.8 MB of ST, ~1.9 MB of generated Python),
reloaded off the loop ``--big-reloads`` times in two phases, alternating, twice each:

- one compile(): the generated module compiled in one call (PIECE_LINES and PIECE_CHARS
  set past its size: the code as it was before the pieces);
- in pieces: as ncgate does it, a piece of about PIECE_CHARS at a time.

Python's compile() holds the interpreter for the whole call, thread or not.  Each phase
also prints its longest pause of the cyclic garbage collector (gc.callbacks), with the
generation: a collection runs on whichever thread allocates, holding the interpreter.  Each
phase begins with an unmeasured reload (it frees the other phase's logic).  Target: a big
reload holds no scan back by more than a few scan periods.

    .venv/bin/python bench/reload.py [--reloads N] [--big STATEMENTS] [--big-reloads N]
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import importlib.util
import tempfile
import time
from pathlib import Path

from ncgate.gateway import Gateway
from ncgate.gateway.lifecycle import tune_interpreter
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.inputs import Command, CommandKind
from ncgate.plc.st import compiler, logic

HERE = Path(__file__).resolve().parent


def program(statements: int = 1000) -> str:
    spec = importlib.util.spec_from_file_location("bench_plc", HERE / "plc.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return str(module.generate(statements))


class GcPauses:
    """The longest pause of the cyclic collector since ``reset`` (ms) and its generation."""

    def __init__(self) -> None:
        self.started = 0.0
        self.reset()
        gc.callbacks.append(self.note)

    def reset(self) -> None:
        self.longest, self.generation = 0.0, -1

    def note(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self.started = time.perf_counter()
        elif (took := (time.perf_counter() - self.started) * 1000) > self.longest:
            self.longest, self.generation = took, info["generation"]


async def phase(gw: Gateway, reloads: int, how: str) -> tuple[int, float]:
    """The worst scan lateness (µs) over ``reloads`` reloads done ``how``, and the wall
    time one reload took on average (s)."""
    status = gw.plc_status
    assert status is not None
    await asyncio.sleep(0.2)  # let a scan or two run, then measure from here
    status.max_lateness_us = 0
    started = time.perf_counter()
    for _ in range(reloads):
        if how == "quiet":
            await asyncio.sleep(1.0)
        elif how == "thread":
            outcome = await gw.reload_plc()
            assert outcome.ok, outcome.diagnostics
        else:  # the door on the loop thread: it compiles there
            gw.door.apply(Command(CommandKind.RELOAD_PLC))
        await asyncio.sleep(0.1)  # a few scans after each
    return status.max_lateness_us, (time.perf_counter() - started) / reloads


async def big(statements: int, reloads: int, pauses: GcPauses) -> None:
    """The big logic's two phases (docstring), alternating, twice each."""
    pieces = compiler.PIECE_LINES, logic.PIECE_CHARS
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        (root / "big.st").write_text(program(statements))
        (root / "ncgate.toml").write_text('[plc]\nlogic = "big.st"\nscan_ms = 10\n'
                                          "watchdog_ms = 0\n[canopen]\nenabled = false\n")
        config = ncgate_test_config(root / "ncgate.toml")
        async with Gateway(config) as gw:
            results: dict[str, tuple[int, float, float, int]] = {}
            for how in ("whole", "pieces", "whole", "pieces"):
                compiler.PIECE_LINES, logic.PIECE_CHARS = (
                    (10**9, 10**12) if how == "whole" else pieces)
                # (unmeasured: it swaps out the other phase's logic, freed on the loop)
                assert (await gw.reload_plc()).ok
                pauses.reset()
                late, each = await phase(gw, reloads, "thread")
                gc_ms, gen = pauses.longest, pauses.generation
                best = results.get(how)
                results[how] = (max(late, best[0]), max(each, best[1]), max(gc_ms, best[2]),
                                gen if gc_ms >= best[2] else best[3]) if best else (
                    late, each, gc_ms, gen)
        compiler.PIECE_LINES, logic.PIECE_CHARS = pieces
    print(f"{statements:,}-statement program ({len(program(statements)) / 1e6:.1f} MB of ST),"
          f" {reloads} reloads off the loop a phase, twice each, alternating")
    for how, name in (("whole", "one compile()"), ("pieces", "in pieces")):
        late, each, gc_ms, gen = results[how]
        print(f"  {name:14} worst scan lateness {late / 1000:8.1f} ms, {each:.1f} s a reload, "
              f"longest gc pause {gc_ms:.1f} ms (generation {gen})")


async def main(reloads: int, statements: int, big_reloads: int) -> None:
    tune_interpreter()  # what `ncgate run` sets for its process
    pauses = GcPauses()
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        (root / "big.st").write_text(program())
        (root / "ncgate.toml").write_text('[plc]\nlogic = "big.st"\nscan_ms = 10\n'
                                          "watchdog_ms = 0\n[canopen]\nenabled = false\n")
        config = ncgate_test_config(root / "ncgate.toml")
        async with Gateway(config) as gw:
            results = {}
            for how in ("quiet", "thread", "loop", "quiet", "thread", "loop"):
                late, each = await phase(gw, reloads, how)
                best = results.get(how)
                results[how] = max(late, best[0]) if best else late, each
        quiet = max(results["quiet"][0], 1)
        print(f"1,000-statement program, {reloads} reloads a phase, twice each, alternating")
        for how, name in (("quiet", "no reload"), ("thread", "reload off the loop"),
                          ("loop", "reload on the loop")):
            late, each = results[how]
            print(f"  {name:22} worst scan lateness {late / 1000:8.1f} ms "
                  f"({late / quiet:6.1f}x quiet)" + (f", {each:.2f} s a reload"
                                                    if how != "quiet" else ""))
    if statements:
        await big(statements, big_reloads, pauses)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--reloads", type=int, default=3)
    parser.add_argument("--big", type=int, default=20000, help="statements (0: no big phase)")
    parser.add_argument("--big-reloads", type=int, default=2)
    args = parser.parse_args()
    asyncio.run(main(args.reloads, args.big, args.big_reloads))
