"""The root of every exception ncgate raises.

Each package has one root of its own under it, and the specific exceptions callers meet also
subclass the fitting builtin (CONTRIBUTING.md, as lark and python-can do), so callers can
catch as narrowly as they like::

    NcgateError
    ├── ConfigError (ValueError)                  ncgate.config: file + dotted key
    ├── PlcError                                  ncgate.plc: the image and the logic
    │   ├── ImageAddressError (IndexError)
    │   ├── ImageValueError (ValueError)
    │   ├── LogicError (SyntaxError): ST diagnostics; PlcFault (RuntimeError)
    │   └── PlcPathError (KeyError): a PLC variable path that names nothing
    ├── InterpreterError                          ncgate.interpreter
    │   ├── ProgramError → ProgramSyntaxError (SyntaxError): diagnostics with spans
    │   ├── ProgramNotFoundError (FileNotFoundError)
    │   └── RuntimeAlarm: an alarm of a process (code + message), never leaves the engine
    ├── InputRefused                              an outside input refused (a Reason)
    └── GatewayError                              ncgate.gateway
        ├── UsageError (ValueError): bad command-line input, exit status 2
        │   └── RecordError: a session record's line that is not one
        ├── ListenError (OSError): a port (TCP or serial) that cannot be served
        ├── WaitIdleTimeout (TimeoutError)
        ├── ClusterLost (TimeoutError): a sweep's Dask scheduler with no worker left
        ├── ProcessAlarmError (RuntimeError)
        ├── ModbusError: a request answered with an exception code
        ├── FramingError (ValueError): a Modbus byte stream that cannot be cut into frames
        ├── FaultError (ValueError): a Modbus fault row the server cannot put in force
        └── VirtualPLCError (AssertionError): the test kit's client got an exception answer

Imports nothing: every package may import it.
"""

from __future__ import annotations

import enum


class NcgateError(Exception):
    """Root of ncgate's exceptions."""


class Reason(enum.StrEnum):
    """Why an input from outside the engine was refused (:class:`InputRefused`).  Each
    protocol maps these to its own code in one table: Modbus exception codes
    (``gateway/modbus/codes.py``), SDO abort codes (``gateway/canopen/codes.py``), HTTP
    statuses (the console)."""

    UNKNOWN_VARIABLE = "unknown variable"  # not a variable name at all
    OUTSIDE_IMAGE = "outside the image"  # a variable the configured image does not hold
    BAD_VALUE = "bad value"  # a value the variable, command or field cannot take
    READ_ONLY = "read-only"  # the map locks the region
    UNKNOWN_PROCESS = "unknown process"  # no such process in the config
    EXTERNAL_PROCESS = "external process"  # runs no part program (or: only those send)
    NOT_EXTERNAL = "not an external process"  # an SND from a process that runs programs
    BUSY = "busy"  # the process already runs a program or is in ALARM
    NOT_RUNNING = "not running"  # e.g. an SND to a process with no program
    NOT_CONFIGURED = "not configured"  # nothing to start: no main program configured
    PROGRAM_NOT_FOUND = "program not found"
    PROGRAM_INVALID = "program invalid"  # does not parse or check: the diagnostics say why
    ROLE_FORBIDS = "role forbids"  # the client's role may not do this
    INTERLOCK = "interlock"  # a PLC interlock input is set (nc.feed_hold_input, ...)
    UNSUPPORTED = "unsupported"  # a form of input this version does not take


class InputRefused(NcgateError):
    """An input from outside the engine was refused and nothing of it applied.

    ``reason`` says why in a form a protocol maps to its own code; the message says it to a
    person."""

    def __init__(self, reason: Reason, message: str = "") -> None:
        super().__init__(message or reason.value)
        self.reason = reason


def render_diagnostic(file: str, line: int, column: int, severity: str, code: str,
                      message: str, source_line: str) -> str:
    """A diagnostic as every front end shows it (spec 1.6), like a compiler:
    ``file:line:col: error CODE: message``, then the source line and a caret under the
    column.  Tabs are shown as one space each, so that the caret stays under its column."""
    shown = source_line.replace("\t", " ")
    caret = " " * (max(column, 1) - 1) + "^"
    return f"{file}:{line}:{column}: {severity} {code}: {message}\n  {shown}\n  {caret}"
