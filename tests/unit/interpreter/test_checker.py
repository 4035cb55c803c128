"""Check-time errors and warnings (spec 1.3, 1.5, 1.6): code and position of each."""

from __future__ import annotations

import pytest

from ncgate.interpreter.codes import DiagnosticCode as C
from ncgate.interpreter.nc110.checker import CheckContext, Limits, check_program
from ncgate.interpreter.nc110.parser import Program


def diagnose(text: str, **context: object) -> list[tuple[C, int, int]]:
    program = Program("P", "p.nc", text)
    ctx = CheckContext(**context)  # type: ignore[arg-type]
    return [(d.code, d.span.line, d.span.column) for d in check_program(program, ctx)]


def test_clean_program_has_no_diagnostic() -> None:
    text = '"START"\nN1(EXE,2,PROG92)\nN2G1X1F100\nN3(WAI,SA10=1)\nN4(BNC,START)\n'
    assert diagnose(text, runs_in=frozenset({1})) == []


def test_process_numbers_out_of_range() -> None:
    text = "N1(EXE,9,P)\nN2(WAI,0)\nN3(SND,6)\nN4(WAI,E1)\nN5(SND,5)\n"
    assert diagnose(text) == [
        (C.PROCESS_OUT_OF_RANGE, 1, 8), (C.PROCESS_OUT_OF_RANGE, 2, 8),
        (C.PROCESS_OUT_OF_RANGE, 3, 8),
    ]
    assert diagnose("N5(SND,7)", processes=8) == []


def test_own_process_rules_only_where_the_process_is_known() -> None:
    text = "N5(WAI,1)\nN6(SND,1)\nN7(EXE,1,P)\n"
    assert diagnose(text) == []
    assert diagnose(text, runs_in=frozenset({1})) == [
        (C.WAIT_FOR_SELF, 1, 8), (C.SND_TO_SELF, 2, 8), (C.EXE_ON_SELF, 3, 8)]
    assert diagnose(text, runs_in=frozenset({2})) == []


def test_exe_on_external_process() -> None:
    assert diagnose("N1(EXE,3,P)", external=frozenset({3})) == [(C.EXE_ON_EXTERNAL, 1, 8)]


def test_comparisons_on_bits() -> None:
    text = "N1(WAI,SA10>0)\nN2(WAI,SA10<1)\nN3(WAI,SA10#0)\nN4(WAI,SA10=2)\nN5(WAI,SA1.BY>3)\n"
    assert diagnose(text) == [
        (C.COMPARE_BIT_ORDER, 1, 8), (C.COMPARE_BIT_ORDER, 2, 8), (C.BIT_VALUE, 4, 13)]


def test_value_a_variable_can_never_hold_is_a_warning() -> None:
    assert diagnose("N1(WAI,SK2=300)\nN2(WAI,SYVAR1=40000)\nN3(WAI,SK2.IN=300)") == [
        (C.CONDITION_NEVER_HOLDS, 1, 12), (C.CONDITION_NEVER_HOLDS, 2, 15)]


@pytest.mark.parametrize(
    ("text", "column"),
    [
        ("E1000=1", 1), ("E1=E1000", 4), ("SYVAR256=1", 1), ("(WAI,SA1024=1)", 6),
        ("(WAI,SA128.BY=1)", 6), ("(WAI,SA127.IN=1)", 6), ("(WAI,SK512=1)", 6),
        ("(WAI,SK511.IN=1)", 6), ("G1XE1000", 4), ("(BGT,E1,SYVAR300,L)", 9),
    ],
)
def test_constant_indexes_out_of_range(text: str, column: int) -> None:
    found = diagnose(f'"L"\n{text}')
    assert (C.INDEX_OUT_OF_RANGE, 2, column) in found
    assert all(code is not C.INDEX_OUT_OF_RANGE or line == 2 for code, line, _ in found)


