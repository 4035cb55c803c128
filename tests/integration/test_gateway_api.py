"""The Python API of spec 4.5, in-process on the wall clock (scaled up to keep tests fast)."""

from __future__ import annotations

import asyncio
import itertools
from pathlib import Path

import pytest

from ncgate.gateway import Gateway, ProcessAlarmError, WaitIdleTimeout, load_config
from ncgate.inputs import Source, SourceKind
from ncgate.interpreter.engine import events as ev

from ..conftest import EXAMPLES

TEST_PLC = Source(SourceKind.API, "test PLC")

FREE_PORT = {"modbus.port": 0}


def fast(folder: Path, scale: float = 2000.0, **overrides: object):  # type: ignore[no-untyped-def]
    return load_config(folder / "ncgate.toml",
                       overrides={"nc.time_scale": scale, "modbus.port": 0, **overrides})


async def test_scheme3_with_the_test_playing_the_plc() -> None:
    async with Gateway(fast(EXAMPLES / "scheme3")) as gw:
        await gw.start("PROG91")
        await gw.wait_state(2, "WAIT_COND", timeout_s=10)
        status = gw.status(2)
        assert status.wait is not None and status.wait.cond == "SA10=1" and status.n == 40
        gw.write("SA10", 1, source=TEST_PLC)
        await gw.wait_idle(timeout_s=20)
        events = gw.trace
    write = next(i for i, e in enumerate(events) if e["event"] == "write" and e["var"] == "SA10")
    resume = next(i for i, e in enumerate(events) if e["event"] == "resume" and e["proc"] == 2
                  and e["n"] == 40)
    assert events[write]["who"] == "api test PLC" and write < resume
    assert events[resume]["by"] == "cond"
    ends = [(e["proc"], e["how"]) for e in events if e["event"] == "end"]
    assert sorted(ends) == [(1, "M30"), (2, "REL"), (2, "REL"), (3, "REL"), (3, "REL")]


async def test_a_write_wakes_its_wait_at_once(tmp_path: Path) -> None:
    # No polling between a write and the wake: the resume happens inside the write, at the
    # same instant on the gateway's clock (time scale 1).
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n')
    (tmp_path / "A.nc").write_text("N1(WAI,SK7=3)\nN2M30\n")
    async with Gateway(load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)) as gw:
        await gw.start()
        await gw.wait_state(1, "WAIT_COND", timeout_s=5)
        gw.write("SK7", 3, source=TEST_PLC)
        assert gw.status(1).state.name == "IDLE"  # resumed and ended, before any await
        await gw.wait_idle(timeout_s=5)
        write, resume = (next(e for e in gw.trace if e["event"] == kind)
                         for kind in ("write", "resume"))
    assert resume["t"] == write["t"] and resume["seq"] == write["seq"] + 1


async def test_wait_idle_times_out_with_the_why_records() -> None:
    async with Gateway(fast(EXAMPLES / "scheme3")) as gw:
        await gw.start("PROG91")
        with pytest.raises(WaitIdleTimeout) as caught:
            await gw.wait_idle(timeout_s=0.3)
    assert "P2 PROG92.nc:8 N40 (WAI,SA10=1) waits for SA10=1 (now 0)" in str(caught.value)


async def test_wait_idle_raises_on_alarms(tmp_path: Path) -> None:
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\ntime_scale = 100.0\n')
    (tmp_path / "A.nc").write_text("N1G1X10F600\nN2E1=1/0\n")
    async with Gateway(load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)) as gw:
        await gw.start()
        with pytest.raises(ProcessAlarmError, match="P1 division by zero"):
            await gw.wait_idle(timeout_s=5)


