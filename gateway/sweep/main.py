"""``ncgate sweep``: run a spec's variants (locally, or on a Dask cluster), write the table,
print the summary."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from ncgate.gateway.errors import ClusterLost
from ncgate.gateway.stdout import stderr, stdout, write_stdout_bytes
from ncgate.gateway.sweep.run import Result
from ncgate.gateway.sweep.spec import Spec, SpecError, Variant, render_value
from ncgate.gateway.sweep.table import (
    Parts,
    Row,
    command_of,
    csv_bytes,
    make_row,
    names_stdout,
    output_path,
    parquet_bytes,
    shown_again,
    write_atomic,
)

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT: the shell's status for a command Ctrl-C stopped
MAX_TIMEOUT_S = 1_000_000.0  # --timeout's largest (11 days): the timers take no more
# A Dask scheduler's address: scheme://host:port (a host name, IPv4, or [IPv6]).
SCHEDULER = re.compile(r"(?P<scheme>tcp|tls|ucx|ws|wss)://(?P<host>\[[0-9A-Fa-f:.]+\]|"
                       r"[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?):(?P<port>\d{1,5})")
FLUSH_ROWS = 64  # rows a part holds at most
FLUSH_S = 2.0  # and a part is written at least this often while rows come
SLOWEST = 5
WORST = 10


@dataclass
class Options:
    output: Path | None  # None: standard output (-o -), as is a name of it (/dev/stdout)
    format: str = "csv"  # or "parquet"
    workers: int | None = None
    scheduler: str | None = None
    resume: bool = False
    timeout_s: float | None = 60.0
    progress: bool | None = None  # None: on a terminal, not in CI


def table_to_stdout(options: Options) -> bool:
    """The table goes to standard output: ``-o -``, or a name of this process's stdout
    (``/dev/stdout``), which as a path had its parts beside a pipe's "pipe:[...]" -- no
    folder.  What the sweep says then goes to stderr, so that stdout carries the table
    alone."""
    return options.output is None or names_stdout(options.output)


def check_options(options: Options) -> None:
    """The command line's values, refused (UsageError: exit 2) before anything is made."""
    from ncgate.gateway.errors import UsageError

    if table_to_stdout(options):
        # A sweep to stdout keeps its parts in a temporary folder of its own, removed at its
        # end however it ends: a stopped one leaves nothing to go on from.
        if options.resume:
            raise UsageError("--resume with -o - (standard output): a sweep to stdout keeps "
                             "no parts to resume from; give -o FILE to sweep resumably")
        # Parquet is binary: on a terminal it is garbage and can upset the terminal itself.
        if options.format == "parquet" and sys.stdout is not None and sys.stdout.isatty():
            raise UsageError("--format parquet -o -: standard output is a terminal; "
                             "redirect it (> FILE.parquet, | a program) or give -o FILE")
    elif options.output is not None:
        # The table goes into a folder that is there: atomic writing makes the missing ones,
        # so a typo in -o made a tree of folders, unsaid.  (Links followed: where it goes.)
        folder = options.output.resolve().parent
        if not folder.is_dir():
            what = "not a folder" if folder.exists() else "no such folder"
            raise UsageError(f"-o {options.output}: {folder}: {what} (the table goes into a "
                             "folder that is there: make it first)")
    timeout = options.timeout_s
    if timeout is not None and not (math.isfinite(timeout) and 0 <= timeout <= MAX_TIMEOUT_S):
        raise UsageError(f"--timeout {timeout}: expected seconds > 0, at most "
                         f"{MAX_TIMEOUT_S:.0f} (0: none)")
    if options.scheduler is not None:
        found = SCHEDULER.fullmatch(options.scheduler)
        if found is None or not 1 <= int(found["port"]) <= 65535:
            raise UsageError(f"--scheduler {options.scheduler}: expected a Dask scheduler's "
                             "address, scheme://host:port (tcp://10.0.0.5:8786)")


