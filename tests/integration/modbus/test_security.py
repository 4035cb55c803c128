"""Modbus/TCP Security (issue 10, finding 8): TLS with mutual authentication on its own port,
the client's role from its certificate, `[modbus.roles]` deciding what it may write.

Real TLS on loopback: a CA of the tests' own (pki.py), pymodbus's TLS client and raw frames
over Python's ssl.  What MB-TCP-Security asks: TLS 1.2 or later, the client authenticated by a
certificate the configured CA signed, its role in the extension 1.3.6.1.4.1.50316.802.1 (a
UTF8String); an unauthorised request is exception 01 and stores nothing; a client without a
valid certificate never gets a Modbus answer.
"""

from __future__ import annotations

import asyncio
import re
import ssl
import struct
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTlsClient

from ncgate.config import Config, ConfigError, load_config
from ncgate.gateway import Gateway
from ncgate.gateway.errors import GatewayError
from ncgate.gateway.modbus import security
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from .pki import Authority, Issued, utf8string
from .rawclient import Raw, pdu

ROLES = {"Operator": ["sa_bits", "k_bytes", "syvars", "sa_bytes", "command", "mailbox"],
         "Viewer": [], "Setter": ["syvars"]}


class Pki:
    def __init__(self, folder: Path) -> None:
        self.ca = Authority(folder, "clients-ca")
        self.server = self.ca.issue("server", server=True)
        self.operator = self.ca.issue("operator", role=utf8string("Operator"))
        self.viewer = self.ca.issue("viewer", role=utf8string("Viewer"))
        self.setter = self.ca.issue("setter", role=utf8string("Setter"))
        self.unlisted = self.ca.issue("maintenance", role=utf8string("Maintenance"))
        self.no_role = self.ca.issue("anonymous")
        self.expired = self.ca.issue("expired", role=utf8string("Operator"), expired=True)
        self.foreign_ca = Authority(folder, "foreign-ca")
        self.foreign = self.foreign_ca.issue("foreign", role=utf8string("Operator"))

    def client(self, issued: Issued | None, **kw: object) -> ssl.SSLContext:
        return self.ca.client_context(issued, **kw)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return Pki(tmp_path_factory.mktemp("pki"))


def tls_overrides(pki: Pki, **more: object) -> dict[str, object]:
    return {"modbus.tls.cert": str(pki.server.cert), "modbus.tls.key": str(pki.server.key),
            "modbus.tls.ca": str(pki.ca.path), "modbus.roles": ROLES, **more}


@pytest.fixture
def ncgate_config(cell: Path, pki: Pki, request: pytest.FixtureRequest) -> Config:
    return ncgate_test_config(cell / "ncgate.toml",
                              **tls_overrides(pki, **getattr(request, "param", {})))


async def tls_raw(gw: Gateway, context: ssl.SSLContext) -> Raw:
    host, port = gw.modbus_tls_address
    return await Raw.open(host, port, tls=context)


# -- roles ------------------------------------------------------------------------------------


async def test_operator_writes_through_pymodbus_tls_client(ncgate_gateway: Gateway,
                                                           pki: Pki) -> None:
    gw = ncgate_gateway
    host, port = gw.modbus_tls_address
    client = AsyncModbusTlsClient(host, port=port, sslctx=pki.client(pki.operator), retries=0)
    assert await client.connect()
    try:
        r = await client.write_coil(10, True, device_id=1)
        assert not r.isError(), r
        r = await client.write_registers(5, [200], device_id=1)  # K byte 5
        assert not r.isError(), r
        r = await client.read_holding_registers(5, count=1, device_id=1)
        assert r.registers == [200]
    finally:
        client.close()
    assert (gw.read("SA10"), gw.read("SK5")) == (1, 200)
    writers = {e["who"] for e in gw.trace if e["event"] == "write"}
    assert writers == {"modbus-tls Operator"}, writers


WRITES = [  # every write function code, each aimed at a mapped, writable address
    pdu(5, "HH", 10, 0xFF00),  # SA10
    pdu(6, "HH", 5, 200),  # K byte 5
    pdu(15, "HHBB", 8, 4, 1, 0x0F),  # SA8..11
    pdu(16, "HHBH", 1000, 1, 2, 7),  # SYVAR0
    pdu(22, "HHH", 5, 0, 200),  # mask write K byte 5
    pdu(23, "HHHHBH", 5, 1, 5, 1, 2, 200),  # read/write K byte 5
]


@pytest.mark.parametrize("who", ["viewer", "unlisted", "no_role"])
async def test_a_role_without_rights_reads_and_every_write_is_01(
        ncgate_gateway: Gateway, pki: Pki, who: str) -> None:
    gw = ncgate_gateway
    raw = await tls_raw(gw, pki.client(getattr(pki, who)))
    try:
        assert await raw.ask(pdu(3, "HH", 5, 1)) == bytes((3, 2, 0, 0))  # reads: yes
        assert (await raw.ask(pdu(4, "HH", 1, 1)))[:2] == bytes((4, 2))
        for request in WRITES:
            assert await raw.ask(request) == bytes((request[0] | 0x80, 0x01)), request.hex()
    finally:
        raw.close()
    assert (gw.read("SA10"), gw.read("SK5"), gw.read("SYVAR0")) == (0, 0, 0)  # nothing stored
    assert not any(e["event"] == "write" for e in gw.trace)


