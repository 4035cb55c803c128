"""docs/security.md as a user follows it: its openssl recipe makes the CA and certificates, its
TOML turns TLS on, and a pymodbus TLS client with the Operator certificate writes.

CI installs openssl (.ci/run); on a machine without it this test is skipped with that reason --
never in CI, where a missing openssl is a failure.
"""

from __future__ import annotations

import os
import re
import shutil
import ssl
import subprocess
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTlsClient

from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from ...helpers import write_cell

if shutil.which("openssl") is None:
    if os.environ.get("CI"):
        pytest.fail("openssl is not installed: .ci/run must install it", pytrace=False)
    pytestmark = pytest.mark.skip(reason="openssl not installed (apt-get install openssl); "
                                         "CI runs this")

DOC = Path(__file__).resolve().parents[3] / "docs" / "security.md"


def block(language: str) -> str:
    (text,) = re.findall(rf"```{language}\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    return text


@pytest.fixture
def cell(tmp_path: Path) -> Path:
    """The docs' config in a folder where the docs' recipe has run."""
    cell = write_cell(tmp_path, "[nc]\nprocesses = 2\n" + block("toml"), {})
    subprocess.run(["bash", "-euo", "pipefail", "-c", block("sh")], cwd=cell, check=True,
                   capture_output=True)
    return cell


async def test_the_documented_recipe_gives_a_working_operator(cell: Path) -> None:
    config = ncgate_test_config(cell / "ncgate.toml", **{"canopen.enabled": False})
    assert config.modbus.tls.cert == (cell / "server.crt").resolve()  # relative to the file
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.load_verify_locations(cell / "clients-ca.crt")
    context.load_cert_chain(cell / "operator.crt", cell / "operator.key")
    async with Gateway(config) as gw:
        _, port = gw.modbus_tls_address
        client = AsyncModbusTlsClient("localhost", port=port, sslctx=context, retries=0)
        assert await client.connect()
        try:
            r = await client.write_register(1000, 42, device_id=1)  # SYVAR0
            assert not r.isError(), r
        finally:
            client.close()
        assert gw.read("SYVAR0") == 42
        assert any(e["who"] == "modbus-tls Operator" for e in gw.trace if e["event"] == "write")