def execute(variants: Iterable[Variant], options: Options,
            client: object = None) -> Iterator[tuple[Variant, Result]]:
    if options.scheduler:
        from ncgate.gateway.sweep.cluster import run_dask

        yield from run_dask(variants, options.scheduler, options.timeout_s, client=client)
    else:
        from ncgate.gateway.sweep.pool import default_workers, run_local

        yield from run_local(variants, options.workers or default_workers(), options.timeout_s)


def run_sweep(spec: Spec, options: Options,
              out: TextIO | None = None) -> tuple[int, list[Row]]:
    """Run what the parts lack, write the table; the exit status and the rows by id.  What
    it says goes to ``out``: by default stdout, or stderr when the table goes to stdout."""
    check_options(options)
    if out is None:
        out = sys.stderr if table_to_stdout(options) else sys.stdout
    stops = _Stops()
    # The stop handlers go in before anything is made: a SIGTERM that came before them, once
    # the private folder of -o - was made, left it behind.
    with _stop_signals(stops):
        try:
            with _output(spec, options) as output:
                if options.format == "parquet":
                    parquet_bytes([], spec.keys)  # pyarrow is there (or say so before any run)
                client = None
                if options.scheduler:  # reached (or said) before the parts are made
                    from ncgate.gateway.sweep.cluster import connect

                    client = connect(options.scheduler)
                try:
                    return _run_sweep(spec, options, output, client, out, stops)
                finally:
                    if client is not None:
                        from ncgate.gateway.sweep.cluster import close

                        close(client)
        except KeyboardInterrupt as exc:
            # Before the first variant ran; or after: a second stop while the first was
            # said, or one while the table was written (written whole, or not at all).
            when = ("while it ended (what was written stands)" if stops.started else
                    "before any variant ran")
            print(f"ncgate sweep: stopped ({str(exc) or 'Ctrl-C'}) {when}", file=sys.stderr)
            return _stopped_status(exc), []


@contextlib.contextmanager
def _stop_signals(stops: _Stops) -> Iterator[None]:
    """SIGTERM, and Ctrl-C where it raises KeyboardInterrupt, go to ``stops`` in the body (in
    the main thread: only there can a handler be set)."""
    previous: dict[signal.Signals, object] = {}
    if threading.current_thread() is threading.main_thread():
        previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, stops.handle)
        # Ctrl-C only where it raises KeyboardInterrupt: ignored (nohup, `&`) it stays so.
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            previous[signal.SIGINT] = signal.signal(signal.SIGINT, stops.handle)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]


@contextlib.contextmanager
def _output(spec: Spec, options: Options) -> Iterator[Path]:
    """The table's file, its parts beside it (``OUTPUT.parts/``, for ``--resume``).  For a
    table on stdout, a name in a private temporary folder that only its parts use, removed
    when the sweep ends however it ends (Ctrl-C, SIGTERM, an error): nothing is left to
    resume from, and nothing is left over in the working folder."""
    if not table_to_stdout(options):
        assert options.output is not None
        yield output_path(options.output, spec.files)
        return
    private = Path(tempfile.mkdtemp(prefix="ncgate-sweep-"))
    try:
        yield private / "table"
    finally:
        shutil.rmtree(private, ignore_errors=True)


