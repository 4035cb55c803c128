"""The one table from a refusal of the door (:class:`ncgate.errors.Reason`) to the OPC UA
status code a write gets (OPC 10000-6, 7.34; the codes are asyncua's ``ua.StatusCodes``).
Total: a test checks that every Reason has a row."""

from __future__ import annotations

from typing import Final

from asyncua.ua.status_codes import StatusCodes

from ncgate.errors import Reason

Bad = StatusCodes

REFUSAL: Final[dict[Reason, int]] = {
    Reason.UNKNOWN_VARIABLE: Bad.BadNodeIdUnknown,
    Reason.OUTSIDE_IMAGE: Bad.BadNodeIdUnknown,
    Reason.READ_ONLY: Bad.BadNotWritable,
    Reason.BAD_VALUE: Bad.BadOutOfRange,
    Reason.UNKNOWN_PROCESS: Bad.BadOutOfRange,
    Reason.EXTERNAL_PROCESS: Bad.BadOutOfRange,
    Reason.NOT_EXTERNAL: Bad.BadOutOfRange,
    Reason.BUSY: Bad.BadInvalidState,
    Reason.INTERLOCK: Bad.BadInvalidState,
    Reason.NOT_RUNNING: Bad.BadInvalidState,
    Reason.NOT_CONFIGURED: Bad.BadConfigurationError,
    Reason.PROGRAM_NOT_FOUND: Bad.BadNotFound,
    Reason.PROGRAM_INVALID: Bad.BadInvalidArgument,
    Reason.ROLE_FORBIDS: Bad.BadUserAccessDenied,
    Reason.UNSUPPORTED: Bad.BadNotSupported,
}
