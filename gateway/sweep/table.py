"""The results table: rows, written in parts as they come, then whole (CSV or Parquet).

While a sweep runs, finished rows go to ``OUTPUT.parts/`` a part at a time; a part is a
temporary file, flushed and fsynced, then renamed into place (``os.replace`` is atomic), so a
``kill -9`` at any byte leaves whole parts and at most a temporary file, which is ignored.
``--resume`` reads the parts and runs only what they lack.  The table itself, sorted by id,
is written the same way at the end, and then the parts are removed: a file named OUTPUT is
always a whole table.
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import stat
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from ncgate.gateway import atomic
from ncgate.gateway.sweep.run import RESULT_FIELDS, Result
from ncgate.gateway.sweep.spec import Spec, SpecError, Variant, render_value

Row = dict[str, Any]
PARTS_FORMAT = "ncgate-sweep-parts/1"


def columns(keys: Sequence[str]) -> list[str]:
    return ["id", "verdict", "program", "script", *keys, "cycle_s", "alarms", "hazards",
            "running_s", "waiting_s", "signature", "report", "command"]


def make_row(variant: Variant, result: Result, keys: Sequence[str]) -> Row:
    values = dict(variant.sets)
    row: Row = {"id": variant.id, "program": variant.program, "script": variant.script or ""}
    row.update({k: values.get(k) for k in keys})
    row.update({k: result[k] for k in RESULT_FIELDS})
    row["command"] = command_of(variant, result["signature"])
    return row


def shown_again(row: Row, variant: Variant) -> Row:
    """A row kept from a stopped sweep (its parts), with its files and command as this run
    shows them: ``program`` and ``script`` are relative to the working folder, and ``command``
    runs from there (docs/sweep.md), so a sweep resumed from another folder gave rows of two
    forms in one table, the kept ones wrong from where the table was written.  The id is the
    same variant's, the same files (``--resume`` checked the spec and its files), so what the
    run found stays as it was."""
    return {**row, "program": variant.program, "script": variant.script or "",
            "command": command_of(variant, row["signature"])}


def command_of(variant: Variant, signature: str) -> str:
    """The ``ncgate sim`` command that runs ``variant`` again as its row says: past its
    virtual-time budget, with ``--until BUDGET`` (sim alone would run on; it stops there)."""
    command = variant.command()
    if signature == "timeout budget":
        command += f" --until {render_value(variant.budget_s)}"
    return command


def names_stdout(output: Path) -> bool:
    """Whether ``output`` is a name of this process's standard output (``/dev/stdout``,
    ``/dev/fd/1``, ``/proc/self/fd/1``, a link to one): the sweep takes it as ``-o -``.

    Told by the names, link by link, not by what the links reach: /proc's ``fd/1`` stands for
    the open file, and its target (``pipe:[4115907]``, a socket) is no path -- the table's
    parts beside it could not be made.  A regular file that stdout was redirected to, given
    by its own name, stays a file written whole (atomically), not appended to."""
    fds = {Path("/proc/self/fd"), Path(f"/proc/{os.getpid()}/fd"), Path("/dev/fd")}
    path = Path(os.path.abspath(output))
    for _ in range(40):  # as the kernel's limit of links in one lookup (ELOOP)
        if path == Path("/dev/stdout") or (path.name == "1" and (
                path.parent in fds or Path(os.path.realpath(path.parent)) in fds)):
            return True
        if not path.is_symlink():
            return False
        path = Path(os.path.abspath(path.parent / os.readlink(path)))
    return False


def output_path(output: Path, inputs: Iterable[Path] = ()) -> Path:
    """Where the table goes: ``output`` with its symbolic links followed (the table is written
    through them, not over them).  A folder, FIFO or device, or one of the sweep's own inputs
    (the spec, a program), is refused: UsageError, exit 2.  (Standard output is told apart
    before: :func:`names_stdout`.)"""
    from ncgate.gateway.errors import UsageError

    target = output.resolve()
    try:
        # What ``output`` reaches, not ``target``: a descriptor's link in /proc (/dev/fd/3 on
        # a pipe) resolves to a name such as "pipe:[4115907]" that is no file, but is a FIFO.
        mode = output.stat().st_mode
    except FileNotFoundError:
        mode = None
    except OSError as exc:
        raise UsageError(f"-o {output}: {exc.strerror}") from None
    if mode is not None and not stat.S_ISREG(mode):
        raise UsageError(f"-o {output}: not a regular file (the table replaces a file; for "
                         "standard output give -o -)")
    if target in {Path(p).resolve() for p in inputs}:
        raise UsageError(f"-o {output}: is one of the sweep's inputs (the spec or a file it "
                         "names): give another output")
    return target


def write_atomic(path: Path, data: bytes) -> None:
    """The file whole or not at all (ncgate.gateway.atomic), with a table's permissions."""
    atomic.write_output(path, data)


def csv_bytes(rows: Iterable[Row], keys: Sequence[str]) -> bytes:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    names = columns(keys)
    writer.writerow(names)
    for row in rows:
        writer.writerow([_cell(row[name]) for name in names])
    return out.getvalue().encode("utf-8")


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool | int | float | str) and not isinstance(value, str):
        return render_value(value)
    return str(value)


