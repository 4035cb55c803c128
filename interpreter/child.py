"""Work done in a child process of its own, at a lower CPU priority: what may wait (checking
a big program) never takes the interpreter lock, or the CPU, from what must stay on time (the
event loop serving the fieldbus, the PLC scan).

A thread that parses a 10 MB program shares the interpreter lock with the loop: each time
the loop gives the lock up for a system call it waits for the reader to hand it back, and the
half million blocks it makes keep the garbage collector busy long after.  A child shares
neither; it sends back only what is small (diagnostics, a few sets).

A job is ``module:function`` and its arguments (pickled), plus one ``bytes`` payload sent
raw.  The function yields frames, each pickled on its own, so that the parent never unpickles
a large answer in one call.  ``python -m ncgate.interpreter.child`` is the child's side; it
is started with the parent's interpreter, never through :mod:`multiprocessing` (whose spawn
would run the user's main module again).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import pickle
import struct
import subprocess
import sys
import threading
from collections.abc import Iterator
from typing import IO, Any, BinaryIO, NoReturn

from ncgate.errors import NcgateError

NICE = 10  # the child's niceness: it gets the CPU the gateway leaves (nice 0: weight 1024, 10: 110)
_LENGTH = struct.Struct(">Q")


class ChildFailed(NcgateError):
    """The child could not do the job (it could not start, or died): do it here instead."""


class ChildCancelled(NcgateError):
    """The job was cancelled (the gateway closes): nobody waits for its answer."""


class ChildJobs:
    """The children running jobs for one owner; :meth:`cancel` kills those running now (a
    SIGTERM of the gateway does not wait for a check of a 10 MB program)."""

    def __init__(self) -> None:
        self._running: set[subprocess.Popen[bytes]] = set()
        self._cancelled: set[subprocess.Popen[bytes]] = set()
        self._lock = threading.Lock()
        self._generation = 0  # cancel() counts up: a job started before it is cancelled

    def run(self, target: str, args: tuple[Any, ...], payload: bytes) -> list[Any]:
        """Every frame ``target(payload, *args)`` yields, in order (call it from a thread:
        it waits for the child).  Raises :class:`ChildCancelled` or :class:`ChildFailed`."""
        with self._lock:
            generation = self._generation
        try:
            child = subprocess.Popen(
                [sys.executable, "-m", __name__], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, close_fds=True)
        except OSError as exc:
            raise ChildFailed(f"no child process: {exc}") from None
        with self._lock:
            self._running.add(child)
            if generation != self._generation:  # cancelled while it started
                self._cancelled.add(child)
                child.kill()
        try:
            assert child.stdin is not None and child.stdout is not None
            try:
                header = pickle.dumps((target, args, len(payload)))
                child.stdin.write(_LENGTH.pack(len(header)) + header)
                child.stdin.write(payload)
                child.stdin.flush()  # left open: the child ends when it closes (see main)
                frames = list(_frames(child.stdout))
            except (OSError, EOFError, pickle.UnpicklingError, struct.error) as exc:
                self._raise_lost(child, exc)
            if not frames or frames[-1][0] != "end":
                self._raise_lost(child, EOFError("no end"))
            if len(frames) > 1 and frames[-2][0] == "failed":
                raise ChildFailed(frames[-2][1])
            return [value for kind, value in frames if kind == "frame"]
        finally:
            with self._lock:
                self._running.discard(child)
                self._cancelled.discard(child)
            for pipe in (child.stdin, child.stdout):  # its stdin's end ends the child
                if pipe is not None:
                    with contextlib.suppress(OSError):
                        pipe.close()
            try:
                child.wait(timeout=1)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()

    def _raise_lost(self, child: subprocess.Popen[bytes], exc: BaseException) -> NoReturn:
        with self._lock:
            cancelled = child in self._cancelled
        if cancelled:
            raise ChildCancelled("cancelled") from None
        raise ChildFailed(f"the child ended before its answer: {exc!r}") from None

    def cancel(self) -> None:
        """Kill the children running now; their callers get :class:`ChildCancelled`.  Jobs
        run after this start children anew."""
        with self._lock:
            self._generation += 1
            running = list(self._running)
            self._cancelled.update(running)
        for child in running:
            if child.poll() is None:
                child.kill()


def _frames(stream: IO[bytes]) -> Iterator[tuple[str, Any]]:
    """The child's frames: ("frame", value)..., then ("failed", traceback) if the job
    raised, then ("end", None).  Tuples of plain data only: in the child this module is
    ``__main__``, so a class of its own would not unpickle here."""
    while True:
        head = stream.read(_LENGTH.size)
        if not head:
            return
        size = _LENGTH.unpack(head)[0]
        body = stream.read(size)
        if len(body) != size:
            raise EOFError("a frame cut short")
        frame = pickle.loads(body)
        yield frame
        if frame[0] == "end":
            return


def _send(out: BinaryIO, frame: object) -> None:
    body = pickle.dumps(frame, protocol=pickle.HIGHEST_PROTOCOL)
    out.write(_LENGTH.pack(len(body)) + body)


def _end_with_parent(stdin: BinaryIO) -> None:
    stdin.read()
    os._exit(3)


def main() -> None:
    if hasattr(os, "nice"):
        os.nice(NICE)
    stdin, out = sys.stdin.buffer, sys.stdout.buffer
    size = _LENGTH.unpack(stdin.read(_LENGTH.size))[0]
    target, args, length = pickle.loads(stdin.read(size))
    payload = stdin.read(length)
    # The parent keeps the pipe open while it waits: its end (the parent closed it, or was
    # killed) ends the child, which never works on for nobody.
    threading.Thread(target=_end_with_parent, args=(stdin,), daemon=True).start()
    module, _, name = target.partition(":")
    try:
        for frame in getattr(importlib.import_module(module), name)(payload, *args):
            _send(out, ("frame", frame))
    except Exception:  # sent back whole: the parent does the job itself
        import traceback

        _send(out, ("failed", traceback.format_exc()))
    _send(out, ("end", None))
    out.flush()


if __name__ == "__main__":
    main()
