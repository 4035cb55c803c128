"""The gateway's side of "What the field found": ``run --watch`` and the PLC logic as the
field writes it."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from ncgate.gateway.plc import LogicWatcher, read_sources

PROGRAM = "PROGRAM p\nVAR x : INT; END_VAR\nx := 1;\nEND_PROGRAM\n"


async def test_run_watch_reloads_a_save_made_while_the_logic_was_first_read(
        tmp_path: Path) -> None:
    logic = tmp_path / "p.st"
    logic.write_text(PROGRAM)
    read_sources((logic,))  # the PLC reads the logic (as start_plc does) ...
    logic.write_text(PROGRAM.replace("x := 1;", "x := 22;"))  # ... and a save lands meanwhile
    reloaded = asyncio.Event()
    watcher = LogicWatcher((logic,), reloaded.set, asyncio.get_running_loop(),
                           interval_s=0.01)
    watcher.start()  # (made once the gateway is up: after the read)
    try:
        async with asyncio.timeout(10):
            await reloaded.wait()
    finally:
        watcher.close()


TCPOU = """<?xml version="1.0" encoding="utf-8"?>
<TcPlcObject Version="1.1.0.1" ProductVersion="3.1.4024.12">
  <POU Name="FB_Axis" Id="{6a5b3f2e-0000-0000-0000-000000000000}" SpecialFunc="None">
    <Declaration><![CDATA[FUNCTION_BLOCK FB_Axis
VAR_INPUT
    bEnable : BOOL;
END_VAR]]></Declaration>
    <Implementation>
      <ST><![CDATA[IF bEnable THEN
    ;
END_IF]]></ST>
    </Implementation>
  </POU>
</TcPlcObject>
"""


@pytest.mark.parametrize("name", ["FB_Axis.TcPOU", "FB_AXIS.NC"])
def test_ncgate_check_says_a_twincat_file_is_twincat_xml_not_an_nc_program(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str) -> None:
    from ncgate.gateway.cli.main import main

    path = tmp_path / name  # by its suffix, or by its root element whatever the suffix
    path.write_text(TCPOU, encoding="utf-8")
    assert main(["check", str(path)]) == 1
    out = capsys.readouterr()
    assert f"{path}:2:1: error ST040: a TwinCAT 3 source file" in out.out
    assert out.out.count(": error ") == 1  # that alone: no NC syntax errors after it
    assert "--dialect" not in out.err
