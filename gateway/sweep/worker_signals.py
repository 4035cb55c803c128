"""Imported first by the local pool's forkserver (its preload), and by nothing else: SIGINT
ignored there from the start, so that the workers forked from it inherit that.

A Ctrl-C at a terminal goes to the whole process group -- the sweep, its forkserver and every
worker.  The sweep (the parent) handles it: keeps the rows done and stops the workers.  A
worker that took it too would die with a KeyboardInterrupt traceback ("Process
ForkServerProcess-2: ...") -- even in the moment between its fork and its first line, before
``pool._serve`` could ignore the signal itself.
"""

from __future__ import annotations

import signal

signal.signal(signal.SIGINT, signal.SIG_IGN)
