"""The heartbeat consumer and what the node does when the master dies (issue 11, item 11);
store/restore of the communication parameters (item 12); a whole DCF applied the way a
master tool does.  Timers on a clock the test moves."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import struct
import subprocess
import sys
from pathlib import Path

import canopen
import pytest

from ncgate.config import Config, load_config
from ncgate.config.state import state_folder
from ncgate.gateway import Gateway
from ncgate.gateway.canopen import store
from ncgate.gateway.canopen.clock import ManualClock
from ncgate.gateway.canopen.dictionary import write_eds
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config
from ncgate.interpreter.engine import ProcessState

from .conftest import Master, connect_master, sdo_error, u8, u32

MASTER_ID = 1
EMCY = 0x90


async def heartbeat(master: Master, state: int = 0x05) -> None:
    """The master's heartbeat (node 1, OPERATIONAL), handled by the node when this returns."""
    master.network.send_message(0x700 + MASTER_ID, bytes((state,)))
    await master.barrier()


async def watch_master(master: Master, ms: int = 500) -> None:
    await master.download(0x1016, 1, u32(MASTER_ID << 16 | ms))


async def running_cell(gw: Gateway) -> None:
    gw.command(1)
    await gw.wait_state(1, "WAIT_COND", timeout_s=5)  # MAIN waits for SA10, SIDE for SK5


def alarms(gw: Gateway) -> list[dict[str, object]]:
    return [e for e in gw.trace if e["event"] == "alarm"]


# -- 11. heartbeat consumer ----------------------------------------------------------------------

async def test_master_lost_alarms_sends_emcy_and_holds(clocked: Gateway, master: Master,
                                                       clock: ManualClock) -> None:
    await watch_master(master)
    await running_cell(clocked)
    await heartbeat(master)
    clock.advance(0.4)
    await heartbeat(master)  # in time: the deadline moves on
    clock.advance(0.4)
    await master.barrier()
    assert alarms(clocked) == [] and master.frames[EMCY].empty()
    clock.advance(0.1)  # 500 ms since the last heartbeat
    code, register, data = struct.unpack("<HB5s", await master.next(EMCY))
    assert (code, register, data[0]) == (0x8130, 0x11, MASTER_ID)  # generic + communication
    (alarm,) = alarms(clocked)
    assert (alarm["proc"], alarm["code"]) == (0, "AL150")
    assert "node 1" in str(alarm["message"]) and "feed hold" in str(alarm["message"])
    assert all(p.held for p in clocked.engine.processes.values() if not p.external)
    assert await master.upload(0x1001, 0) == u8(0x11)
    # it comes back: error reset, the register clears, the processes stay held
    await heartbeat(master)
    code, register, _ = struct.unpack("<HB5s", await master.next(EMCY))
    assert (code, register) == (0, 0)
    assert await master.upload(0x1001, 0) == u8(0)
    assert clocked.engine.processes[1].held
    clocked.command(1)  # cycle start: on it goes
    assert not clocked.engine.processes[1].held


@pytest.mark.parametrize("ncgate_config", [{"canopen.on_master_lost": "reset"}],
                         indirect=True)
async def test_master_lost_reset(clocked: Gateway, master: Master, clock: ManualClock) -> None:
    await watch_master(master, 200)
    await running_cell(clocked)
    await heartbeat(master)
    clock.advance(0.2)
    await master.next(EMCY)
    await clocked.wait_idle(timeout_s=5)  # reset: every process IDLE
    assert [e["how"] for e in clocked.trace if e["event"] == "end"][:2] == ["reset", "reset"]


@pytest.mark.parametrize("ncgate_config", [{"canopen.on_master_lost": "none"}],
                         indirect=True)
async def test_master_lost_none_only_reports(clocked: Gateway, master: Master,
                                             clock: ManualClock) -> None:
    await watch_master(master, 200)
    await running_cell(clocked)
    await heartbeat(master)
    clock.advance(0.2)
    await master.next(EMCY)
    assert len(alarms(clocked)) == 1
    assert clocked.status(1).state is ProcessState.WAIT_COND
    assert not clocked.engine.processes[1].held


async def test_watching_starts_with_a_heartbeat_and_a_boot_up_pauses_it(
        clocked: Gateway, master: Master, clock: ManualClock) -> None:
    await watch_master(master, 100)
    clock.advance(1.0)  # no heartbeat yet: nothing is watched
    await heartbeat(master)
    await heartbeat(master, 0x00)  # the master boots again
    clock.advance(1.0)
    await master.barrier()
    assert alarms(clocked) == [] and master.frames[EMCY].empty()
    await heartbeat(master, 0x7F)  # pre-operational heartbeat: watched again
    clock.advance(0.1)
    assert struct.unpack_from("<H", await master.next(EMCY))[0] == 0x8130


