"""The one status encoding (gateway/view.py) against the published tables, not against the
code that used to compute it: the state codes of docs/runtime.md (STEP 9: docs/plc.md), the
wait kinds of docs/isg.md and docs/interfacing-a-plc.md, README.md's Modbus map (discrete
inputs 16(k-1)+0..5: program loaded, running, waiting, alarm, motion active, hold; input
registers 100+20(k-1)+0..17: state, block N, line, wait kind/target, alarm, the counters --
SNDs sent, SNDs received, blocks executed, as ``ncgate map`` names them --, X/Y/Z µm as int32
saturating at its bounds; 32-bit values high word first), and the CANopen status record
0x2500+k-1 sub 1..8 (state, block N, source line, wait kind, wait target, alarm code, SNDs
sent, SNDs received: README.md, ``ncgate map``).  The expected numbers are worked out by
hand here."""

from __future__ import annotations

from dataclasses import replace

import pytest

from ncgate.gateway.view import ProcessView, encode, status_registers
from ncgate.interpreter.engine import ProcessState, ProcessStatus, WaitKind, WaitRecord
from ncgate.interpreter.engine.states import Stage


def _status(state: ProcessState, **fields: object) -> ProcessStatus:
    base = ProcessStatus(number=1, state=state, external=False, program="PROG91", line=0,
                         n=None, wait=None, alarm_code=0, alarm_message=None, snd_sent=0,
                         snd_received=0, blocks=0, position=(0.0, 0.0, 0.0),
                         motion_active=False, held=False)
    return replace(base, **fields)  # type: ignore[arg-type]


def _wait(kind: WaitKind, target: int) -> WaitRecord:
    return WaitRecord(kind=kind, target=target, code="(WAI,2)", where=("PROG91", 12, 70),
                      since=0.5, stage=Stage.DECODER)


def _view(s: ProcessStatus, loaded: bool = True) -> ProcessView:
    record, flags = encode(s, loaded)
    return ProcessView(
        number=1, state=s.state, external=False, program=s.program, line=s.line, n=s.n,
        block="", blocks=s.blocks, snd_sent=s.snd_sent, snd_received=s.snd_received,
        position=s.position, moving=s.motion_active, held=s.held, loaded=loaded, stopped=None,
        standing=None, single_block=False, feed=None, feed_override=100, rapid_override=100,
        wait=None, alarm=None, record=record, flags=flags)


# docs/runtime.md's table (and docs/plc.md for STEP): the code of each state.
STATE_CODES = {ProcessState.IDLE: 0, ProcessState.RUNNING: 1, ProcessState.WAIT_PROC: 2,
               ProcessState.WAIT_COND: 3, ProcessState.WAIT_SND: 4, ProcessState.WAIT_EXE: 5,
               ProcessState.DWELL: 6, ProcessState.HOLD: 7, ProcessState.ALARM: 8,
               ProcessState.STEP: 9}


@pytest.mark.parametrize("state", list(STATE_CODES))
def test_the_state_code_is_the_documented_one_on_both_fieldbuses(state: ProcessState) -> None:
    view = _view(_status(state))
    assert status_registers(view)[0] == STATE_CODES[state]
    assert view.canopen_record[0] == STATE_CODES[state]


def test_a_waiting_process_reads_as_the_map_and_the_dictionary_say() -> None:
    s = _status(ProcessState.WAIT_PROC, line=12, n=70, wait=_wait(WaitKind.PROC, 2),
                snd_sent=70_000, snd_received=3, blocks=123_456,
                position=(1.5, -2.0, 0.0004))
    view = _view(s)
    # state 2, N 70, line 12, wait kind 1 (an SND from P2: docs/isg.md's signal wait is the
    # same kind), target 2, no alarm; 70,000 = 1 * 65536 + 4464; 123,456 = 1 * 65536 + 57920;
    # X 1500 µm, Y -2000 µm as int32 (0xFFFFF830), Z 0.4 µm rounds to 0.
    assert status_registers(view) == [2, 70, 12, 1, 2, 0, 1, 4464, 0, 3, 1, 57920,
                                      0, 1500, 0xFFFF, 0xF830, 0, 0]
    assert view.canopen_record == (2, 70, 12, 1, 2, 0, 70_000, 3)
    # loaded, not running, waiting, no alarm, not moving, no hold
    assert view.flags == (True, False, True, False, False, False)