def _run_sweep(spec: Spec, options: Options, output: Path, client: object,
               out: TextIO, stops: _Stops) -> tuple[int, list[Row]]:
    parts = Parts(output, spec)
    rows: dict[str, Row] = {}
    todo = _Remaining(spec, parts.start(options.resume), rows, stops)
    total = len(spec.variants)
    if todo.done:
        print(f"resuming: {len(todo.done)} of {total} variants done, {todo.count} to run",
              file=out)
    elif options.resume:  # nothing to go on from: said, not run again unsaid
        print(f"resuming: no rows kept in {parts.folder}: all {n_variants(todo.count)} to run",
              file=out)
    show = options.progress
    if show is None:
        show = sys.stderr.isatty() and not os.environ.get("CI")
    progress = Progress(todo.count) if show else None
    pending: list[Row] = []
    last = time.monotonic()
    stops.started = True
    try:
        for variant, result in execute(todo, options, client):
            with stops.held():
                row = make_row(variant, result, spec.keys)
                # The twin was taken before this one finished (both were running).
                _refuse_twin(spec, rows, variant)
                rows[variant.id] = row
                pending.append(row)
                if progress is not None:
                    progress.step()
                if len(pending) >= FLUSH_ROWS or time.monotonic() - last >= FLUSH_S:
                    parts.add(pending)
                    pending = []
                    last = time.monotonic()
    except SpecError:  # two variants of one id
        parts.add(pending)
        raise
    except (KeyboardInterrupt, ClusterLost) as exc:  # Ctrl-C, SIGTERM, the cluster lost:
        parts.add(pending)  # what is done is kept, for --resume
        if progress is not None:
            progress.close()
        # The kept rows the stream has not passed yet are done too.
        count = f"{len(rows) + len(todo.done)} of {total} variants done"
        if isinstance(exc, ClusterLost):
            why, later = f": the Dask scheduler at {exc.scheduler} {exc.why}", exc.resume
        else:
            why, later = f" ({str(exc) or 'Ctrl-C'})", "to go on"
        if table_to_stdout(options):  # its parts go with their temporary folder
            what = (f"{count}, no table written (-o -: nothing to resume; give -o FILE to "
                    "keep the rows done)")
        else:
            what = f"{count}, kept in {parts.folder}; run again with --resume {later}"
        print(f"ncgate sweep: stopped{why}: {what}", file=sys.stderr)
        return _stopped_status(exc), []
    parts.add(pending)
    if progress is not None:
        progress.close()
    # Every variant is in ``rows`` now, run or kept (the stream was taken to its end); a
    # kept row the stream never met was no variant of this spec's, and is left out.
    ordered = [rows[key] for key in sorted(rows)]  # by id: 12 lowercase hex digits each
    data = (parquet_bytes(ordered, spec.keys) if options.format == "parquet"
            else csv_bytes(ordered, spec.keys))
    if table_to_stdout(options):
        write_stdout_bytes(data)
    else:
        write_atomic(output, data)
    parts.finish()
    summary(ordered, spec.keys, out)
    print(f"wrote {options.output or '-'}", file=out)
    return (EXIT_OK if all(r["verdict"] == "ok" for r in ordered) else EXIT_FAILED), ordered


class _Remaining:
    """The variants a sweep runs, taken once: the spec's, in its order (each made, and its
    id hashed, as it is taken), without those whose rows a stopped sweep's parts hold.

    A kept row is matched to its variant as the stream passes it, and goes into ``rows``
    then, shown as this run shows it (``shown_again``); ``done`` holds the kept rows the
    stream has not passed yet.  Nothing else is kept per variant: a resume of a spec of a
    million starts its first variant as soon as the stream has passed the kept ones.

    Every id taken is checked against the rows before it: two variants of one id (a
    collision of the ids' 48 bits, spec.ID_LENGTH) would be one row, and one of them could
    be taken for done.  The spec refuses a run given twice before anything runs
    (``Variants.duplicate``); this is the rest, checked as the variants go."""

    def __init__(self, spec: Spec, done: dict[str, Row], rows: dict[str, Row],
                 stops: _Stops) -> None:
        self.spec = spec
        self.done = done
        self.rows = rows
        self.stops = stops
        # Exact but for a kept row of no variant of this spec (parts edited by hand).
        self.count = max(0, len(spec.variants) - len(done))
        self._stream = self._take()

    def __iter__(self) -> Iterator[Variant]:
        return self._stream

    def _take(self) -> Iterator[Variant]:
        for variant in self.spec.variants.in_spec_order():
            _refuse_twin(self.spec, self.rows, variant)
            row = self.done.get(variant.id)
            if row is None:
                yield variant
                continue
            with self.stops.held():  # in one or the other, for the count a stop says
                self.rows[variant.id] = shown_again(row, variant)
                del self.done[variant.id]


def _refuse_twin(spec: Spec, rows: dict[str, Row], variant: Variant) -> None:
    """SpecError when a row of another variant has ``variant``'s id."""
    twin = rows.get(variant.id)
    if twin is not None:
        raise SpecError(f"{spec.file}: two variants have the id {variant.id} (the ids are "
                        f"a hash's first {len(variant.id)} hex digits): {twin['command']} "
                        f"and {variant.command()}; split the spec")


