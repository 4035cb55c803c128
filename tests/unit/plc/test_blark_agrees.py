"""An independent parser agrees on what is valid Structured Text (issue 29, item 7).

blark (a lark-based IEC 61131-3 parser, Beckhoff TwinCAT's dialect, on PyPI) reads every ST
file of the repository that is marked valid -- ``tests/programs/st/valid/`` and the examples'
``.st`` files -- and every one marked invalid
(``tests/programs/st/invalid/``, syntax errors).  ncgate must load each valid file and
refuse each invalid one, and blark must say the same.  Where the two disagree for a reason
(a gap of blark's, or a construct ncgate refuses), the file is listed in ``DISAGREE`` with
that reason, and the test checks that they still disagree: a listed file that blark comes
to accept fails the test until it is taken off the list.  Nothing is skipped in silence.

blark checks syntax only (it has no type checker): the invalid corpus is syntax errors.  The
vendored utility library (``library/``) is no plain ST file -- it is written as logi.CAD
units -- and ``test_utility_library.py`` reads it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ncgate.plc.st.compiler import Context, compile_logic
from ncgate.plc.st.diagnostics import LogicError
from ncgate.plc.st.plcopen import read_logic_file

from ...conftest import EXAMPLES, ROOT

CORPUS = ROOT / "tests" / "programs" / "st"
VALID = sorted([*(CORPUS / "valid").glob("*.st"), *EXAMPLES.rglob("*.st")])
INVALID = sorted((CORPUS / "invalid").glob("*.st"))
CONTEXT = Context(1024, 512, 256, 5, frozenset())
# Files on which ncgate and blark 0.8.3 disagree, and why (relative to the repository).
DISAGREE: dict[str, str] = {
    "tests/programs/st/valid/state_machine.st":
        "blark reads a typed enumeration value (E_State#FILLING, IEC 61131-3 6.4.4.2) only "
        "as a CASE label, not in an expression: TwinCAT writes E_State.FILLING",
}


def ncgate_accepts(path: Path) -> bool:
    """ncgate's verdict on a file: an example's logic with its cell's context (the I/O names
    of its [symbols] are variables there), any other file with a bare one."""
    context = CONTEXT
    config = path.parent / "ncgate.toml"
    if config.is_file():
        from ncgate.config import load_config
        from ncgate.gateway.plc import logic_context

        context = logic_context(load_config(config, serving=False))
    try:
        compile_logic([read_logic_file(path)], context)
    except LogicError:
        return False
    return True


def blark_accepts(path: Path) -> bool:
    from blark.parse import parse_source_code

    result = parse_source_code(path.read_text(encoding="utf-8"), fn=str(path))
    return result.exception is None


def test_the_corpus_is_there() -> None:
    assert len(VALID) >= 9 and len(INVALID) >= 5
    assert EXAMPLES / "plclogic" / "plc.st" in VALID


@pytest.mark.parametrize("path", [*VALID, *INVALID],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_ncgate_and_blark_agree_on_validity(path: Path) -> None:
    marked_valid = path in VALID
    assert ncgate_accepts(path) is marked_valid, "ncgate does not read it as marked"
    name = str(path.relative_to(ROOT))
    theirs = blark_accepts(path)
    if name in DISAGREE:
        assert theirs is not marked_valid, (f"blark now agrees on {name}: take it off "
                                            "DISAGREE")
    else:
        assert theirs is marked_valid, f"blark says {'valid' if theirs else 'invalid'}"


def test_every_listed_disagreement_is_a_file_of_the_corpus() -> None:
    files = {str(p.relative_to(ROOT)) for p in [*VALID, *INVALID]}
    assert set(DISAGREE) <= files