def test_limits_follow_the_config() -> None:
    limits = Limits(e_params=10, syvars=4, sa_bits=16, k_bytes=4)
    assert diagnose("E9=SYVAR3\n(WAI,SA15=1)\n(WAI,SK2.IN=1)", limits=limits) == []
    assert diagnose("E10=SYVAR4\n(WAI,SA2.BY=1)\n(WAI,SK3.IN=1)", limits=limits) == [
        (C.INDEX_OUT_OF_RANGE, 1, 1), (C.INDEX_OUT_OF_RANGE, 1, 5),
        (C.INDEX_OUT_OF_RANGE, 2, 6), (C.INDEX_OUT_OF_RANGE, 3, 6)]


def test_programs_do_not_write_plc_packets() -> None:
    assert diagnose("SA10=1\nSK2=3\nSK2.IN=E1") == [
        (C.WRITE_TO_PLC_PACKET, 1, 1), (C.WRITE_TO_PLC_PACKET, 2, 1),
        (C.WRITE_TO_PLC_PACKET, 3, 1)]


def test_unknown_label_with_suggestion_and_duplicates() -> None:
    program = Program("P", "p.nc", '"START"\nN1(BNC,STRAT)\nN2(BEQ,1,1,ZZZ)\n"START"\n')
    found = check_program(program, CheckContext())
    assert [(d.code, d.span.line, d.span.column) for d in found] == [
        (C.UNKNOWN_LABEL, 2, 3), (C.UNKNOWN_LABEL, 3, 3), (C.DUPLICATE_LABEL, 4, 1)]
    assert found[0].message == 'label "STRAT" is not defined (did you mean "START"?)'
    assert found[1].message == 'label "ZZZ" is not defined'


def test_labels_match_case_insensitively() -> None:
    assert diagnose('"Start"\n(BNC,START)') == []


def test_unbalanced_repeats() -> None:
    assert diagnose("(RPT,2)\n(RPT,3)\n(ERP)\n(ERP)\n") == []
    assert diagnose("(ERP)\n(RPT,2)\n(RPT,2)\n(ERP)\n") == [
        (C.UNBALANCED_REPEAT, 1, 1), (C.UNBALANCED_REPEAT, 2, 1)]


def test_repeats_nest_at_most_16_deep() -> None:
    nested = "".join("(RPT,2)\n" for _ in range(16)) + "".join("(ERP)\n" for _ in range(16))
    assert diagnose(nested) == []
    deeper = "(RPT,2)\n" + nested + "(ERP)\n"
    assert diagnose(deeper) == [(C.REPEAT_TOO_DEEP, 17, 1)]


def test_a_jump_into_an_rpt_body_from_outside_it_is_flagged() -> None:
    # Back into a finished body (from after its ERP), and in from before its RPT.
    text = '(RPT,2)\n"IN"\nG1X1F100\n(ERP)\n(BNC,IN)\n'
    assert diagnose(text) == [(C.JUMP_INTO_REPEAT, 5, 1)]
    assert diagnose('(BNC,IN)\n(RPT,2)\n"IN"\n(ERP)\n') == [(C.JUMP_INTO_REPEAT, 1, 1)]
    # Inside its own body, to its RPT line, or past the ERP: no warning.
    assert diagnose('(RPT,2)\n"IN"\nG1X1F100\n(BNC,IN)\n(ERP)\n') == []
    assert diagnose('"L"(RPT,2)\nG91G1X0.001F6000\n(BNC,L)\n(ERP)\n') == []
    assert diagnose('(RPT,2)\n(BNC,OUT)\n(ERP)\n"OUT"\n') == []


def test_a_jump_into_a_nested_rpt_body_names_the_innermost_body_it_enters() -> None:
    # Outer body lines 1..7, inner 2..5: from inside the outer body only (line 6) and from
    # outside both (line 8) a jump to line 3 enters the inner one; from inside it, none.
    text = ('(RPT,2)\n(RPT,3)\n"IN"\nG1X1F100\n(ERP)\n(BNC,IN)\n(ERP)\n(BNC,IN)\n'
            '(RPT,2)\n"OWN"\n(BNC,OWN)\n(ERP)\n')
    assert diagnose(text) == [(C.JUMP_INTO_REPEAT, 6, 1), (C.JUMP_INTO_REPEAT, 8, 1)]
    messages = [d.message for d in check_program(Program("T", "t.nc", text), CheckContext())
                if d.code is C.JUMP_INTO_REPEAT]
    assert all("(RPT) on line 2 " in m for m in messages), messages