def _stopped_status(stop: BaseException) -> int:
    """A sweep stopped by Ctrl-C is interrupted (130); by SIGTERM or a lost cluster, failed (1)."""
    ctrl_c = isinstance(stop, KeyboardInterrupt) and str(stop) != "SIGTERM"
    return EXIT_INTERRUPTED if ctrl_c else EXIT_FAILED


class _Stops:
    """Ctrl-C and SIGTERM as a KeyboardInterrupt ("SIGTERM" for the latter), held back while
    a result is counted and written (``held()``): it goes into the rows, the rows to write and
    the parts whole.  A stop while a part was written (between its file and ``pending = []``)
    wrote that part's rows a second time in the stop's own flush; one between ``rows`` and
    ``pending`` counted a row the parts never got.  (Not a signal mask: a Dask client's
    threads would take the signal, and Python still runs the handler in the main thread.)"""

    def __init__(self) -> None:
        self.holding = False
        self.stop: KeyboardInterrupt | None = None
        self.started = False  # the variants are run (a stop before is said by run_sweep)

    def handle(self, signum: int, frame: object) -> None:
        stop = KeyboardInterrupt("SIGTERM" if signum == signal.SIGTERM else "")
        if not self.holding:
            raise stop
        self.stop = self.stop or stop

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        self.holding = True
        try:
            yield
        finally:
            self.holding = False
        if self.stop is not None:
            stop, self.stop = self.stop, None
            raise stop


def n_variants(count: int) -> str:
    """``count`` variants, in words: "1 variant", "2 variants"."""
    return f"{count} variant{'' if count == 1 else 's'}"


def label(row: Row, keys: Sequence[str]) -> str:
    values = " ".join(f"{k}={row[k]}" for k in keys if row.get(k) is not None)
    script = f" {Path(row['script']).name}" if row.get("script") else ""
    return f"{row['program']}{script}" + (f" {values}" if values else "")


def summary(rows: Sequence[Row], keys: Sequence[str], out: TextIO) -> None:
    counts = Counter(r["verdict"] for r in rows)
    order = sorted(counts, key=lambda v: (v != "ok", -counts[v], v))
    print(f"{n_variants(len(rows))}: " + ", ".join(f"{counts[v]} {v}" for v in order), file=out)
    ran = [r for r in rows if r["verdict"] not in ("crash", "error")]
    if ran:
        print("slowest (cycle time):", file=out)
        for r in sorted(ran, key=lambda r: (-r["cycle_s"], r["id"]))[:SLOWEST]:
            print(f"  {r['cycle_s']:10.3f} s  {r['id']}  {label(r, keys)}", file=out)
    bad = [r for r in rows if r["verdict"] != "ok"]
    if bad:
        shown = f" (the first {WORST} of {len(bad)})" if len(bad) > WORST else ""
        print(f"not ok{shown}:", file=out)
        for r in bad[:WORST]:
            print(f"  {r['id']}  {r['verdict']:<13} {label(r, keys)}: {r['report']}", file=out)