async def test_unwatching_a_lost_master_clears_its_alarm(clocked: Gateway, master: Master,
                                                         clock: ManualClock) -> None:
    await watch_master(master, 100)
    await heartbeat(master)
    clock.advance(0.1)
    await master.next(EMCY)
    await master.download(0x1016, 1, u32(0))
    code, register, _ = struct.unpack("<HB5s", await master.next(EMCY))
    assert (code, register) == (0, 0)


async def test_consumer_entries_for_one_node_twice_are_refused(gw: Gateway,
                                                               master: Master) -> None:
    await master.download(0x1016, 1, u32(MASTER_ID << 16 | 500))
    assert await sdo_error(master.download(0x1016, 2, u32(MASTER_ID << 16 | 800))) == 0x06040043
    assert await master.upload(0x1016, 2) == u32(0)
    await master.download(0x1016, 2, u32(2 << 16 | 800))  # another node: fine


# -- 12. store and restore -----------------------------------------------------------------------

async def configure(master: Master) -> None:
    await master.download(0x1802, 2, u8(1))  # TPDO3 on every SYNC ...
    await master.download(0x1A02, 1, u32(0x20000108))  # ... with SA byte 0
    await master.download(0x1A02, 0, u8(1))
    await master.download(0x1802, 1, u32(0x40000390))
    await master.download(0x1016, 1, u32(MASTER_ID << 16 | 700))
    await master.download(0x1005, 0, u32(0x81))


async def configured(master: Master) -> bool:
    return (await master.upload(0x1802, 1) == u32(0x40000390)
            and await master.upload(0x1A02, 0) == u8(1)
            and await master.upload(0x1016, 1) == u32(MASTER_ID << 16 | 700)
            and await master.upload(0x1005, 0) == u32(0x81))


async def test_store_survives_resets_and_restarts(gw: Gateway, master: Master,
                                                  ncgate_config: Config) -> None:
    node = gw.canopen_node
    assert node is not None
    path = node.store_path
    assert path.parent == ncgate_config.source.parent  # type: ignore[union-attr]
    assert await master.upload(0x1010, 1) == u32(1)  # saves on command
    await configure(master)
    assert await sdo_error(master.download(0x1010, 2, b"SAVE")) == 0x08000020
    assert not path.exists()
    await master.download(0x1010, 2, b"save")
    assert json.loads(path.read_text())["parameters"]["0x1A02"] == {"0": "01", "1": "08010020"}
    assert await master.upload(0x1010, 2) == u32(1)  # the signature is not kept
    master.nmt(0x82)  # reset communication: the stored values are the power-on ones
    await master.next(0x710)
    assert await configured(master)
    await master.download(0x1011, 1, b"load")  # defaults again ... after the next reset
    assert not path.exists() and await configured(master)
    master.nmt(0x81)
    await master.next(0x710)
    assert not await configured(master)
    assert await master.upload(0x1802, 1) == u32(0xC0000390)


async def test_stored_parameters_apply_at_start(master: Master, ncgate_config: Config) -> None:
    async with Gateway(ncgate_config):
        await configure(master)
        await master.download(0x1010, 1, b"save")
    async with Gateway(ncgate_config):
        assert await configured(master)
        master.listen(0x390)
        master.nmt(0x01)
        master.sync(cob=0x81)
        assert await master.next(0x390) == b"\x00"  # TPDO3 on the moved SYNC


async def test_a_store_file_that_does_not_fit_is_ignored(master: Master,
                                                         ncgate_config: Config) -> None:
    path = ncgate_config.canopen.store_file
    assert path is not None
    store.save(path, {0x1A07: {0: b"\x01"}})  # no such object here
    async with Gateway(ncgate_config):
        assert await master.upload(0x1802, 1) == u32(0xC0000390)
    store.save(path, {0x1A02: {0: b"\x01", 1: struct.pack("<L", 0x20FF0108)}})  # no such byte
    async with Gateway(ncgate_config):
        assert await master.upload(0x1A02, 0) == u8(0)
    path.write_text("{half a fi")
    async with Gateway(ncgate_config):
        assert await master.upload(0x1802, 1) == u32(0xC0000390)