async def test_command_word_and_external_snd(tmp_path: Path) -> None:
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\ntime_scale = 50.0\n[[nc.process]]\nnumber = 4\nexternal = true\n')
    (tmp_path / "A.nc").write_text("N1G1X100F600\nN2(WAI,4)\nN3M30\n")
    async with Gateway(load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)) as gw:
        gw.command(1)  # cycle start: main in process 1
        # Its decoder reaches (WAI,4) at once, while the move of N1 goes on.
        await gw.wait_state(1, "WAIT_PROC", timeout_s=5)
        assert gw.status(1).motion_active
        gw.command(2)  # feed hold
        await gw.wait_state(1, "HOLD", timeout_s=5)
        assert gw.status(1).held
        gw.command(1)  # cycle start again: resume after the hold
        await gw.wait_state(1, "WAIT_PROC", timeout_s=5)
        gw.send(4, 1)
        await gw.wait_idle(timeout_s=5)
        starts = [e["by"] for e in gw.trace if e["event"] == "start"]
        assert starts == ["api"]
        assert [e["by"] for e in gw.trace if e["event"] == "resume"] == [4]


async def test_timing_follows_time_scale(tmp_path: Path) -> None:
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\ntime_scale = 20.0\n')
    (tmp_path / "A.nc").write_text("N1(DLY,4)\nN2M30\n")  # 4 s at 20x: 0.2 s of wall time
    async with Gateway(load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)) as gw:
        await gw.start()
        await gw.wait_idle(timeout_s=5)
        (start,) = [e for e in gw.trace if e["event"] == "start"]
        (end,) = [e for e in gw.trace if e["event"] == "end"]
    # The dwell ends at its timer's own time, however late the loop got round to it.
    assert end["t"] - start["t"] == pytest.approx(4.0, abs=2e-6)


