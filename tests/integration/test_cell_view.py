"""The cell's view on a running gateway (gateway/view.py): built only when something reads it,
once however many reads, again after any change -- a write, a turn of the engine, a state
change inside a turn -- and never when nothing changed."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from ncgate.config.script import load_script
from ncgate.gateway import Gateway, load_config
from ncgate.gateway import view as cell_view
from ncgate.gateway.sim import run_sim
from ncgate.inputs import Source, SourceKind
from ncgate.interpreter.engine import Process, ProcessState

TEST_PLC = Source(SourceKind.API, "test PLC")
NOTHING_SERVED = {"modbus.enabled": False, "canopen.enabled": False}


def _cell(tmp_path: Path, program: str) -> Path:
    (tmp_path / "ncgate.toml").write_text('[nc]\nmain = "A"\n')
    (tmp_path / "A.nc").write_text(program)
    return tmp_path / "ncgate.toml"


def _counting(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    builds: list[int] = []
    real = cell_view.build

    def counted(*args: object) -> cell_view.CellView:
        builds.append(1)
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(cell_view, "build", counted)
    return builds


def test_a_sim_builds_no_view(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # ncgate sim's speed is a measured target: the view is the gateway's, built on demand.
    builds = _counting(monkeypatch)
    monkeypatch.setattr(cell_view, "_process", lambda *args: builds.append(1))
    config = load_config(_cell(tmp_path, "N1(DLY,0.5)\nN2(WAI,SK7=3)\nN3M30\n"))
    result = run_sim(config, "A", load_script(None), until=2.0)
    assert result.outcome in ("stall", "until") and builds == []


async def test_a_gateway_no_adapter_reads_builds_no_view(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    builds = _counting(monkeypatch)
    config = load_config(_cell(tmp_path, "N1(WAI,SK7=3)\nN2M30\n"), overrides=NOTHING_SERVED)
    async with Gateway(config) as gw:
        await gw.start()
        await gw.wait_state(1, "WAIT_COND", timeout_s=5)
        gw.write("SK7", 3, source=TEST_PLC)
        await gw.wait_idle(timeout_s=5)
    assert builds == []


async def test_a_view_is_built_once_for_many_reads_and_again_after_a_write(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    builds = _counting(monkeypatch)
    config = load_config(_cell(tmp_path, "N1(WAI,SK7=3)\nN2M30\n"), overrides=NOTHING_SERVED)
    async with Gateway(config) as gw:
        await gw.start()
        await gw.wait_state(1, "WAIT_COND", timeout_s=5)
        first = gw.view
        assert all(gw.view is first for _ in range(100))
        assert len(builds) == 1
        assert first.processes[0].state is ProcessState.WAIT_COND
        assert first.processes[0].wait is not None and first.processes[0].wait.value == 0
        gw.write("SK7", 3, source=TEST_PLC)  # wakes the wait and ends the program, inside
        after = gw.view
        assert after is not first and after.processes[0].state is ProcessState.IDLE
        assert first.processes[0].state is ProcessState.WAIT_COND  # a view never changes


async def test_a_state_listener_reads_the_state_it_hears_of(tmp_path: Path) -> None:
    # A reader inside the engine's turn (a TPDO built on a state change) sees the change,
    # though the turn has not ended: an event recorded or a state change is a change of the
    # view (this fails when the view waits for the turn's end).
    config = load_config(_cell(tmp_path, "N1(WAI,SK7=3)\nN2(WAI,SK7=4)\nN3M30\n"),
                         overrides=NOTHING_SERVED)
    seen: list[tuple[ProcessState, ProcessState]] = []
    async with Gateway(config) as gw:

        def heard(process: Process | None, old: ProcessState) -> None:
            if process is not None:
                seen.append((process.state, gw.view.processes[process.number - 1].state))

        await gw.start()
        await gw.wait_state(1, "WAIT_COND", timeout_s=5)
        gw.view  # noqa: B018 -- a view built before the changes below
        gw.engine.state_listeners.append(heard)
        gw.write("SK7", 3, source=TEST_PLC)
        gw.write("SK7", 4, source=TEST_PLC)
        await gw.wait_idle(timeout_s=5)
    assert seen and all(state is shown for state, shown in seen)


PLANT = """
[plant]
scan_ms = 10
[[plant.model]]
name = "clamp"
kind = "cylinder"
extend = "SA20"
extended = "SA30"
retracted = "SA31"
travel_ms = 300
"""


def _plant_cell(tmp_path: Path, program: str) -> Path:
    path = _cell(tmp_path, program)
    path.write_text(path.read_text() + PLANT)
    return path


async def test_a_view_keeps_the_image_and_the_plant_of_its_moment(tmp_path: Path) -> None:
    # The image and the plant are the view's, as of its moment: a write, a model moving and
    # a fault after it change the next view, never this one -- whether its image was read
    # before the writes or not (taken then, or copied before the first write).
    config = load_config(_plant_cell(tmp_path, "N1(WAI,SK7=3)\nN2M30\n"),
                         overrides=NOTHING_SERVED)
    async with Gateway(config) as gw:
        await gw.start()
        await gw.wait_state(1, "WAIT_COND", timeout_s=5)
        read, unread = gw.view, None
        assert read.image.k[7] == 0 and read.image.sa[31 >> 3] >> (31 & 7) & 1  # retracted
        gw.write("SK6", 1, source=TEST_PLC)
        unread = gw.view
        assert unread is not read
        gw.write("SK7", 3, source=TEST_PLC)
        gw.write("SA20", 1, source=TEST_PLC)  # the clamp extends
        gw.fault("clamp", "slow", factor=2.0)
        await gw.wait_idle(timeout_s=5)
        now = gw.view
        assert now.plant is not None and now.plant.models[0].state in ("extends", "extended")
        assert now.plant.faults[0].kind == "slow" and now.plant.models[0].fault == "slow"
        assert (now.image.k[7], now.image.sa[20 >> 3] >> (20 & 7) & 1) == (3, 1)
        assert now.image.writers()["SK"] == {6: str(TEST_PLC), 7: str(TEST_PLC)}
        for view in (read, unread):
            assert view.plant is not None and view.plant.models[0].state == "retracted"
            assert view.plant.faults == () and view.plant.models[0].fault is None
            assert view.image.k[7] == 0 and view.image.sa[20 >> 3] >> (20 & 7) & 1 == 0
        assert (read.image.k[6], unread.image.k[6]) == (0, 1)
        assert 6 not in read.image.writers()["SK"]
        assert unread.image.writers()["SK"] == {6: str(TEST_PLC)}


async def test_a_view_whose_image_nobody_reads_copies_none(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # A reader of the whole view after every write (the CANopen node's error register, a
    # status without its image) takes no copy of the image: the view kept is dropped before
    # the write.  One held across a write is copied, once.
    from ncgate.plc.image import FrozenImage

    copies: list[str] = []
    for name in ("_take_areas", "_take_stamps"):
        real = getattr(FrozenImage, name)
        monkeypatch.setattr(FrozenImage, name, lambda self, _real=real, _name=name: (
            copies.append(_name), _real(self))[1])
    config = load_config(_cell(tmp_path, "N1(WAI,SK7=3)\nN2M30\n"), overrides=NOTHING_SERVED)
    async with Gateway(config) as gw:
        await gw.start()
        await gw.wait_state(1, "WAIT_COND", timeout_s=5)
        for value in range(10):
            assert gw.view.processes[0].state is ProcessState.WAIT_COND
            gw.write("SYVAR1", value, source=TEST_PLC)
        assert copies == []
        held = gw.view
        gw.write("SYVAR1", 99, source=TEST_PLC)
        gw.write("SYVAR1", 100, source=TEST_PLC)
        assert sorted(copies) == ["_take_areas", "_take_stamps"]
        assert held.image.syvar[1] == 9 and gw.view.image.syvar[1] == 100


async def test_on_the_wall_clock_a_strokes_progress_moves_on_between_its_events(
        tmp_path: Path) -> None:
    """A cylinder without a position output has no event between its stroke's start and
    end: the view of it (the console's Plant panel, /api/status) showed "extends, 0 of
    600000 ms" until the end, as the new user found with a 3 s stroke.  Now it is read at
    the time of the read."""
    path = _plant_cell(tmp_path, "N1(WAI,SK7=3)\nN2M30\n")
    path.write_text(path.read_text().replace("travel_ms = 300", "travel_ms = 600000"))
    async with Gateway(load_config(path, overrides=NOTHING_SERVED)) as gw:
        gw.write("SA20", 1, source=TEST_PLC)  # a ten-minute stroke begins
        seen: list[str] = []
        async with asyncio.timeout(30):  # the old code: the same progress for ten minutes
            while True:
                model = gw.view.plant.models[0]  # type: ignore[union-attr]
                if model.state == "extends":
                    seen.append(model.detail)
                    if seen[0] != seen[-1]:
                        break
                await asyncio.sleep(0.01)  # (a stroke has no event to wait on: that is the
                # point; the timeout above is what fails, not a time asserted)
        assert model.detail.startswith("clamp extends, ") and model.detail.endswith(
            " of 600000 ms"), seen[-3:]
        assert gw.runtime.plant is not None
        first = gw.runtime.plant.status()["models"][0]["detail"]
        async with asyncio.timeout(30):  # Plant.status() (OPC UA's) reads it likewise
            while True:
                if gw.runtime.plant.status()["models"][0]["detail"] != first:
                    break
                await asyncio.sleep(0.01)
