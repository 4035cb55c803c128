"""I/O names in Structured Text (issue 29, item 4): each name of the config's [symbols] is a
global of the logic bound to its image variable -- read, and written as the logic writes
SA[i], SK[i], SYVAR[i]; a name that clashes with a name of the logic is ST013 at that
name's position."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import load_config
from ncgate.gateway.plc import load_logic
from ncgate.plc.image import IOImage
from ncgate.plc.scan import PlcRuntime
from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.diagnostics import LogicError
from ncgate.plc.st.parser import parse_source

from .st_harness import Plc, RecordingNc

SYMBOLS = (("door_closed", "SA10"), ("lamp", "SA11"), ("mode", "SA2.BY"), ("code", "K3"),
           ("speed", "SK4.IN"), ("spindle_speed", "SYVAR3"))
CONTEXT = Context(64, 16, 8, 5, frozenset({4, 5}), SYMBOLS)


def test_io_names_read_and_write_their_image_variables() -> None:
    plc = Plc("""PROGRAM main
    VAR seen : BOOL; m : BYTE; s : INT; END_VAR
    seen := door_closed;
    lamp := NOT door_closed;
    m := mode; code := mode + 1;
    spindle_speed := speed * 2;
    s := speed;
    speed := -3;
    mode.7 := TRUE;
    END_PROGRAM""", context=CONTEXT)
    plc.image.write([("SA", 10, "bit", 1), ("SA", 2 * 8 + 0, "bit", 1),
                     ("SK", 4, "BY", 0x2C), ("SK", 5, "BY", 0x01)], "test")
    plc.scan()
    image = plc.image
    assert plc["main.seen"] is True and image.read("SA", 11, "bit") == 0
    assert plc["main.m"] == 1 and image.read("SK", 3, "BY") == 2
    # SK4.IN is bytes 4 and 5, low byte first: 0x012C = 300 (spec 1.3).
    assert plc["main.s"] == 300 and image.read("SYVAR", 3, "IN") == 600
    assert image.read("SK", 4, "IN") == -3
    assert image.read("SA", 2, "BY") == 0x81


@pytest.mark.parametrize(("source", "line", "column"), [
    ("PROGRAM main VAR lamp : BOOL; END_VAR END_PROGRAM", 1, 18),
    ("VAR_GLOBAL\n  Door_Closed : BOOL;\nEND_VAR\nPROGRAM main END_PROGRAM", 2, 3),
    ("FUNCTION_BLOCK speed END_FUNCTION_BLOCK\nPROGRAM main END_PROGRAM", 1, 1),
    ("TYPE mode : INT; END_TYPE\nPROGRAM main END_PROGRAM", 1, 6),
])
def test_an_io_name_that_clashes_with_a_name_of_the_logic_is_st013_there(
        source: str, line: int, column: int) -> None:
    with pytest.raises(LogicError) as caught:
        compile_logic([parse_source(source, "clash.st")], CONTEXT)
    d = caught.value.diagnostics[0]
    assert (d.code.code, d.span.file, d.span.line, d.span.column) == (
        "ST013", "clash.st", line, column)


def test_the_gateway_gives_the_configs_symbols_to_the_logic(tmp_path: Path) -> None:
    (tmp_path / "plc.st").write_text("PROGRAM cell\nlamp := door_closed;\nEND_PROGRAM\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n[canopen]\nenabled = false\n'
        '[plc]\nlogic = "plc.st"\n[symbols]\ndoor_closed = "SA10"\n'
        'lamp = { var = "SA12", comment = "green" }\n')
    config = load_config(tmp_path / "ncgate.toml")
    logic = load_logic(config.plc.logic, config)
    image = IOImage(config.plc.sa_bits, config.plc.k_bytes, config.plc.syvars)
    runtime = PlcRuntime(logic, image, RecordingNc(), ["cell"])
    image.write([("SA", 10, "bit", 1)], "test")
    runtime.scan(0)
    assert image.read("SA", 12, "bit") == 1
