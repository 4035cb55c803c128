"""Who the gateway says it is, on every fieldbus: the CANopen identity object (0x1018) and the
Modbus device identification (FC43/14) come from these same values."""

from __future__ import annotations

from typing import Final

from ncgate import __version__

VENDOR_NAME: Final = "ncgate"
VENDOR_ID: Final = 0x00000000  # no CiA vendor id assigned; tools show the product name instead
PRODUCT_CODE: Final = 0x4E434754  # "NCGT"
PRODUCT_NAME: Final = "ncgate CNC co-simulator gateway"
REVISION: Final = 0x00010000  # map/dictionary version 1.0: major in the high word


def product_code_text() -> str:
    return PRODUCT_CODE.to_bytes(4, "big").decode("ascii")


def revision_text() -> str:
    """MajorMinorRevision (FC43 object 0x02): the software version, the text CANopen's
    0x100A gives, so that both fieldbuses name the same release.  (0x1018:3, REVISION, is
    the revision of the map and dictionary, a number CiA 301 defines on its own.)"""
    return __version__


def model_name() -> str:
    return f"ncgate {__version__}"
