"""Where a run keeps its state when the config does not say (issue 25, item 16): beside the
user's config, but for the built-in config and one shipped inside the package, in the user's
state folder (docs/decisions.md) -- ``ncgate run --config <site-packages>/.../examples/...``
never writes into the package."""

from __future__ import annotations

import asyncio
import os
import signal
import sys
from pathlib import Path

from ncgate.config.state import state_folder, user_state_dir

from ..conftest import EXAMPLES


def test_state_of_a_packaged_config_goes_to_the_user_state_folder(tmp_path: Path) -> None:
    assert state_folder(None) == user_state_dir() / "built-in"
    assert state_folder(EXAMPLES / "plclogic" / "ncgate.toml") == \
        user_state_dir() / "examples" / "plclogic"
    assert state_folder(tmp_path / "ncgate.toml") == tmp_path


async def test_run_of_an_installed_example_never_writes_into_the_package(
        tmp_path: Path) -> None:
    example = EXAMPLES / "plclogic"
    leaked = example / "ncgate-plc-retain.sqlite"
    assert not leaked.exists()
    state = tmp_path / "state"
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ncgate", "run", "--config", str(example / "ncgate.toml"),
        "--no-web", "--set", "modbus.port=0", "--set", "canopen.channel=kit-isolation",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
        env={**os.environ, "XDG_STATE_HOME": str(state)})
    assert proc.stdout is not None
    lines: list[str] = []
    try:
        async with asyncio.timeout(20):
            while "PLC logic:" not in (lines or [""])[-1]:  # the RETAIN store is open by then
                line = (await proc.stdout.readline()).decode()
                assert line, "ncgate run ended early:\n" + "".join(lines)
                lines.append(line)
        proc.send_signal(signal.SIGTERM)
        async with asyncio.timeout(20):
            await proc.stdout.read()
            assert await proc.wait() == 0
        assert (state / "ncgate" / "examples" / "plclogic" / "ncgate-plc-retain.sqlite").exists()
        assert not leaked.exists()
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        remove_sqlite(leaked)  # what the old code left in the repository


def remove_sqlite(path: Path) -> None:
    for suffix in ("", "-wal", "-shm"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)