@pytest.mark.parametrize(("kind", "code"), [(WaitKind.FLUSH, 5), (WaitKind.AUX, 6)])
def test_a_flush_and_an_acknowledge_are_wait_cond_with_their_wait_kind(kind: WaitKind,
                                                                      code: int) -> None:
    # docs/isg.md: a flush is WAIT_COND (3) with wait kind 5; docs/interfacing-a-plc.md: an
    # acknowledge WAIT_COND with wait kind AUX (6); a condition has no target process.
    view = _view(_status(ProcessState.WAIT_COND, wait=_wait(kind, 0)))
    assert status_registers(view)[:6] == [3, 0, 0, code, 0, 0]
    assert view.canopen_record[:6] == (3, 0, 0, code, 0, 0)


def test_an_alarm_shows_its_code_and_the_alarm_flag() -> None:
    view = _view(_status(ProcessState.ALARM, line=3, n=30, alarm_code=143,
                         alarm_message="PROG91.nc:3 N30: wait timeout"))
    assert status_registers(view)[:6] == [8, 30, 3, 0, 0, 143]
    assert view.canopen_record[5] == 143
    assert view.flags == (True, False, False, True, False, False)


@pytest.mark.parametrize(("state", "held", "moving", "flags"), [
    (ProcessState.RUNNING, False, True, (True, True, False, False, True, False)),
    (ProcessState.DWELL, False, False, (True, True, False, False, False, False)),
    (ProcessState.WAIT_EXE, False, False, (True, False, True, False, False, False)),
    (ProcessState.WAIT_SND, False, False, (True, False, True, False, False, False)),
    (ProcessState.HOLD, True, False, (True, False, False, False, False, True)),
])
def test_the_process_flags_are_the_discrete_inputs_of_the_map(
        state: ProcessState, held: bool, moving: bool, flags: tuple[bool, ...]) -> None:
    # running: RUNNING or DWELL (a dwell is part of the program's run); waiting: the four
    # WAIT_ states; hold: a feed hold is on.
    assert _view(_status(state, held=held, motion_active=moving)).flags == flags


def test_an_idle_process_without_a_program_reads_all_zero() -> None:
    view = _view(_status(ProcessState.IDLE, program=None), loaded=False)
    assert status_registers(view) == [0] * 18
    assert view.canopen_record == (0,) * 8
    assert view.flags == (False,) * 6


@pytest.mark.parametrize(("mm", "words"), [
    (3e6, (0x7FFF, 0xFFFF)),  # 3 km: past +2,147,483,647 µm, the bound
    (-3e6, (0x8000, 0x0000)),  # and the other bound, never wrapped to a positive position
    (float("inf"), (0x7FFF, 0xFFFF)),
    (float("nan"), (0, 0)),  # no position to show
    (-0.0006, (0xFFFF, 0xFFFF)),  # -0.6 µm rounds to -1
])
def test_a_position_is_an_int32_of_um_saturating_at_its_bounds(
        mm: float, words: tuple[int, int]) -> None:
    view = _view(_status(ProcessState.RUNNING, position=(mm, 0.0, 0.0)))
    assert tuple(status_registers(view)[12:14]) == words


def test_n_and_the_line_are_16_bits_and_the_counters_32() -> None:
    view = _view(_status(ProcessState.RUNNING, n=70_000, line=65_537,
                         snd_sent=2**32 + 5, blocks=2**32 + 7))
    registers = status_registers(view)
    assert registers[1:3] == [70_000 - 65_536, 1]
    assert registers[6:8] == [0, 5]
    assert registers[10:12] == [0, 7]
    assert view.canopen_record[6] == 5