async def test_a_stall_is_reported_after_stall_s_and_not_again_until_something_changes(
        tmp_path: Path) -> None:
    """nc.stall_s in run: every process blocked and nothing changing for stall_s (simulated)
    seconds gives one `stall` event naming the waits; outside can still end it."""
    (tmp_path / "A.nc").write_text("N10(WAI,SA10=1)\nN20(WAI,SA11=1)\nN30M30\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n[nc.storage]\nMP0 = "."\n')
    stalls: list[ev.Stall] = []
    seen = asyncio.Event()

    def listen(event: ev.Event) -> None:
        if isinstance(event, ev.Stall):
            stalls.append(event)
            seen.set()

    config = fast(tmp_path, scale=100.0, **{"nc.stall_s": 5.0, "canopen.enabled": False})
    async with Gateway(config, listeners=[listen]) as gw:
        await gw.start("A")
        async with asyncio.timeout(10):
            await seen.wait()
        (stall,) = stalls
        assert [(b.proc, b.n) for b in stall.blocked] == [(1, 10)]
        assert "(WAI,SA10=1) waits for SA10=1 (now 0)" in stall.blocked[0].reason
        assert stall.t >= 5.0
        seen.clear()
        gw.write("SA10", 1)  # something changed: P1 goes on to N20 and waits again
        async with asyncio.timeout(10):
            await seen.wait()
        assert [(b.proc, b.n) for b in stalls[1].blocked] == [(1, 20)]
        assert stalls[1].t >= gw.engine.last_change + 5.0 - 1e-9
        gw.write("SA11", 1)
        await gw.wait_idle(timeout_s=10)
    assert len(stalls) == 2


async def test_a_runaway_loop_is_an_alarm_and_start_returns(tmp_path: Path) -> None:
    """Issue 9.1: `await gw.start` returns; the loop ends in AL144 naming the loop."""
    (tmp_path / "LOOP.nc").write_text('"L"\nN1E1=E1+1\nN2(BNC,L)\n')
    (tmp_path / "ncgate.toml").write_text('[nc.storage]\nMP0 = "."\n')
    async with Gateway(fast(tmp_path)) as gw:
        await gw.start("LOOP")
        with pytest.raises(ProcessAlarmError, match=r"runaway: 100000 blocks.*line 3"):
            await gw.wait_idle(timeout_s=20)
        assert gw.status(1).alarm_code == 144


async def test_an_endless_loop_without_limit_can_be_reset_by_the_fieldbus(
        tmp_path: Path) -> None:
    (tmp_path / "LOOP.nc").write_text('"L"\nN1E1=E1+1\nN2(BNC,L)\n')
    (tmp_path / "ncgate.toml").write_text('[nc]\nrunaway_blocks = 0\n[nc.storage]\nMP0 = "."\n')
    async with Gateway(fast(tmp_path)) as gw:
        await gw.start("LOOP")
        driver = gw._driver
        assert driver is not None
        for _ in range(3):  # the engine hands the loop back between slices
            driver.changed.clear()
            await driver.changed.wait()
        blocks = gw.status(1).blocks
        assert gw.status(1).state.name == "RUNNING" and blocks > 0
        gw.command(3)  # reset, as a PLC would write it
        await gw.wait_idle(timeout_s=5)


async def test_the_engine_says_when_it_falls_behind_its_clock(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A dwell loop far denser than the loop can run at this time scale: the engine cannot
    keep nc.time_scale, and says so -- in the status, Modbus info register 8, and a WARNING
    (once a minute).  After a reset it keeps time again and the lag is 0."""
    from ncgate.gateway.modbus.map import Table

    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\ntime_scale = 1000.0\n')
    (tmp_path / "A.nc").write_text('"L" N1(DLY,0.001)\nN2(BNC,L)\n')
    async with Gateway(load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)) as gw:
        assert gw.lag_s == 0.0
        await gw.start()
        driver = gw._driver
        assert driver is not None
        async with asyncio.timeout(10):
            while gw.lag_s < 200.0:  # 0.2 s of the wall clock behind: worth a warning
                driver.changed.clear()
                await driver.changed.wait()
        (lag_ms,) = gw.map.read_registers(gw, Table.INPUT, 8, 1)
        assert lag_ms > 0
        gw.command(3)  # reset: nothing is due any more
        driver.changed.clear()
        await driver.changed.wait()
        assert gw.lag_s == 0.0 and driver.max_lag_s > 0.0
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len([w for w in warnings if "behind the clock" in w]) == 1


async def test_a_big_program_is_read_off_the_loop(tmp_path: Path) -> None:
    """A cycle start of a 2 MB main: while it is read and checked, the fieldbus is served
    (Modbus answers come in before the program starts), and then it starts."""
    from ncgate.gateway.testing.modbus_kit import VirtualPLC

    lines = [f"N{n % 9999}G1X{n % 500}Y{(n * 7) % 500}F60000\n" for n in range(100_000)]
    (tmp_path / "BIG.nc").write_text("".join(lines) + "M30\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "BIG"\n')
    async with Gateway(load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)) as gw, \
            VirtualPLC(*gw.modbus_address, gw.config) as plc:
        await plc.command(1)  # answered at once: the program is read in a thread
        answered_before_start = 0
        async with asyncio.timeout(60):
            while gw.engine.processes[1].loaded is None:
                await plc.status(1)  # a Modbus round trip through the gateway's loop
                answered_before_start += 1
        assert answered_before_start >= 3, answered_before_start
        (start,) = [e for e in gw.trace if e["event"] == "start"]
        assert start["prog"] == "BIG" and start["by"].startswith("modbus 127.0.0.1:")


async def test_a_close_while_a_big_program_is_checked_kills_its_child(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    """A program of 512 KB and more is checked in a child process (interpreter/child.py):
    a gateway closed while it works kills the child, and the reading thread ends quietly
    (nothing is kept of the cancelled read: the next start reads the file anew)."""
    import signal
    import subprocess
    import threading

    from ncgate.interpreter import child as child_module

    lines = [f"N{n % 9999}G1X{n % 500}Y{(n * 7) % 500}F60000\n" for n in range(400_000)]
    (tmp_path / "BIG.nc").write_text("".join(lines) + "M30\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "BIG"\n')
    children: list[subprocess.Popen[bytes]] = []
    spawned = threading.Event()
    real_popen = subprocess.Popen

    def popen(*args: object, **kwargs: object) -> subprocess.Popen[bytes]:
        child: subprocess.Popen[bytes] = real_popen(*args, **kwargs)  # type: ignore[call-overload]
        if child_module.__name__ in child.args:  # type: ignore[operator]
            children.append(child)
            spawned.set()
        return child

    monkeypatch.setattr(child_module.subprocess, "Popen", popen)
    async with Gateway(load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)) as gw:
        gw.command(1)  # cycle start: BIG is read in a thread, checked in a child
        assert await asyncio.to_thread(spawned.wait, 30)
        store = gw.runtime.store
    # Closed: the child was killed, not left to check 8 MB for nobody.
    (child,) = children
    assert child.wait(timeout=10) == -signal.SIGKILL
    readers = [t for t in threading.enumerate() if t.name == "ncgate load BIG"]
    for reader in readers:
        await asyncio.to_thread(reader.join, 30)
    assert not any(t.is_alive() for t in readers)
    assert not store.ready("BIG", 1)  # the cancelled read was not kept
    assert [r.getMessage() for r in caplog.records if r.levelno >= 30] == []


async def test_a_gateway_tunes_the_collector_and_leaves_the_switch_interval(
        tmp_path: Path) -> None:
    """While a gateway runs the garbage collector's young generation is 5,000 objects (700
    made one write in 200 pay a collection on its way to the resume:
    lifecycle.GC_YOUNG_OBJECTS), put back when it closes.  The switch interval is the
    process's: `ncgate run` takes 0.2 ms, tune_interpreter() gives it to an embedding
    program (a test's own CANopen master took a quarter fewer TPDOs a second at it)."""
    import gc
    import sys

    from ncgate.gateway.lifecycle import GC_YOUNG_OBJECTS, GIL_SWITCH_S, tune_interpreter

    before, threshold = sys.getswitchinterval(), gc.get_threshold()
    assert before > GIL_SWITCH_S  # Python's default, 5 ms
    assert threshold[0] < GC_YOUNG_OBJECTS  # Python's default, 700
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n')
    async with Gateway(load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)):
        assert sys.getswitchinterval() == before
        assert gc.get_threshold() == (GC_YOUNG_OBJECTS, *threshold[1:])
    assert sys.getswitchinterval() == before and gc.get_threshold() == threshold
    restore = tune_interpreter()  # what `ncgate run` takes for its whole process
    try:
        assert sys.getswitchinterval() == pytest.approx(GIL_SWITCH_S)
        assert gc.get_threshold() == (GC_YOUNG_OBJECTS, *threshold[1:])
    finally:
        restore()
    assert sys.getswitchinterval() == before and gc.get_threshold() == threshold


def test_run_in_process_gives_back_the_switch_interval_and_the_collector(
        tmp_path: Path) -> None:
    """`main(["run", ...])` takes run's switch interval and young generation while it serves
    and puts them back when it returns: a test that ran a gateway so left them to every test
    after it in its process (this file's test above then failed, by the order xdist chose)."""
    import gc
    import sys

    from ncgate.gateway.cli.main import main

    (tmp_path / "O1.nc").write_text("N10 (DLY,0.05)\nN20 M30\n")
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "O1"\n[modbus]\nport = 0\n[canopen]\nenabled = false\n'
        '[web]\nenabled = false\n')
    (tmp_path / "s.toml").write_text('[[expect]]\nname = "ends"\ncond = "P1 IDLE"\nby = 0.3\n')
    before = (sys.getswitchinterval(), gc.get_threshold())
    assert main(["run", "--config", str(tmp_path / "ncgate.toml"), "--script",
                 str(tmp_path / "s.toml")]) == 0
    assert (sys.getswitchinterval(), gc.get_threshold()) == before


