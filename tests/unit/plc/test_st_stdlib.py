"""The standard function blocks against the IEC 61131-3 timing diagrams, call by call on a
virtual clock: each row is (time in ms, inputs) -> the outputs the standard's diagram shows."""

from __future__ import annotations

import pytest

from ncgate.plc.st.stdlib import (
    CTD,
    CTU,
    CTUD,
    F_TRIG,
    MUX,
    R_TRIG,
    ROL,
    ROR,
    RS,
    SHL,
    SHR,
    SR,
    TOF,
    TON,
    TP,
    convert,
    wrap,
)


def run_timer(fb: TON | TOF | TP, rows: list[tuple[int, bool, bool, int]]) -> None:
    for t, in_, q, et in rows:
        fb.IN = in_
        fb(t)
        assert (q, et) == (fb.Q, fb.ET), f"t={t} IN={in_}"


def test_ton_diagram() -> None:
    # IN rises at 0 and stays 30 ms (< PT): no Q; rises at 100 for 80 ms: Q from 150 to 180.
    run_timer(TON(PT=50), [
        (0, True, False, 0), (10, True, False, 10), (30, False, False, 0),
        (100, True, False, 0), (140, True, False, 40), (150, True, True, 50),
        (170, True, True, 50), (180, False, False, 0), (190, False, False, 0)])


def test_tof_diagram() -> None:
    # IN on 0..20: Q on at once, off 50 after the fall (70); IN back on at 100 and off at
    # 110, on again at 130 before PT ran out: Q never drops.
    run_timer(TOF(PT=50), [
        (0, False, False, 0), (10, True, True, 0), (20, False, True, 0),
        (50, False, True, 30), (69, False, True, 49), (70, False, False, 50),
        (90, False, False, 50), (100, True, True, 0), (110, False, True, 0),
        (130, True, True, 0), (140, True, True, 0)])


def test_tp_diagram() -> None:
    # A rising IN starts a 50 ms pulse whatever IN does meanwhile; ET holds PT while IN
    # stays TRUE after the pulse and returns to 0 when IN is FALSE.
    run_timer(TP(PT=50), [
        (0, True, True, 0), (10, False, True, 10), (20, True, True, 20),
        (50, True, False, 50), (60, True, False, 50), (70, False, False, 0),
        (80, True, True, 0), (100, False, True, 20), (130, False, False, 0)])


def test_r_trig_pulses_for_one_call() -> None:
    fb = R_TRIG()
    seen = []
    for clk in (False, True, True, False, True, True):
        fb.CLK = clk
        fb()
        seen.append(fb.Q)
    assert seen == [False, True, False, False, True, False]
    first = R_TRIG(CLK=True)
    first()
    assert first.Q  # TRUE at the first call: a rise from the initial FALSE


def test_f_trig_pulses_on_the_fall_only() -> None:
    fb = F_TRIG()
    seen = []
    for clk in (False, True, False, False, True, False):
        fb.CLK = clk
        fb()
        seen.append(fb.Q)
    assert seen == [False, False, True, False, False, True]


def test_ctu_counts_rising_edges_and_stops_at_the_int_limit() -> None:
    fb = CTU(PV=3)
    for cu in (True, True, False, True, False, True):
        fb.CU = cu
        fb()
    assert (fb.CV, fb.Q) == (3, True)  # three rises
    fb.R = True
    fb()
    assert (fb.CV, fb.Q) == (0, False)
    top = CTU(PV=1, CV=32767)
    top.CU = True
    top()
    assert top.CV == 32767


def test_ctd_loads_and_counts_down_to_the_limit() -> None:
    fb = CTD(PV=2)
    fb.LD = True
    fb()
    assert (fb.CV, fb.Q) == (2, False)
    fb.LD = False
    for cd in (True, False, True, False, True):
        fb.CD = cd
        fb()
    assert (fb.CV, fb.Q) == (-1, True)
    bottom = CTD(CV=-32768)
    bottom.CD = True
    bottom()
    assert bottom.CV == -32768


def test_ctud_up_down_and_both_at_once() -> None:
    fb = CTUD(PV=2)
    for cu, cd in ((True, False), (False, False), (True, False), (False, True),
                   (False, False), (True, True)):  # both rise together: no count
        fb.CU, fb.CD = cu, cd
        fb()
    assert (fb.CV, fb.QU, fb.QD) == (1, False, False)
    fb.LD = True
    fb()
    assert (fb.CV, fb.QU) == (2, True)
    fb.LD, fb.R = True, True  # reset wins over load
    fb()
    assert (fb.CV, fb.QD) == (0, True)


def test_bistables() -> None:
    sr, rs = SR(S1=True, R=True), RS(S=True, R1=True)
    sr()
    rs()
    assert (sr.Q1, rs.Q1) == (True, False)  # set dominant, reset dominant
    sr.S1, rs.R1 = False, False
    sr.R = False
    sr()
    rs()
    assert (sr.Q1, rs.Q1) == (True, True)  # both hold / set


@pytest.mark.parametrize(("value", "type_name", "wrapped"), [
    (32768, "INT", -32768), (-32769, "INT", 32767), (256, "BYTE", 0), (-1, "UINT", 65535),
    (2**31, "DINT", -(2**31)), (200, "SINT", -56)])
def test_integers_wrap_as_on_a_plc(value: int, type_name: str, wrapped: int) -> None:
    assert wrap(value, type_name) == wrapped


def test_shifts_rotations_selection_and_conversions() -> None:
    assert SHL(0x81, 1, "BYTE") == 0x02 and SHR(0x81, 1, "BYTE") == 0x40
    assert ROL(0x81, 1, "BYTE") == 0x03 and ROR(0x81, 1, "BYTE") == 0xC0
    assert ROL(0x1234, 20, "WORD") == ROL(0x1234, 4, "WORD") == 0x2341
    assert MUX(2, "a", "b", "c") == "c"
    with pytest.raises(IndexError):
        MUX(3, "a", "b", "c")
    assert convert(2.5, "INT") == 2 and convert(3.5, "INT") == 4  # halves to even
    assert convert(40000.0, "INT") == 40000 - 65536 and convert(7, "REAL") == 7.0
