"""[opcua]'s keys and refusals without a client: the one refusal table, a public bind without
security, security without a certificate, the regions and users it takes, and `ncgate map`'s
list of the UA nodes."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from ncgate.config import ConfigError, load_config
from ncgate.errors import Reason
from ncgate.gateway.cli.main import main
from ncgate.gateway.opcua.codes import REFUSAL
from ncgate.gateway.opcua.space import password_matches


def test_every_reason_has_a_bad_status_code() -> None:
    assert set(REFUSAL) == set(Reason)
    assert all(code & 0x80000000 for code in REFUSAL.values())  # each one Bad_


def test_a_bind_beyond_loopback_without_security_is_refused_naming_the_key() -> None:
    with pytest.raises(ConfigError, match=r"opcua\.security: .*0\.0\.0\.0"):
        load_config(None, overrides={"opcua.host": "0.0.0.0"})
    assert load_config(None, overrides={"opcua.host": "127.0.0.2"}).opcua.host == "127.0.0.2"


def test_security_needs_a_certificate_and_a_key() -> None:
    with pytest.raises(ConfigError, match=r"opcua\.security: .*opcua\.certificate"):
        load_config(None, overrides={"opcua.security": "sign_encrypt"})


def test_writable_takes_only_image_regions() -> None:
    with pytest.raises(ConfigError, match=r"opcua\.writable"):
        load_config(None, overrides={"opcua.writable": ["command"]})
    config = load_config(None, overrides={"opcua.writable": ["sa_bits", "syvars"]})
    assert config.opcua.writable == {"sa_bits", "syvars"}


def test_a_user_is_a_pbkdf2_hash_that_the_server_checks() -> None:
    digest = hashlib.pbkdf2_hmac("sha256", b"s3cret", b"salt", 1000).hex()
    stored = f"pbkdf2_sha256$1000$salt${digest}"
    config = load_config(None, overrides={"opcua.users": {"alice": stored}})
    assert password_matches(config.opcua.users["alice"], "s3cret")
    assert not password_matches(config.opcua.users["alice"], "guess")
    with pytest.raises(ConfigError, match=r"opcua\.users\.bob"):
        load_config(None, overrides={"opcua.users": {"bob": "plain-text"}})


def test_map_lists_the_ua_nodes_beside_the_registers_when_opcua_is_on(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "press.toml"
    config.write_text('[opcua]\nenabled = true\nwritable = ["sa_bits"]\n[symbols]\n'
                      'door_closed = "SA10"\nspeed = "SYVAR3"\nstatus_byte = "SA1.BY"\n')
    assert main(["map", "--config", str(config), "--format", "md"]) == 0
    out = capsys.readouterr().out
    assert "# OPC UA nodes" in out
    assert ("| Objects/Machines/press/Monitoring/Process 1/ChannelState | "
            "ns=urn:ncgate:ua;s=P1/ChannelState | ChannelState (enumeration) | read | "
            "0 Active, 1 Interrupted, 2 Reset |") in out
    assert ("| Objects/CncInterface/CncChannelList/Process 1/ActProgramStatus | "
            "ns=urn:ncgate:ua;s=P1/ActProgramStatus | CncChannelProgramStatus (enumeration) "
            "| read | 0 Stopped, 1 Running, 2 Waiting, 3 Interrupted, 4 Canceled |") in out
    assert "| Int32 |" not in out  # the enumerations' variables are typed by them
    assert "| Objects/Server | ns=0;i=2253 | events | read |" in out  # alarm lists look there
    assert ("| Objects/Image/Symbols/door_closed | ns=urn:ncgate:image;s=door_closed | as SA10 "
            "| read/write |") in out
    assert "| Objects/Image/Symbols/speed | ns=urn:ncgate:image;s=speed | as SYVAR3 | read |" in out
    assert "Symbols/status_byte" not in out  # a byte of SA is no node of its own
    assert "| Objects/Image/SYVAR/SYVAR0 .. SYVAR255 |" in out
    config.write_text("")
    assert main(["map", "--config", str(config), "--format", "md"]) == 0
    assert "OPC UA" not in capsys.readouterr().out


async def test_a_port_in_use_stops_the_start_naming_the_key_without_a_traceback(
        capfd: pytest.CaptureFixture[str]) -> None:
    """As a taken Modbus port does: the key to change and the system's reason (a new user
    found two tracebacks, asyncua's and the server process's, and no key)."""
    from ncgate.gateway import Gateway
    from ncgate.gateway.errors import ListenError
    from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

    async with Gateway(ncgate_test_config(**{"opcua.enabled": True,
                                             "canopen.enabled": False})) as first:
        port = int(first.opcua_endpoint.rsplit(":", 1)[1].strip("/"))
        second = Gateway(ncgate_test_config(**{"opcua.enabled": True, "opcua.port": port,
                                               "canopen.enabled": False}))
        capfd.readouterr()
        with pytest.raises(ListenError, match=rf"opcua.port: cannot listen on 127.0.0.1:{port}:"
                                              " Address already in use"):
            async with second:
                pass
        assert "Traceback" not in capfd.readouterr().err


def test_a_certificate_user_is_a_path_beside_the_config_and_other_tables_are_refused(
        tmp_path: Path) -> None:
    config = tmp_path / "cell.toml"
    config.write_text('[opcua.users]\nbob = { certificate = "pki/bob.crt" }\n')
    assert load_config(config).opcua.users == {"bob": tmp_path / "pki" / "bob.crt"}
    config.write_text('[opcua.users]\nbob = { cert = "bob.crt" }\n')
    with pytest.raises(ConfigError, match=r"opcua\.users\.bob"):
        load_config(config)


def test_trusted_takes_files_and_folders_beside_the_config_and_is_needed_beyond_loopback(
        tmp_path: Path) -> None:
    (tmp_path / "pki").mkdir()
    _pair(tmp_path, "ua", None)
    config = tmp_path / "cell.toml"
    secure = ('[opcua]\nsecurity = "sign"\ncertificate = "ua.crt"\nprivate_key = "ua.key"\n')
    # A folder with no certificate: asyncua's "can't create an empty store" at start.
    config.write_text(secure + 'trusted = ["pki", "ua.crt"]\n')
    with pytest.raises(ConfigError, match=r"opcua\.trusted\[0\]: the folder .*pki holds no "
                                          r"certificate \(\*\.pem"):
        load_config(config)
    _pair(tmp_path / "pki", "client", "urn:client")
    assert load_config(config).opcua.trusted == (tmp_path / "pki", tmp_path / "ua.crt")
    (tmp_path / "pki" / "notes.pem").write_text("not a certificate")
    with pytest.raises(ConfigError, match=r"opcua\.trusted\[0\]: .*notes.pem is not a "
                                          r"certificate"):
        load_config(config)
    (tmp_path / "pki" / "notes.pem").unlink()
    config.write_text(secure + 'trusted = ["pki", "gone.pem"]\n')
    with pytest.raises(ConfigError, match=r"opcua\.trusted\[1\]: no such file"):
        load_config(config)
    # Beyond loopback, an empty list would let in any client that makes a certificate.
    config.write_text(secure + 'host = "0.0.0.0"\n')
    with pytest.raises(ConfigError, match=r"opcua\.trusted: .*0\.0\.0\.0"):
        load_config(config)
    config.write_text(secure + 'host = "0.0.0.0"\ntrusted = "pki"\n')
    assert load_config(config).opcua.trusted == (tmp_path / "pki",)
    # Without security no client certificate is exchanged: a list would be a false comfort.
    config.write_text('[opcua]\ntrusted = ["pki"]\n')
    with pytest.raises(ConfigError, match=r"opcua\.trusted: .*sign"):
        load_config(config)


def _pair(folder: Path, name: str, uri: str | None) -> tuple[Path, Path]:
    """A self-signed RSA certificate (its subjectAltName: ``uri``, if any) and its key."""
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = datetime.datetime.now(datetime.UTC)
    builder = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now).not_valid_after(now + datetime.timedelta(days=30)))
    if uri is not None:
        builder = builder.add_extension(x509.SubjectAlternativeName(
            [x509.UniformResourceIdentifier(uri)]), critical=False)
    cert = folder / f"{name}.crt"
    cert.write_bytes(builder.sign(key, hashes.SHA256()).public_bytes(
        serialization.Encoding.PEM))
    private = folder / f"{name}.key"
    private.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                          serialization.PrivateFormat.PKCS8,
                                          serialization.NoEncryption()))
    return cert, private


def test_the_servers_certificate_and_key_are_checked_at_start(tmp_path: Path) -> None:
    """asyncua took a key of another certificate (every secure client then timed out, the
    server failing to decrypt) and a certificate of another application URI (a strict
    client refuses it) without a word (a dashboard builder's try)."""
    good, good_key = _pair(tmp_path, "press", "urn:ncgate:press")
    other, other_key = _pair(tmp_path, "other", "urn:ncgate:other")
    bare, bare_key = _pair(tmp_path, "bare", None)
    config = tmp_path / "press.toml"
    config.write_text('[opcua]\nenabled = true\nsecurity = "sign_encrypt"\n')

    def load(cert: Path, key: Path) -> None:
        load_config(config, overrides={"opcua.certificate": str(cert),
                                       "opcua.private_key": str(key)})

    load(good, good_key)
    with pytest.raises(ConfigError, match=r"press.toml: opcua.private_key: other.key is not "
                                          r"the key of the certificate press.crt"):
        load(good, other_key)
    with pytest.raises(ConfigError, match=r"opcua.certificate: other.crt's subjectAltName "
                                          r"holds urn:ncgate:other, not the server's "
                                          r"application URI urn:ncgate:press"):
        load(other, other_key)
    with pytest.raises(ConfigError, match=r"bare.crt's subjectAltName holds no URI"):
        load(bare, bare_key)
    with pytest.raises(ConfigError, match=r"opcua.certificate: press.key is not a "
                                          r"certificate"):
        load(good_key, good_key)
    with pytest.raises(ConfigError, match=r"opcua.private_key: press.crt is not a private"):
        load(good, good)
    # The server off: nothing is loaded (a certificate kept for later is no error).
    load_config(config, overrides={"opcua.enabled": False, "opcua.certificate": str(other),
                                   "opcua.private_key": str(good_key)})
