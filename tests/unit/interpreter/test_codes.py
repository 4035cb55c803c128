"""The code table: unique, stable in form, and documented."""

from __future__ import annotations

from ncgate.interpreter.codes import AlarmCode, DiagnosticCode, Severity, codes_markdown

from ...conftest import ROOT


def test_codes_are_unique_and_well_formed() -> None:
    codes = [c.code for c in DiagnosticCode]
    assert len(codes) == len(set(codes))
    for c in DiagnosticCode:
        prefix = "NC" if c.severity is Severity.ERROR else "NW"
        assert c.code.startswith(prefix) and c.code[2:].isdigit() and len(c.code) == 5
    assert len({int(a) for a in AlarmCode}) == len(AlarmCode)


def test_docs_table_is_the_code_table() -> None:
    assert (ROOT / "docs" / "diagnostics.md").read_text() == codes_markdown(), (
        "docs/diagnostics.md is stale: regenerate it from interpreter.codes.codes_markdown()")