class Progress:
    """One line on stderr: done/total, rate, ETA."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.done = 0
        self.start = time.monotonic()
        self.shown = 0.0

    def step(self) -> None:
        self.done += 1
        now = time.monotonic()
        if now - self.shown < 0.2 and self.done < self.total:
            return
        self.shown = now
        rate = self.done / max(now - self.start, 1e-9)
        eta = (self.total - self.done) / rate if rate else 0.0
        sys.stderr.write(f"\r{self.done}/{self.total} variants  {rate:.1f}/s  ETA {eta:.0f} s ")
        sys.stderr.flush()

    def close(self) -> None:
        sys.stderr.write("\n")


def main(spec_path: str, options: Options, explore: int | None = None) -> int:
    from ncgate.gateway.sweep.spec import load_spec

    check_options(options)
    # `ncgate sweep ... | head`: a reader that goes early stops neither the sweep nor its
    # table, and the status is still the rows' (the flush at the end: it was exit 120).
    # With the table on stdout (-o -) what the sweep says goes to stderr, which a reader
    # (2>&1 | head) may close alike.
    out = stderr() if table_to_stdout(options) else stdout()
    spec = load_spec(spec_path, explore)
    if spec.draws is not None and spec.draws[1] < spec.draws[0]:
        where = "--explore" if explore is not None else "[random]"
        print(f"{where}: the {spec.draws[0]} draws gave {spec.draws[1]} distinct samples (a "
              f"repeated draw runs once): {n_variants(len(spec.variants))}", file=out)
    status, rows = run_sweep(spec, options, out)
    if explore is not None and rows:
        findings(rows, spec, out, options.timeout_s, said=options.progress is not False)
    out.flush()
    return status


def findings(rows: Sequence[Row], spec: Spec, out: TextIO,
             timeout_s: float | None = None, said: bool = True) -> None:
    """``--explore``: the failures grouped by signature (the deadlock's cycle, the stall's
    blocked processes, the first alarm's code and block), each with the variant that shows it
    in the least simulated time, and its smallest reproducer: that variant with each swept key
    left at its default in turn, as long as the run still fails the same way."""
    groups: dict[tuple[str, str], list[Row]] = {}
    for row in rows:
        if row["verdict"] != "ok":
            key = (row["verdict"], row["signature"] or row["report"])
            groups.setdefault(key, []).append(row)
    if not groups:
        print(f"explored {n_variants(len(rows))}: no failure", file=out)
        return
    print(f"explored {n_variants(len(rows))}: {len(groups)} distinct failure"
          f"{'s' if len(groups) > 1 else ''}", file=out)
    for (verdict, signature), found in sorted(groups.items(), key=lambda g: (-len(g[1]), g[0])):
        first = min(found, key=lambda r: (r["cycle_s"], r["id"]))
        print(f"{verdict} in {len(found)} of {len(rows)} variants: {signature}", file=out)
        print(f"  first in {first['cycle_s']:.3f} s of simulated time: {first['id']}", file=out)
        variant = spec.variants.find(first["id"])
        assert variant is not None
        if first["signature"] == "timeout wall":
            # Each try could take a whole --timeout, and a try that times out tells nothing
            # of the failure: not reduced.
            print(f"  smallest reproducer: not looked for (a wall timeout: each try could take "
                  f"the --timeout); the variant: {command_of(variant, first['signature'])}",
                  file=out)
            continue
        smallest = reduce(variant, verdict, first["signature"], timeout_s, said)
        # As the row's own command: a run past its budget stops there (--until BUDGET).
        print(f"  smallest reproducer: {command_of(smallest, first['signature'])}", file=out)


def reduce(variant: Variant, verdict: str, signature: str,
           timeout_s: float | None, said: bool = True) -> Variant:
    """``variant`` without each swept key (its default instead) that the failure does not
    need: one key at a time, in column order, kept out when the run without it fails with
    the same verdict and signature.  Each try is a line on stderr (a try may take up to
    ``timeout_s``; not ``said`` with -q, as the progress line is not), and one past the wall
    timeout says so (with -q too: it changes the reproducer): its key is kept."""
    from ncgate.gateway.sweep.run import run_variant

    for step, (key, value) in enumerate(variant.sets, 1):
        if said:
            print(f"reducing {variant.id}: trying {key} at its default, not "
                  f"{render_value(value)} ({step} of {len(variant.sets)})...",
                  file=sys.stderr, flush=True)
        fewer = dataclasses.replace(variant, sets=tuple(s for s in variant.sets if s[0] != key))
        result = run_variant(fewer, timeout_s)
        if (result["verdict"], result["signature"]) == (verdict, signature):
            variant = fewer
        elif result["signature"] == "timeout wall":
            print(f"reducing {variant.id}: {key} at its default ran past the --timeout of "
                  f"{timeout_s or 0:g} s: {key} kept", file=sys.stderr, flush=True)
    return variant


__all__ = ["EXIT_FAILED", "EXIT_OK", "EXIT_USAGE", "Options", "SpecError", "main", "run_sweep"]