def test_exe_program_and_device_must_exist_when_storage_is_known() -> None:
    ctx = {
        "find_program": lambda name, device: name.upper() == "PROG92",
        "has_device": lambda device: (device or "MP0") in {"MP0", "MP1"},
    }
    assert diagnose("(EXE,2,prog92)", **ctx) == []
    assert diagnose("(EXE,2,PROG99)\n(EXE,2,PROG92/MP3)", **ctx) == [
        (C.PROGRAM_NOT_FOUND, 1, 1), (C.UNKNOWN_DEVICE, 2, 1)]


def test_warnings_for_implicit_syvar_and_unmodelled_codes() -> None:
    found = diagnose("(WAI,SYVAR>5)\n(MIR,X)\n")
    assert found == [(C.SYVAR_WITHOUT_INDEX, 1, 6), (C.UNMODELLED_CODE, 2, 1)]


def test_all_errors_of_a_file_in_source_order() -> None:
    text = "N1(WAI,SA10>0)\nN2GXY\nN3(EXE,9,P)\nN4(WAI,SA12=1\n"
    assert [code for code, _, _ in diagnose(text)] == [
        C.COMPARE_BIT_ORDER, C.WORD_WITHOUT_VALUE, C.PROCESS_OUT_OF_RANGE, C.MISSING_CLOSE_PAREN]


@pytest.mark.parametrize(("text", "expected"), [
    # The blocks: each was last-wins, silently.
    ("G1X10X20F100", [(C.REPEATED_WORD, 6)]),
    ("G1X10F100F5000", [(C.REPEATED_WORD, 10)]),
    ("G1G0X10F100", [(C.MODAL_CONFLICT, 3)]),
    ("G1G1X10F100", [(C.REPEATED_WORD, 3)]),
    ("G90G91X1", [(C.MODAL_CONFLICT, 4)]), ("G17G18", [(C.MODAL_CONFLICT, 4)]),
    ("G1G81X1F100", [(C.MODAL_CONFLICT, 3)]),
    ("N1 M3 M5", [(C.MODAL_CONFLICT, 7)]), ("N1 M6 M6", [(C.REPEATED_WORD, 7)]),
    ("N1 M0 M30", [(C.MODAL_CONFLICT, 7)]),
    ("XE1XE2", [(C.REPEATED_WORD, 4)]), ("T1.1T2.1", [(C.REPEATED_WORD, 5)]),
    # Reported once a letter: a block of many X words is one diagnostic, at the second X.
    ("G1" + "X1Y2" * 50 + "F100", [(C.REPEATED_WORD, 7), (C.REPEATED_WORD, 9)]),
    # What a control accepts: G codes of different groups, M codes of different groups or
    # the machine's own, one of each address.
    ("N1G90G1G17X10Y5Z1F100", []), ("N1G0G40X0", []), ("N1T1.1M6M3S1000M8M100", []),
    ("N1 G1 X1 (SND,2) (SND,3)", []), ("N1GE1GE2X1F100", []),
])
def test_a_block_takes_one_word_an_address_and_one_code_a_modal_group(
        text: str, expected: list[tuple[C, int]]) -> None:
    assert [(code, col) for code, _, col in diagnose(text)] == expected


@pytest.mark.parametrize(("text", "column"), [("N1G999X1", 3), ("N1G1.5X1", 3), ("N1M1.5", 3),
                                              ("N1G20", 3)])
def test_a_g_or_m_code_the_language_does_not_know_is_a_warning(text: str, column: int) -> None:
    assert diagnose(text) == [(C.UNKNOWN_G_OR_M, 1, column)]
    assert diagnose("N1G0G1G2G3G4G17G18G19G40G41G42G80G81G89G90G91".replace("G", "\nG")) == []
