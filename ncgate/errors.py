"""The root of every exception ncgate raises.

Each package has one root of its own under it, which also subclasses the fitting builtin
(STYLE.md, as lark and python-can do), so callers can catch as narrowly as they like::

    NcgateError
    ├── ConfigError (ValueError)                  ncgate.config: file + dotted key
    ├── PlcError                                  ncgate.plc: the I/O image
    │   ├── ImageAddressError (IndexError)
    │   └── ImageValueError (ValueError)
    ├── InterpreterError                          ncgate.interpreter
    │   ├── ProgramError → ProgramSyntaxError (SyntaxError): diagnostics with spans
    │   ├── ProgramNotFoundError (FileNotFoundError)
    │   └── RuntimeAlarm: an alarm of a process (code + message), never leaves the engine
    └── GatewayError                              ncgate.gateway
        ├── UsageError (ValueError): bad command-line input, exit status 2
        ├── WaitIdleTimeout (TimeoutError)
        ├── ProcessAlarmError (RuntimeError)
        ├── ModbusError: a request answered with an exception code
        └── VirtualPLCError (AssertionError): the test kit's client got an exception answer

Imports nothing: every package may import it.
"""

from __future__ import annotations


class NcgateError(Exception):
    """Root of ncgate's exceptions."""


def render_diagnostic(file: str, line: int, column: int, severity: str, code: str,
                      message: str, source_line: str) -> str:
    """A diagnostic as every front end shows it (spec 1.6), like a compiler:
    ``file:line:col: error CODE: message``, then the source line and a caret under the
    column.  Tabs are shown as one space each, so that the caret stays under its column."""
    shown = source_line.replace("\t", " ")
    caret = " " * (max(column, 1) - 1) + "^"
    return f"{file}:{line}:{column}: {severity} {code}: {message}\n  {shown}\n  {caret}"