def parquet_bytes(rows: Sequence[Row], keys: Sequence[str]) -> bytes:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise SpecError("--format parquet needs pyarrow: pip install 'ncgate[parquet]'") from None
    names = columns(keys)
    arrays = {}
    for name in names:
        values = [row[name] for row in rows]
        if name == "cycle_s":
            arrays[name] = pa.array(values, pa.float64())
        elif name == "hazards":
            arrays[name] = pa.array(values, pa.int64())
        elif name in keys:
            arrays[name] = pa.array(_one_type(values))
        else:
            arrays[name] = pa.array(values, pa.string())
    sink = io.BytesIO()
    pq.write_table(pa.table(arrays), sink)
    return sink.getvalue()


def _one_type(values: list[Any]) -> list[Any]:
    """A swept key's values as one column type: ints and floats as floats, else as text."""
    kinds = {type(v) for v in values if v is not None}
    if kinds <= {int, float} and float in kinds:
        return [None if v is None else float(v) for v in values]
    if len(kinds) > 1:
        return [None if v is None else render_value(v) for v in values]
    return values


def _files_changed(then: Any, now: dict[str, str]) -> str:
    """The files whose content differs between two manifests' ``files`` (path -> digest),
    in words: a resumed sweep's refusal names them (a log written beside the programs, as
    MP0 reads a .txt, changed "the spec or a file it names" and nobody could tell which).
    "" when the stopped sweep's manifest has none (an older one)."""
    if not isinstance(then, dict):
        return ""
    changed = [p for p in sorted(now) if p in then and then[p] != now[p]]
    added = [p for p in sorted(now) if p not in then]
    gone = [p for p in sorted(then) if p not in now]
    words = [f"{p} (changed)" for p in changed] + [f"{p} (new)" for p in added] + [
        f"{p} (gone)" for p in gone]
    if not words:
        return ""
    more = f" and {len(words) - 3} more" if len(words) > 3 else ""
    return ", ".join(words[:3]) + more


class Parts:
    """``OUTPUT.parts/``: the rows finished so far, in whole files."""

    def __init__(self, output: Path, spec: Spec) -> None:
        self.folder = output.with_name(output.name + ".parts")
        self.spec = spec
        self.count = 0

    def manifest(self) -> dict[str, Any]:
        return {"format": PARTS_FORMAT, "spec": str(self.spec.file.resolve()),
                "fingerprint": self.spec.fingerprint, "variants": len(self.spec.variants),
                "explore": self.spec.explore, "files": self.spec.digests}

    def changed(self, found: dict[str, Any]) -> str | None:
        """What differs between the stopped sweep's manifest ``found`` and this one's, said
        for --resume's refusal; None: nothing.  (A manifest from before "explore" was kept
        has no such key: the count of variants tells.)"""
        now = self.manifest()
        if any(found.get(k) != now[k] for k in ("format", "spec", "fingerprint")):
            said = _files_changed(found.get("files"), now["files"])
            if said:
                return (f"what the sweep reads is not what the sweep in {self.folder} read "
                        f"(the spec, its programs, configs and scripts, every program file "
                        f"on their storage: a .txt beside the programs is one): {said}")
            return f"the spec or a file it names changed since the sweep in {self.folder} " \
                   "was stopped"
        was = found.get("explore", now["explore"])
        if was != now["explore"]:
            then = "without --explore" if was is None else f"with --explore {was}"
            this = ("no --explore" if self.spec.explore is None
                    else f"--explore {self.spec.explore}")
            return f"the sweep in {self.folder} was run {then}, this one has {this}"
        if found.get("variants") != now["variants"]:
            return (f"the sweep in {self.folder} had {found.get('variants')} variants, the "
                    f"spec gives {now['variants']} now")
        return None

    def start(self, resume: bool) -> dict[str, Row]:
        """The rows of a stopped sweep (``resume``) by id, else none: the parts are cleared.
        The ids are not looked up here (that would hash every variant's): the sweep matches
        each row to its variant as it takes the variants, and leaves out a row it never
        meets."""
        done: dict[str, Row] = {}
        if resume and self.folder.is_dir():
            manifest = self.folder / "manifest.json"
            try:
                found = json.loads(manifest.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                found = None
            changed = None if found is None else self.changed(found)
            if changed is not None:
                raise SpecError(f"{self.spec.file}: --resume: {changed}; run again "
                                "without --resume")
            for part in sorted(self.folder.glob("part-*.jsonl")):
                number = part.stem.removeprefix("part-")
                self.count = max(self.count, int(number) if number.isdigit() else 0)
                for line in part.read_text(encoding="utf-8").splitlines():
                    row = json.loads(line)
                    done[row["id"]] = row
            for tmp in self.folder.glob(".*.tmp"):
                tmp.unlink()
        else:
            shutil.rmtree(self.folder, ignore_errors=True)
        write_atomic(self.folder / "manifest.json",
                     (json.dumps(self.manifest(), indent=1) + "\n").encode())
        return done

    def add(self, rows: Sequence[Row]) -> None:
        if not rows:
            return
        self.count += 1
        text = "".join(json.dumps(row, sort_keys=True) + "\n" for row in rows)
        write_atomic(self.folder / f"part-{self.count:06d}.jsonl", text.encode("utf-8"))

    def finish(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