async def test_a_write_storm_does_not_slow_the_machine(tmp_path: Path) -> None:
    """Inputs bring the engine to now by running what was due before them, each at its own
    time: a dwell loop under a storm of writes keeps exactly its 10 ms a round (machine
    time), instead of starting each dwell when a write happened to jump the clock.

    lookahead = 0: each round's SYVAR1 write acts after its dwell, in motion order. With the
    default look-ahead the decoder ran 16 rounds ahead at the start (16 writes at the same
    time, each a hazard), which the test saw only while the 10,000-event trace ring had not
    wrapped: it failed on a machine too slow to wrap it. The rounds are heard by a trace
    listener, every one of them, and the storm lasts a number of rounds, not of seconds."""
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\ntime_scale = 20.0\n'
                                          'lookahead = 0\n')
    (tmp_path / "A.nc").write_text('"L" N1(DLY,0.01)\nN2E1=E1+1\nN3SYVAR1=E1\nN4(BNC,L)\n')
    rounds: list[float] = []
    hazards: list[ev.Hazard] = []

    def listen(event: ev.Event) -> None:
        if isinstance(event, ev.Write) and event.var == "SYVAR1":
            rounds.append(event.t)
        elif isinstance(event, ev.Hazard):
            hazards.append(event)

    config = load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)
    async with Gateway(config, listeners=[listen]) as gw:
        await gw.start()
        async with asyncio.timeout(60):
            while len(rounds) < 50:  # the storm: writes as fast as they come, for 50 rounds
                for _ in range(50):
                    gw.write("SK1", 1)
                await asyncio.sleep(0)  # the loop runs the engine's timers between bursts
    assert not hazards
    gaps = {round(b - a, 6) for a, b in itertools.pairwise(rounds)}
    assert gaps == {0.01}, sorted(gaps)[-5:]


