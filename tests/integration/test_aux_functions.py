"""Auxiliary functions with the PLC's handshake (issue 28, item 1; docs/interfacing-a-plc.md).

The expected times come from the configuration and the programs, never from a run: a tool
change takes nc.tool_change_s, a G1 move its length over the feed, a G0 move its length over
nc.rapid_mm_min, a PLC scan plc.scan_ms (spec 2.4, 2.5).
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path
from typing import Any

import pytest

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway import Gateway
from ncgate.gateway.sim import run_sim
from ncgate.gateway.testing.modbus_kit import VirtualPLC
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.gateway.web.status import process as process_status
from ncgate.interpreter.engine import WaitKind

EventDict = dict[str, Any]

# The built-in cell's PLC, in Structured Text: it answers every strobe of P1..P3 after the
# work it stands for (coolant 100 ms, a tool 300 ms), holds the acknowledge until the NC drops
# the strobe (the next scan drops it), and plays the manual's SA10 for P2's N40.
CELL_PLC = """\
PROGRAM cell
VAR
  coolant : TON;
  tool1, tool2, tool3 : TON;
  answer : TON;
END_VAR
coolant(IN := NC.P[1].MSTROBE, PT := T#100ms);
NC.P[1].MACK := coolant.Q;
tool1(IN := NC.P[1].TSTROBE, PT := T#300ms);
NC.P[1].TACK := tool1.Q;
tool2(IN := NC.P[2].TSTROBE, PT := T#300ms);
NC.P[2].TACK := tool2.Q;
tool3(IN := NC.P[3].TSTROBE, PT := T#300ms);
NC.P[3].TACK := tool3.Q;
answer(IN := NC.P[2].STATE = 3 AND NC.P[2].N = 40, PT := T#500ms);
IF answer.Q THEN
  SA[10] := TRUE;
END_IF
IF SA[10] AND NC.P[2].N > 40 THEN
  SA[10] := FALSE;
END_IF
END_PROGRAM
"""
# The handshakes the commissioning runs: M08 before the first cut's motion, M09 after the
# rapid return, the T call before the tool change.  S and M6 are output with none.
AUX = {"nc.aux.codes": {"M8": "before_motion", "M9": "after_motion", "T": "before_motion"}}
SCAN = 0.010  # plc.scan_ms of the built-in cell
TOOL_CHANGE = 2.0  # nc.tool_change_s of the built-in cell


def _move_s(start: tuple[float, float], end: tuple[float, float], mm_min: float) -> float:
    return math.dist(start, end) / mm_min * 60.0


def _of(events: list[EventDict], proc: int, kind: str, **fields: Any) -> list[EventDict]:
    return [e for e in events if e["proc"] == proc and e["event"] == kind
            and all(e.get(k) == v for k, v in fields.items())]


def _after(events: list[EventDict], event: EventDict, proc: int) -> EventDict:
    """The next trace event of ``proc`` after ``event``."""
    i = events.index(event)
    return next(e for e in events[i + 1:] if e["proc"] == proc)


def _handshake(events: list[EventDict], aux: EventDict) -> tuple[EventDict, EventDict]:
    """The aux_ack and the resume that end the handshake of ``aux``."""
    proc = aux["proc"]
    rest = events[events.index(aux) + 1:]
    ack = next(e for e in rest if e["proc"] == proc and e["event"] == "aux_ack")
    resume = next(e for e in rest if e["proc"] == proc and e["event"] == "resume")
    assert ack["code"] == aux["code"] and resume["by"] == "aux"
    return ack, resume


def _check_cell_timing(events: list[EventDict], plc_answers: bool) -> None:
    """The built-in cell's first cycle, step by step, as the spec times it.  ``plc_answers``:
    the ST PLC's answer times are known (its work and its scan)."""
    t1 = _of(events, 1, "aux", code="T1")[0]
    assert t1["handshake"] == "before_motion" and t1["strobe"] == "SA898"  # P1 T: 896 + 2
    ack, resume = _handshake(events, t1)
    if plc_answers:  # the tool's 300 ms of work (from the first scan that saw the strobe)
        assert 0.3 <= ack["t"] - t1["t"] <= 0.3 + SCAN + 1e-9
        assert resume["t"] - ack["t"] == pytest.approx(SCAN)  # the next scan drops the ack
    # N3's tool change (M6) runs only once the T call is acknowledged: the block's motion
    # waited for it.  N4's M08 comes after it, before N4's cut.
    m8 = _of(events, 1, "aux", code="M8")[0]
    assert m8["n"] == 4 and m8["t"] == pytest.approx(resume["t"] + TOOL_CHANGE)
    ack8, resume8 = _handshake(events, m8)
    if plc_answers:
        assert 0.1 <= ack8["t"] - m8["t"] <= 0.1 + SCAN + 1e-9
        assert resume8["t"] - ack8["t"] == pytest.approx(SCAN)
    # N4's cut (X0Y0 -> X100Y50 at F500) starts at the acknowledge's end: N24 comes after it.
    n24 = _after(events, resume8, 1)
    assert n24["n"] == 24
    assert n24["t"] == pytest.approx(resume8["t"] + _move_s((0, 0), (100, 50), 500))
    # M09 after N76's rapid return (X50Y50 -> X0Y0), which follows N68's cut from X0Y0; N68
    # starts when N67's wait ends.  The next block (N77) waits for the acknowledge.
    m9 = _of(events, 1, "aux", code="M9")[0]
    assert m9["n"] == 76 and m9["handshake"] == "after_motion"
    # N67 (WAI,3) ends with P1's resume or, when P3 already waited in its SND, with that
    # SND's delivery: the last of these before M09 is where N68 began.
    n67 = [e for e in events[:events.index(m9)]
           if (e["proc"] == 1 and e["event"] == "resume")
           or (e["event"] == "snd" and e["to"] == 1)][-1]
    assert m9["t"] == pytest.approx(n67["t"] + _move_s((0, 0), (50, 50), 500)
                                    + _move_s((50, 50), (0, 0), 10000))
    _, resume9 = _handshake(events, m9)
    rest = events[events.index(resume9) + 1:]
    n77 = next(e for e in rest if (e["event"] == "snd" and e["to"] == 1) or (
        e["proc"] == 1 and e["event"] == "wait"))  # N77 (WAI,2): P2's SND, or P1 waits
    assert n77["t"] == resume9["t"]
    # The other processes' T calls were answered too, each once a cycle.
    assert len(_of(events, 2, "aux", code="T20")) == 2
    assert len(_of(events, 3, "aux", code="T30")) == 2
    assert [e["code"] for e in events if e["event"] == "aux" and e["proc"] == 1
            and e["code"] in ("M8", "M9")] == ["M8", "M9", "M8", "M9"]


def _cell_with_plc(tmp_path: Path, st: str, **overrides: Any) -> Any:
    (tmp_path / "cell.st").write_text(st)
    return load_config(None, overrides={"plc.logic": str(tmp_path / "cell.st"),
                                        "canopen.enabled": False, **AUX, **overrides})


def test_the_built_in_cell_commissions_with_st_logic_answering_m08_m09_and_t(
        tmp_path: Path) -> None:
    result = run_sim(_cell_with_plc(tmp_path, CELL_PLC), "PROG91", load_script(None))
    assert result.outcome == "idle" and result.alarms == 0
    events = result.events
    _check_cell_timing(events, plc_answers=True)
    # Every acknowledge was the PLC logic's, through the door (attributed to its line).
    assert {e["by"].split(":")[0] for e in events if e["event"] == "aux_ack"} == {
        "plc cell.st"}
    assert not [e for e in events if e["event"] == "hazard" and "PLC-side" in e["message"]]


def test_a_missing_acknowledge_is_a_stall_that_names_the_m_code(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from ncgate.gateway.sim import report

    # The PLC answers the tools and M08, never M09.
    st = CELL_PLC.replace("NC.P[1].MACK := coolant.Q;",
                          "NC.P[1].MACK := coolant.Q AND NC.P[1].M = 8;")
    result = run_sim(_cell_with_plc(tmp_path, st, **{"nc.stall_s": 5.0}), "PROG91",
                     load_script(None))
    assert result.outcome == "stall"
    stall = next(e for e in result.events if e["event"] == "stall")
    reasons = {b["proc"]: b for b in stall["blocked"]}
    assert reasons[1]["n"] == 76 and reasons[1]["reason"].startswith("M09 waits for the PLC")
    report(result, __import__("sys").stdout)
    assert "N76 M09 waits for the PLC to acknowledge it (SA960=1, now 0" in (
        capsys.readouterr().out)


async def test_the_built_in_cell_commissions_with_a_virtual_plc_over_modbus() -> None:
    config = ncgate_test_config(None, **AUX, **{"nc.time_scale": 200.0,
                                                "canopen.enabled": False})
    answered: list[tuple[int, str]] = []
    done = asyncio.Event()

    async def plc_program(plc: VirtualPLC) -> None:
        """The PLC: every strobe answered at once; SA10 for P2's N40, as the manual has it.
        (It stops between requests: a pymodbus request cancelled half-way is never
        answered.)"""
        while not done.is_set():
            for seen in await plc.aux_strobes():
                answered.append((seen.process, seen.code))
                await plc.ack_aux(seen)
            state, n, _, kind = (await plc.status(2))[:4]
            if state == 3 and n == 40 and kind == WaitKind.COND:
                await plc.set("SA10", 1)
            elif n > 40 and await plc.get("SA10"):
                await plc.set("SA10", 0)
            await asyncio.sleep(plc.poll_s)  # a Modbus client learns only by reading

    async with Gateway(config) as gw, VirtualPLC(*gw.modbus_address, gw.config) as plc:
        await plc.command(1)
        seen = await plc.expect_aux("T1", process=1)  # N3: the T call, before the M6
        assert seen.code == "T1"
        await plc.wait_state(1, "WAIT_COND")
        assert (await plc.status(1))[3] == WaitKind.AUX  # wait kind 6: the acknowledge
        assert gw.status(1).wait is not None and gw.status(1).wait.code == "T1"
        lane = process_status(gw, 1)["wait"]  # the console's lane (GET /api/status)
        assert (lane["kind"], lane["code"], lane["cond"], lane["value"]) == (
            "AUX", "T1", "SA962=1", 0)
        assert "waits for the PLC to acknowledge it" in lane["reason"]
        await plc.ack_aux(seen)
        task = asyncio.create_task(plc_program(plc))
        try:
            await gw.wait_idle(timeout_s=30)
        finally:
            done.set()
            await task
        events = gw.trace
    _check_cell_timing(events, plc_answers=False)
    assert (1, "M8") in answered and (1, "M9") in answered and (2, "T20") in answered
    acks = [e for e in events if e["event"] == "aux_ack"]
    assert acks and all(e["by"].startswith("modbus 127.0.0.1:") for e in acks)