async def test_a_role_writes_only_its_regions(ncgate_gateway: Gateway, pki: Pki) -> None:
    gw = ncgate_gateway
    raw = await tls_raw(gw, pki.client(pki.setter))  # Setter = ["syvars"]
    try:
        assert await raw.ask(pdu(6, "HH", 1001, 9)) == pdu(6, "HH", 1001, 9)  # SYVAR1
        assert await raw.ask(pdu(6, "HH", 5, 200)) == bytes((0x86, 0x01))  # a K byte: 01
        # FC23 writing a K byte while reading SYVARs: 01, and nothing written
        assert await raw.ask(pdu(23, "HHHHBH", 1000, 2, 5, 1, 2, 200)) == bytes((0x97, 0x01))
        # an unmapped address is still 02 (the address is checked first)
        assert await raw.ask(pdu(6, "HH", 999, 1)) == bytes((0x86, 0x02))
    finally:
        raw.close()
    assert (gw.read("SYVAR1"), gw.read("SK5")) == (9, 0)


# -- who gets no answer -----------------------------------------------------------------------


@pytest.mark.parametrize("who", ["none", "expired", "foreign"])
async def test_no_valid_certificate_no_modbus_answer(ncgate_gateway: Gateway, pki: Pki,
                                                     who: str) -> None:
    gw = ncgate_gateway
    host, port = gw.modbus_tls_address
    issued = {"none": None, "expired": pki.expired, "foreign": pki.foreign}[who]
    context = pki.client(issued)
    operator = await tls_raw(gw, pki.client(pki.operator))  # a good client, connected first
    try:
        # TLS 1.3: the client finishes its side before the server's verdict arrives, so the
        # refusal shows on the first read; TLS 1.2 fails in the handshake itself.
        try:
            raw = await Raw.open(host, port, tls=context)
        except (ssl.SSLError, ConnectionError):
            pass
        else:
            await raw.send(struct.pack(">HHHB", 1, 0, 6, 1) + pdu(3, "HH", 0, 1))
            with pytest.raises((ssl.SSLError, ConnectionError, asyncio.IncompleteReadError)):
                await raw.recv()
            raw.close()
        # the others are served all the while
        assert await operator.ask(pdu(3, "HH", 5, 1)) == bytes((3, 2, 0, 0))
    finally:
        operator.close()
    assert gw.modbus_server is not None
    assert gw.modbus_server.handler.served == 1  # only the good client's request


async def test_plain_modbus_on_the_tls_port_gets_no_answer(ncgate_gateway: Gateway,
                                                             caplog: pytest.LogCaptureFixture
                                                             ) -> None:
    raw = await Raw.open(*ncgate_gateway.modbus_tls_address)  # no TLS at all
    try:
        await raw.send(struct.pack(">HHHB", 1, 0, 6, 1) + pdu(3, "HH", 0, 1))
        data = await raw.reader.read(1024)  # a TLS alert at most, then the end
        assert data == b"" or data[0] == 0x15  # 0x15: a TLS alert record, not Modbus
        assert await raw.closed_by_peer()
    finally:
        raw.close()
    assert "TLS handshake failed" in caplog.text


