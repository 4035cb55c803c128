"""The console over HTTPS (issue 30, item 2: `[web.tls]`, with the loader of the Modbus TLS
port), with certificates made by openssl as a user makes them.

CI installs openssl (.ci/run); on a machine without it these tests are skipped with that
reason -- never in CI, where a missing openssl is a failure.
"""

from __future__ import annotations

import os
import shutil
import ssl
import subprocess
from pathlib import Path

import aiohttp
import pytest

from ncgate.config import ConfigError
from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

if shutil.which("openssl") is None:
    if os.environ.get("CI"):
        pytest.fail("openssl is not installed: .ci/run must install it", pytrace=False)
    pytestmark = pytest.mark.skip(reason="openssl not installed (apt-get install openssl); "
                                         "CI runs this")


def self_signed(folder: Path, name: str) -> tuple[Path, Path]:
    """A certificate for 127.0.0.1 and its key, as `openssl req -x509` makes them."""
    cert, key = folder / f"{name}.crt", folder / f"{name}.key"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt",
                    "ec_paramgen_curve:P-256", "-nodes", "-keyout", str(key), "-out", str(cert),
                    "-days", "2", "-subj", "/CN=127.0.0.1", "-addext",
                    "subjectAltName=IP:127.0.0.1"], check=True, capture_output=True)
    return cert, key


async def test_the_console_speaks_https_only_when_web_tls_is_set(tmp_path: Path) -> None:
    cert, key = self_signed(tmp_path, "console")
    config = ncgate_test_config(**{"web.port": 0, "web.tls.cert": str(cert),
                                   "web.tls.key": str(key)})
    async with Gateway(config, console=True) as gw:
        host, port = gw.web_address
        assert gw.web_console.url == f"https://{host}:{port}/"
        trusted = ssl.create_default_context(cafile=str(cert))
        base = f"https://{host}:{port}"
        async with aiohttp.ClientSession(base) as http:
            async with http.get("/api/status", ssl=trusted) as r:
                assert r.status == 200 and (await r.json())["session"] == gw.session
            # The page's own writes: its Origin is https://...
            async with http.post("/api/write", json={"var": "SYVAR5", "value": 9},
                                 headers={"Origin": base}, ssl=trusted) as r:
                assert r.status == 200
            assert gw.read("SYVAR5") == 9
            # A client that does not trust the certificate gets no answer.
            with pytest.raises(aiohttp.ClientConnectorCertificateError):
                await http.get("/api/status", ssl=ssl.create_default_context())
        async with aiohttp.ClientSession() as http:  # plain HTTP: not served
            with pytest.raises(aiohttp.ClientError):
                await http.get(f"http://{host}:{port}/api/status")


def test_web_tls_needs_a_certificate_and_its_key(tmp_path: Path) -> None:
    cert, key = self_signed(tmp_path, "a")
    _, other_key = self_signed(tmp_path, "b")
    cases = [
        ({"web.tls.cert": str(cert)}, "web.tls.key: missing"),
        ({"web.tls.key": str(key)}, "web.tls.cert: missing"),
        ({"web.tls.cert": str(tmp_path / "none.crt"), "web.tls.key": str(key)},
         "web.tls.cert: no such file"),
        ({"web.tls.cert": str(cert), "web.tls.key": str(other_key)},
         "web.tls.key: the certificate a.crt and key b.key do not load as a pair"),
    ]
    for overrides, message in cases:
        with pytest.raises(ConfigError) as caught:
            ncgate_test_config(**overrides)
        assert message in str(caught.value), (overrides, str(caught.value))