def test_store_is_never_half_written_even_on_kill_9(tmp_path: Path) -> None:
    """A writer saving in a loop, killed at once with SIGKILL, again and again: the file
    is always the old one or a new one, whole."""
    path = tmp_path / "params.json"
    big = {0x1600 + i: {s: bytes(4) + bytes((i, s)) for s in range(9)} for i in range(64)}
    store.save(path, big)
    writer = (
        "import sys\n"
        "from pathlib import Path\n"
        "from ncgate.gateway.canopen import store\n"
        f"big = {big!r}\n"
        "print('ready', flush=True)\n"
        "i = 0\n"
        "while True:\n"
        "    i += 1\n"
        "    big[0x1600][0] = i.to_bytes(4, 'little')\n"
        f"    store.save(Path({str(path)!r}), big)\n"
    )
    for _ in range(5):
        proc = subprocess.Popen([sys.executable, "-c", writer], stdout=subprocess.PIPE,
                                text=True)
        assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
        before = path.stat().st_mtime_ns
        while path.stat().st_mtime_ns == before:  # until it has replaced the file once
            pass
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        loaded = store.load(path)
        assert loaded is not None and len(loaded) == 64
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "params.json"]
    assert all(name.startswith(".params.json.") for name in leftovers)  # temporary files only


# -- a DCF, applied the way a master tool does -------------------------------------------------

async def test_dcf_applied_by_a_master(tmp_path: Path, clocked: Gateway, master: Master,
                                       clock: ManualClock, ncgate_config: Config) -> None:
    eds = tmp_path / "ncgate.eds"
    write_eds(ncgate_config, str(eds))
    od = canopen.import_od(str(eds), ncgate_config.canopen.node_id)
    # the commissioning engineer's choices, as a configuration tool writes them to the DCF
    od[0x1802][1].value, od[0x1802][2].value = 0x40000390, 1  # TPDO3: every SYNC
    od[0x1A02][0].value, od[0x1A02][1].value = 2, 0x25000108  # P1 state
    od[0x1A02][2].value = 0x25010108  # P2 state
    od[0x1803][1].value, od[0x1803][2].value = 0x40000490, 254  # TPDO4: on change
    od[0x1803][5].value = 250  # and every 250 ms
    od[0x1A03][0].value, od[0x1A03][1].value = 1, 0x20000208  # SA byte 1
    od[0x1801][1].value = 0xC0000290  # TPDO2 off
    od[0x1016][1].value = MASTER_ID << 16 | 1000
    dcf = tmp_path / "ncgate.dcf"
    canopen.export_od(od, str(dcf), doc_type="dcf")
    tool = connect_master(ncgate_config)
    try:
        remote = canopen.RemoteNode(ncgate_config.canopen.node_id, str(dcf))
        tool.network.add_node(remote)
        await asyncio.to_thread(remote.load_configuration)
    finally:
        tool.network.disconnect()
    for cob in (0x390, 0x490):
        master.listen(cob)
    master.nmt(0x01)
    assert await master.next(0x490) == b"\x00"  # TPDO4 says where things stand
    await running_cell(clocked)
    await master.barrier()
    assert master.frames[0x390].empty()  # TPDO3 waits for the SYNC
    master.sync()
    assert await master.next(0x390) == bytes((3, 3))
    clocked.write("SA10", 1)  # TPDO4 on change
    assert await master.next(0x490) == b"\x04"
    clock.advance(0.25)  # and on its event timer
    assert await master.next(0x490) == b"\x04"
    clocked.send(4, 1)
    await master.barrier()
    assert master.frames[0x290].empty()  # TPDO2 is off
    assert await master.upload(0x1016, 1) == u32(MASTER_ID << 16 | 1000)


def test_store_path_follows_config(tmp_path: Path) -> None:
    cfg = tmp_path / "cell" / "ncgate.toml"
    cfg.parent.mkdir()
    cfg.write_text("[canopen]\nnode_id = 9\n")
    assert load_config(cfg).canopen.store_file is None
    assert store.default_path(state_folder(cfg), 9) == cfg.parent / "ncgate-canopen-node9.json"
    cfg.write_text('[canopen]\nstore_file = "state/co.json"\n')
    assert load_config(cfg).canopen.store_file == (cfg.parent / "state/co.json").resolve()
    # The test kit keeps it in the test's own folder, whatever the config says.
    assert ncgate_test_config(cfg).canopen.store_file == tmp_path / "ncgate-canopen-node16.json"
