"""The code table: unique, stable in form, and documented."""

from __future__ import annotations

from ncgate.interpreter.codes import AlarmCode, DiagnosticCode, Severity, codes_markdown
from ncgate.plc.st.diagnostics import StCode
from ncgate.plc.st.diagnostics import codes_markdown as st_codes_markdown

from ...conftest import ROOT


def test_codes_are_unique_and_well_formed() -> None:
    codes = [c.code for c in DiagnosticCode]
    assert len(codes) == len(set(codes))
    for c in DiagnosticCode:
        isg = c.name.startswith("ISG_")  # the ISG dialect has its own codes (spec 5.2)
        prefix = {(False, Severity.ERROR): "NC", (False, Severity.WARNING): "NW",
                  (True, Severity.ERROR): "IS", (True, Severity.WARNING): "IW"}[
            (isg, c.severity)]
        assert c.code.startswith(prefix) and c.code[2:].isdigit() and len(c.code) == 5, c
    assert len({int(a) for a in AlarmCode}) == len(AlarmCode)


def test_st_codes_are_unique_and_well_formed() -> None:
    codes = [c.code for c in StCode]
    assert len(codes) == len(set(codes))
    assert all(c[:2] in ("ST", "SW") and c[2:].isdigit() and len(c) == 5 for c in codes)


def test_docs_table_is_the_code_table() -> None:
    assert (ROOT / "docs" / "diagnostics.md").read_text() == (
        codes_markdown() + st_codes_markdown()), (
        "docs/diagnostics.md is stale: regenerate it from interpreter.codes.codes_markdown() "
        "+ plc.st.diagnostics.codes_markdown()")
