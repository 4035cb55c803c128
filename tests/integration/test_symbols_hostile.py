"""An I/O list ([symbols]'s symbols_file, issue 28 item 3) as a careless export writes it:
what would be read in more than one way is a config error naming the row, never a guess."""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.config import ConfigError, load_config

CELL = '[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n[canopen]\nenabled = false\n'


@pytest.mark.parametrize("header", ["name,var,var", "name,var,Name", "name;var;comment;comment"])
def test_a_header_that_names_a_column_twice_is_a_config_error(tmp_path: Path,
                                                              header: str) -> None:
    """'name,var,var' was taken, and each row's name read from the last 'var' column -- an
    export with two address columns (a PLC's and a field's) loaded the other one silently."""
    sep = ";" if ";" in header else ","
    row = sep.join(["door", "SA10", "SA11", "x"][:header.count(sep) + 1])
    (tmp_path / "io.csv").write_text(f"{header}\n{row}\n")
    (tmp_path / "ncgate.toml").write_text('symbols_file = "io.csv"\n' + CELL)
    with pytest.raises(ConfigError, match=r"symbols_file: .*io.csv:1: .*twice"):
        load_config(tmp_path / "ncgate.toml")
