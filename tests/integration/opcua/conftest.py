"""An independent OPC UA client for the tests: node-opcua (npm), driven through JSON lines
(``tests/integration/opcua_client/client.js``).

CI installs it (``.ci/run``: ``npm ci`` in that folder); on a developer machine without node or
its ``node_modules`` these tests are skipped with that reason -- never in CI (CI=1), where a
missing client is a failure."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import shutil
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest

CLIENT = Path(__file__).resolve().parents[1] / "opcua_client"
IMAGE = "urn:ncgate:image"
NCGATE = "urn:ncgate:ua"
MACHINE_TOOL = "http://opcfoundation.org/UA/MachineTool/"
MACHINERY = "http://opcfoundation.org/UA/Machinery/"
CNC = "http://opcfoundation.org/UA/CNC"
DI = "http://opcfoundation.org/UA/DI/"


def _missing() -> str | None:
    if shutil.which("node") is None:
        return "node is not installed (apt-get install nodejs npm)"
    if not (CLIENT / "node_modules" / "node-opcua-client").is_dir():
        return f"node-opcua is not installed (cd {CLIENT} && npm ci)"
    return None


class UaClient:
    """node-opcua in a child process: ``await call(op, ...)``; notifications by tag."""

    def __init__(self, process: asyncio.subprocess.Process) -> None:
        self.process = process
        self._ids = itertools.count(1)
        self._answers: dict[int, asyncio.Future[Any]] = {}
        self.notes: dict[str, list[Any]] = {}
        self._changed = asyncio.Event()
        self._reader = asyncio.get_running_loop().create_task(self._read())

    async def _read(self) -> None:
        assert self.process.stdout is not None
        async for raw in self.process.stdout:
            line = raw.decode().strip()
            if not line.startswith("{"):
                continue  # node-opcua's own warnings
            message = json.loads(line)
            if "tag" in message:
                self.notes.setdefault(message["tag"], []).append(message["value"])
                self._changed.set()
            elif message.get("id") in self._answers:
                future = self._answers.pop(message["id"])
                if "error" in message:
                    future.set_exception(AssertionError(f"node-opcua: {message['error']}"))
                else:
                    future.set_result(message["ok"])

    async def call(self, op: str, **args: Any) -> Any:
        number = next(self._ids)
        future: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._answers[number] = future
        assert self.process.stdin is not None
        self.process.stdin.write((json.dumps({"id": number, "op": op, **args}) + "\n").encode())
        await self.process.stdin.drain()
        async with asyncio.timeout(30):
            return await future

    async def until(self, tag: str, done: Callable[[list[Any]], bool],
                    timeout_s: float = 30.0) -> list[Any]:
        """The notifications of ``tag`` once ``done`` holds of them."""
        async with asyncio.timeout(timeout_s):
            while not done(self.notes.get(tag, [])):
                self._changed.clear()
                await self._changed.wait()
        return self.notes.get(tag, [])

    async def close(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.close()
        try:
            async with asyncio.timeout(10):
                await self.process.wait()
        except TimeoutError:
            self.process.kill()
            await self.process.wait()
        self._reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._reader


@pytest.fixture
async def ua_client() -> AsyncIterator[UaClient]:
    missing = _missing()
    if missing is not None:
        if os.environ.get("CI"):
            pytest.fail(f"{missing}: CI must install it (.ci/run)")
        pytest.skip(f"{missing}; CI runs these")
    process = await asyncio.create_subprocess_exec(
        "node", str(CLIENT / "client.js"), stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.DEVNULL, cwd=CLIENT)
    client = UaClient(process)
    try:
        yield client
    finally:
        await client.close()