async def test_the_programs_an_exe_starts_are_read_ahead_off_the_loop(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A started program's EXE chain (A -> BIG -> C) is read in a thread while A runs, so
    the EXEs find their programs read: nothing of BIG or C is read on the loop, where 2 MB
    would stall every fieldbus client (issue 24)."""
    import threading

    from ncgate.gateway.programs import ProgramStore

    lines = [f"N{n % 9999}G1X{n % 500}Y{(n * 7) % 500}F60000\n" for n in range(100_000)]
    (tmp_path / "BIG.nc").write_text("N1(EXE,3,C)\n" + "".join(lines) + "M30\n")
    (tmp_path / "C.nc").write_text("N1M30\n")
    (tmp_path / "A.nc").write_text("N1(WAI,SA5=1)\nN2(EXE,2,BIG)\nN3M30\n")
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n')
    read_on: dict[str, str] = {}
    real_read = ProgramStore._read

    def spy(self: ProgramStore, path: Path, version: object, process: int,
            apart: bool = False) -> object:
        result = real_read(self, path, version, process, apart)  # type: ignore[arg-type]
        read_on.setdefault(path.stem, threading.current_thread().name)
        return result

    monkeypatch.setattr(ProgramStore, "_read", spy)
    c_started = asyncio.Event()

    def listen(event: ev.Event) -> None:
        if isinstance(event, ev.Start) and event.proc == 3:
            c_started.set()

    config = load_config(tmp_path / "ncgate.toml", overrides=FREE_PORT)
    async with Gateway(config, listeners=[listen]) as gw:
        await gw.start()  # A is read in a thread, which then reads ahead of A's EXEs
        for reader in [t for t in threading.enumerate() if t.name == "ncgate load A"]:
            await asyncio.to_thread(reader.join, 60)  # (gone already: it is done)
        store = gw.runtime.store
        assert store.ready("BIG", 2) and store.ready("C", 3)
        assert gw.status(1).state.name == "WAIT_COND"  # A has not reached its EXE yet
        gw.write("SA5", 1)
        async with asyncio.timeout(30):
            await c_started.wait()
        starts = [(e["proc"], e["prog"]) for e in gw.trace if e["event"] == "start"]
    assert starts == [(1, "A"), (2, "BIG"), (3, "C")]
    main = threading.main_thread().name
    assert read_on["BIG"] != main and read_on["C"] != main, read_on
