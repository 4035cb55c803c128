"""Modbus's numbers, named once: function codes, exception codes, the command words, and the
one table that turns a refusal of the door (:class:`ncgate.errors.Reason`) into an exception
code (Modbus application protocol specification V1.1b3, 6 and 7)."""

from __future__ import annotations

import enum
from typing import Final

from ncgate import inputs
from ncgate.errors import Reason
from ncgate.inputs import CommandKind


class FunctionCode(enum.IntEnum):
    READ_COILS = 1
    READ_DISCRETE_INPUTS = 2
    READ_HOLDING_REGISTERS = 3
    READ_INPUT_REGISTERS = 4
    WRITE_SINGLE_COIL = 5
    WRITE_SINGLE_REGISTER = 6
    WRITE_MULTIPLE_COILS = 15
    WRITE_MULTIPLE_REGISTERS = 16
    MASK_WRITE_REGISTER = 22
    READ_WRITE_MULTIPLE_REGISTERS = 23
    ENCAPSULATED_INTERFACE = 43  # with MEI type 0x0E: read device identification


class ExceptionCode(enum.IntEnum):
    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_DATA_ADDRESS = 0x02
    ILLEGAL_DATA_VALUE = 0x03
    SERVER_DEVICE_FAILURE = 0x04
    SERVER_DEVICE_BUSY = 0x06
    GATEWAY_TARGET_NO_RESPONSE = 0x0B


ILLEGAL_FUNCTION: Final = ExceptionCode.ILLEGAL_FUNCTION
ILLEGAL_ADDRESS: Final = ExceptionCode.ILLEGAL_DATA_ADDRESS
ILLEGAL_VALUE: Final = ExceptionCode.ILLEGAL_DATA_VALUE
DEVICE_FAILURE: Final = ExceptionCode.SERVER_DEVICE_FAILURE
DEVICE_BUSY: Final = ExceptionCode.SERVER_DEVICE_BUSY
TARGET_NO_RESPONSE: Final = ExceptionCode.GATEWAY_TARGET_NO_RESPONSE

# The command word's values (holding register 2000 by default): the door's CommandKind.
COMMAND_WORDS: Final = {kind.value: kind for kind in CommandKind}


command_word = inputs.command_word  # one decoding for every fieldbus (ncgate.inputs)

# Why the door refused an input -> the exception code the client gets.  Total: a test checks
# that every Reason has a row.
REFUSAL: Final[dict[Reason, ExceptionCode]] = {
    Reason.UNKNOWN_VARIABLE: ILLEGAL_ADDRESS,
    Reason.OUTSIDE_IMAGE: ILLEGAL_ADDRESS,
    Reason.READ_ONLY: ILLEGAL_ADDRESS,
    Reason.BAD_VALUE: ILLEGAL_VALUE,
    Reason.UNKNOWN_PROCESS: ILLEGAL_VALUE,
    Reason.EXTERNAL_PROCESS: ILLEGAL_VALUE,
    Reason.NOT_EXTERNAL: ILLEGAL_VALUE,
    Reason.BUSY: DEVICE_BUSY,
    Reason.INTERLOCK: DEVICE_BUSY,
    Reason.NOT_RUNNING: DEVICE_FAILURE,
    Reason.NOT_CONFIGURED: DEVICE_FAILURE,
    Reason.PROGRAM_NOT_FOUND: DEVICE_FAILURE,
    Reason.PROGRAM_INVALID: DEVICE_FAILURE,
    Reason.ROLE_FORBIDS: ILLEGAL_FUNCTION,
    Reason.UNSUPPORTED: ILLEGAL_FUNCTION,
}
