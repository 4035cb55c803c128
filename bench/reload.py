"""Online change of a big PLC program: does the scan stay on time (issue 29, item 5)?

Load: ``bench/plc.py``'s generated 1,000-statement program (100 TONs, a FOR loop, IFs) as
``[plc] logic`` of a running gateway (``plc.scan_ms`` 10, the switch interval ``run`` sets),
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

    .venv/bin/python bench/reload.py [--reloads N]
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import sys
import tempfile
import time
from pathlib import Path

from ncgate.gateway import Gateway
from ncgate.gateway.cli.main import SWITCH_INTERVAL_S
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.inputs import Command, CommandKind

HERE = Path(__file__).resolve().parent


def program() -> str:
    spec = importlib.util.spec_from_file_location("bench_plc", HERE / "plc.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return str(module.generate(1000))


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


async def main(reloads: int) -> None:
    sys.setswitchinterval(SWITCH_INTERVAL_S)
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


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--reloads", type=int, default=3)
    asyncio.run(main(parser.parse_args().reloads))
