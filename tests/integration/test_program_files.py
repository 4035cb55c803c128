"""Issue 9.5: program files as users have them -- a byte-order mark, a file that is not
UTF-8, and the Cyrillic look-alikes of address letters that Russian operators type."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ncgate.gateway.cli.main import main

from ..helpers import write_cell

CONFIG = '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n'


def test_a_byte_order_mark_is_no_error(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, CONFIG, {})
    (tmp_path / "A.nc").write_bytes(b"\xef\xbb\xbfN1G1X10F600\r\nN2M30\r\n")
    assert main(["check", str(tmp_path / "A.nc")]) == 0
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 0
    assert "every program ended" in capsys.readouterr().out


def test_a_file_that_is_not_utf8_is_nc015_with_its_name_line_and_column(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, CONFIG, {"B": "N1M30\n"})
    (tmp_path / "A.nc").write_bytes(b"N1G1X10F600\nN2(DIS,\"ok\")\nN3E1=1\xff\nN4M30\n")
    # check: the bad file's report, and the other file still checked.
    assert main(["check", str(tmp_path / "A.nc"), str(tmp_path / "B.nc")]) == 1
    captured = capsys.readouterr()
    assert "A.nc:3:7: error NC015: byte 0xff is not UTF-8" in captured.out
    assert "2 file(s) checked: 1 error(s)" in captured.err
    # sim: the program never starts; the same diagnostic, no traceback.
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml")]) == 2
    err = capsys.readouterr().err
    assert "A.nc:3:7: error NC015" in err and "Traceback" not in err


def test_cyrillic_lookalikes_are_read_as_latin_with_a_warning(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # As the manual writes it: Е4 with a Cyrillic Е; a label with one; a Russian DIS text.
    program = ('"\u04154"\nN1\u04151=\u04151+1\nN2(DIS,"\u041e\u0421\u0422",\u04151)\n'
               "N3(BL\u0422,E1,3,\u04154) ; \u0415 in a comment stays\nN4M30\n")
    write_cell(tmp_path, CONFIG, {"A": program})
    assert main(["check", str(tmp_path / "A.nc")]) == 0
    out = capsys.readouterr().out
    assert "A.nc:2:3: warning NW004: Cyrillic letters read as their Latin twins: \u0415\u2192E" \
        in out
    assert "A.nc:3:14: warning NW004" in out  # the DIS argument, not its quoted text
    assert "A.nc:4:6: warning NW004" in out and "\u0422\u2192T" in out
    assert "A.nc:1:" not in out  # the quoted label is left as written
    trace = tmp_path / "t.jsonl"
    assert main(["sim", "--config", str(tmp_path / "ncgate.toml"), "--trace", str(trace)]) == 0
    shown = [json.loads(line)["text"] for line in trace.read_text().splitlines()
             if json.loads(line)["event"] == "display"]
    assert shown == ["\u041e\u0421\u0422 1", "\u041e\u0421\u0422 2", "\u041e\u0421\u0422 3"]


def test_a_cyrillic_letter_that_is_no_lookalike_stays_an_error(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_cell(tmp_path, CONFIG, {"A": "N1\u041b1=1\n"})  # Л looks like no address letter
    assert main(["check", str(tmp_path / "A.nc")]) == 1
    assert "A.nc:1:3: error NC002" in capsys.readouterr().out
