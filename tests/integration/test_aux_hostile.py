"""Auxiliary functions ([nc.aux], issue 28 item 1) against a client that is not the PLC it
should be: the strobe is the NC's, but any Modbus client, the sim script or a force may write
its bit.  What the NC then says of the wait must be what the image holds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ncgate.config import load_config
from ncgate.config.script import load_script
from ncgate.gateway.sim import run_sim


def _sim(tmp_path: Path, script: str, main: str = "A") -> Any:
    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\nlookahead = 0\nstall_s = 2.0\n[nc.storage]\nMP0 = "."\n'
        '[canopen]\nenabled = false\n[nc.aux]\nhandshake = "before_motion"\n')
    (tmp_path / "A.nc").write_text("N10M08\nN20M30\n")
    (tmp_path / "script.toml").write_text(script)
    return run_sim(load_config(tmp_path / "ncgate.toml"), main,
                   load_script(tmp_path / "script.toml"), None)


def test_a_stall_report_says_the_strobe_is_down_when_another_writer_dropped_it(
        tmp_path: Path) -> None:
    """A client drops the NC's strobe SA896 at 0.5 s: the PLC sees no function and never
    acknowledges.  The report said 'strobe SA896=1' (a constant of the text) -- the one
    thing a commissioning engineer would check first, and it was wrong."""
    result = _sim(tmp_path, '[[write]]\nat = 0.5\nset = "SA896=0"\n')
    assert result.outcome == "stall"
    stall = next(e for e in result.events if e["event"] == "stall")
    (blocked,) = stall["blocked"]
    assert blocked["n"] == 10
    reason = blocked["reason"]
    assert "M08 waits for the PLC to acknowledge it (SA960=1, now 0" in reason
    assert "SA896=1" not in reason and "SA896 is 0" in reason
    assert "script write[0]" in reason  # who dropped it


def test_a_stall_report_of_an_undisturbed_strobe_says_it_is_up(tmp_path: Path) -> None:
    result = _sim(tmp_path, "")
    stall = next(e for e in result.events if e["event"] == "stall")
    (blocked,) = stall["blocked"]
    assert "strobe SA896=1" in blocked["reason"]


def test_an_acknowledge_of_a_strobe_another_writer_set_is_a_hazard_that_says_so(
        tmp_path: Path) -> None:
    """A client sets SA896 (the NC's strobe) with no function output; the PLC acknowledges
    it.  The hazard said 'no strobe up (SA896 is 0)' while SA896 was 1."""
    (tmp_path / "B.nc").write_text("N10(DLY,1)\nN20M30\n")
    result = _sim(tmp_path, '[[write]]\nat = 0.2\nset = "SA896=1"\n'
                            '[[write]]\nat = 0.5\nset = "SA960=1"\n', main="B")
    assert result.outcome == "idle" and result.alarms == 0
    (hazard,) = [e for e in result.events if e["event"] == "hazard"]
    assert hazard["t"] == 0.5 and "SA960" in hazard["message"]
    assert "SA896 is 0" not in hazard["message"]
    assert "SA896 is 1" in hazard["message"] and "script write[0]" in hazard["message"]


async def test_a_forced_strobe_the_nc_cannot_drop_is_said_in_the_wait(tmp_path: Path) -> None:
    """The strobe SA896 forced to 1 (a commissioning engineer's force of the NC's output):
    the PLC acknowledges, the NC's drop of the strobe is overridden, and a PLC that drops
    its acknowledge only when the strobe drops never does.  The wait said 'the NC dropped
    the strobe SA896' while SA896 read 1."""
    from ncgate.gateway import Gateway
    from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
    from ncgate.inputs import Force, Var

    (tmp_path / "ncgate.toml").write_text(
        '[nc]\nmain = "A"\nlookahead = 0\n[nc.storage]\nMP0 = "."\n'
        '[canopen]\nenabled = false\n[nc.aux]\nhandshake = "before_motion"\n')
    (tmp_path / "A.nc").write_text("N10M08\nN20M30\n")
    async with Gateway(ncgate_test_config(tmp_path / "ncgate.toml")) as gw:
        gw.apply(Force(Var.parse("SA896"), 1))
        await gw.start()
        await gw.wait_state(1, "WAIT_COND", timeout_s=10)
        gw.write("SA960", 1)  # the PLC's acknowledge: the NC drops its strobe -- overridden
        assert gw.read("SA896") == 1
        blocked = gw.describe_blocked()
        assert "waits for the PLC to drop its acknowledge" in blocked
        assert "the NC dropped the strobe SA896)" not in blocked
        assert "SA896 is still 1" in blocked