async def test_a_handshake_has_the_partial_frame_clock(ncgate_gateway: Gateway,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    from ncgate.gateway.modbus import server as modbus_server

    monkeypatch.setattr(modbus_server, "PARTIAL_FRAME_TIMEOUT_S", 0.3)
    raw = await Raw.open(*ncgate_gateway.modbus_tls_address)
    try:
        await raw.send(b"\x16\x03\x01")  # the first bytes of a ClientHello, and no more
        assert await raw.closed_by_peer(timeout_s=5.0)
    finally:
        raw.close()


async def test_tls_1_2_is_enough_and_older_is_refused(ncgate_gateway: Gateway,
                                                      pki: Pki) -> None:
    raw = await tls_raw(ncgate_gateway, pki.client(pki.operator, maximum=ssl.TLSVersion.TLSv1_2))
    try:
        assert raw.writer.get_extra_info("ssl_object").version() == "TLSv1.2"
        assert await raw.ask(pdu(3, "HH", 5, 1)) == bytes((3, 2, 0, 0))
    finally:
        raw.close()
    config = ncgate_gateway.config.modbus.tls
    assert security.server_context(config).minimum_version is ssl.TLSVersion.TLSv1_2


async def test_several_frames_in_one_tls_record_are_all_answered(
        ncgate_gateway: Gateway, pki: Pki) -> None:
    raw = await tls_raw(ncgate_gateway, pki.client(pki.viewer))
    try:
        frames = b"".join(struct.pack(">HHHB", tid, 0, 6, 1) + pdu(4, "HH", 0, 1)
                          for tid in (1, 2, 3))
        await raw.send(frames)
        assert [(await raw.recv())[0] for _ in range(3)] == [1, 2, 3]
    finally:
        raw.close()


# -- plain Modbus/TCP beside it ---------------------------------------------------------------


async def test_plain_tcp_stays_as_it_was(ncgate_gateway: Gateway) -> None:
    gw = ncgate_gateway
    raw = await Raw.open(*gw.modbus_address)  # no certificate, no role: writes as before
    try:
        assert await raw.ask(pdu(6, "HH", 5, 200)) == pdu(6, "HH", 5, 200)
    finally:
        raw.close()
    assert gw.read("SK5") == 200


@pytest.mark.parametrize("ncgate_config", [{"modbus.tls.plain": False}], indirect=True)
async def test_plain_off_leaves_only_tls(ncgate_gateway: Gateway, pki: Pki) -> None:
    with pytest.raises(GatewayError, match="plain = false"):
        _ = ncgate_gateway.modbus_address
    assert ncgate_gateway.modbus_server is not None
    assert ncgate_gateway.modbus_server.address is None
    raw = await tls_raw(ncgate_gateway, pki.client(pki.operator))
    raw.close()


# -- the role extension and the config --------------------------------------------------------


def test_role_is_read_from_the_der_utf8string(pki: Pki) -> None:
    from cryptography import x509

    def role(issued: Issued) -> str | None:
        cert = x509.load_pem_x509_certificate(issued.cert.read_bytes())
        return security.role_of(cert.public_bytes(serialization_der()))

    assert role(pki.operator) == "Operator"
    assert role(pki.no_role) is None
    assert security._utf8string(bytes((0x0C, 0x81, 3)) + b"abc") == "abc"  # long form
    assert security._utf8string(bytes((0x13, 3)) + b"abc") is None  # PrintableString
    assert security._utf8string(bytes((0x0C, 4)) + b"abc") is None  # short


def serialization_der():  # type: ignore[no-untyped-def]
    from cryptography.hazmat.primitives import serialization
    return serialization.Encoding.DER


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"modbus.tls.key": None}, "modbus.tls.key: missing"),
        ({"modbus.tls.cert": None}, "modbus.tls.cert: missing"),
        ({"modbus.tls.ca": "nowhere.crt"}, "modbus.tls.ca: no such file"),
        ({"modbus.tls.key": "operator.key"}, "modbus.tls.key: the certificate server.crt and "
         "key operator.key do not load as a pair"),
        ({"modbus.tls.ca": "server.key"}, "modbus.tls.ca: not a PEM CA certificate"),
        ({"modbus.roles": {"Operator": ["sa_bits", "coils"]}},
         "modbus.roles.Operator[1]: expected one of sa_bits"),
        ({"modbus.roles": {"Operator": "all"}}, "modbus.roles.Operator: expected a list"),
    ],
)
def test_bad_tls_config_names_the_key(pki: Pki, overrides: dict[str, object],
                                      message: str) -> None:
    folder = pki.server.cert.parent
    given = tls_overrides(pki)
    for key, value in overrides.items():
        if value is None:
            del given[key]
        else:
            given[key] = str(folder / value) if isinstance(value, str) else value
    with pytest.raises(ConfigError, match="^<built-in default>: " + re.escape(message)):
        load_config(None, given)


def test_plain_off_without_tls_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"modbus\.tls\.plain: false needs TLS on"):
        load_config(None, {"modbus.tls.plain": False})


async def test_a_busy_tls_port_names_the_key(cell: Path, pki: Pki) -> None:
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        config = ncgate_test_config(cell / "ncgate.toml",
                                    **tls_overrides(pki, **{"modbus.tls.port": port}))
        with pytest.raises(OSError, match=rf"modbus\.tls\.port: cannot listen on 127\.0\.0\.1:"
                                          rf"{port}"):
            async with Gateway(config):
                pass


@pytest.mark.parametrize(("expired", "said"), [(True, "expired on"), (False, None)])
def test_an_expired_certificate_is_warned_about_at_start(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, expired: bool, said: str | None
) -> None:
    """[web.tls] and [modbus.tls] load through one loader: a certificate past its date is a
    warning at start, naming the file (a client would refuse it with no word on our side)."""
    import logging

    from ncgate.gateway.tls import server_context

    from .pki import Authority

    issued = Authority(tmp_path, "ca").issue("server", server=True, expired=expired)
    with caplog.at_level(logging.WARNING, logger="ncgate"):
        server_context(issued.cert, issued.key)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    if said is None:
        assert warnings == []
    else:
        assert len(warnings) == 1 and said in warnings[0] and str(issued.cert) in warnings[0]
