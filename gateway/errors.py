"""The gateway's exceptions: one root, :class:`GatewayError`, under ncgate's own
(:mod:`ncgate.errors` draws the whole tree)."""

from __future__ import annotations

import errno

from ncgate.errors import NcgateError


class GatewayError(NcgateError):
    """Root of the gateway's exceptions."""


class ListenError(GatewayError, OSError):
    """A port that cannot be served: a TCP port that cannot be listened on, a serial port
    that cannot be opened (an OSError too, with its errno when the system gave one)."""


def listen_error(exc: OSError, key: str, host: str, port: int) -> ListenError:
    """A port that cannot be listened on, said with the config key to change."""
    hint = (" (a port below 1024 needs root or CAP_NET_BIND_SERVICE)"
            if exc.errno == errno.EACCES else "")
    return ListenError(exc.errno, f"{key}: cannot listen on {host}:{port}: {exc.strerror}"
                       f"{hint}")


class UsageError(GatewayError, ValueError):
    """Bad command-line input (exit status 2)."""


class WaitIdleTimeout(GatewayError, TimeoutError):
    """``wait_idle``/``wait_state`` ran out of time; the message has the why-records."""


class ClusterLost(GatewayError, TimeoutError):
    """``ncgate sweep --scheduler``: the Dask scheduler has had no worker for
    ``cluster.WORKERLESS_S`` in a row, or went away itself, so the sweep stopped waiting for
    its tasks.  ``why``: which, in words ("has had no worker for 60 s", "went away
    (...)"); ``resume``: when a ``--resume`` can go on."""

    def __init__(self, scheduler: str, unfinished: int, workerless_s: float = 0.0,
                 gone: str | None = None) -> None:
        self.why = (f"went away ({gone})" if gone is not None else
                    f"has had no worker for {workerless_s:.0f} s")
        self.resume = ("once it serves again" if gone is not None else
                       "once the cluster has workers")
        super().__init__(f"the Dask scheduler at {scheduler} {self.why}; {unfinished} "
                         f"variant{'s' if unfinished != 1 else ''} not done")
        self.scheduler = scheduler
        self.workerless_s = workerless_s
        self.unfinished = unfinished


class ProcessAlarmError(GatewayError, RuntimeError):
    """Every process stopped, some in ALARM: the message has the alarms."""


class ModbusError(GatewayError):
    """A request the map refuses: carries the exception code to answer."""

    def __init__(self, code: int, why: str = "") -> None:
        super().__init__(why or f"exception {code:#04x}")
        self.code = code


class VirtualPLCError(GatewayError, AssertionError):
    """The test kit's client got a Modbus exception answer, or a wait ran out of time.

    An AssertionError too, so that pytest reports it as a failed expectation of the test."""
