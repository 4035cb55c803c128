"""OPC UA security seen by node-opcua (docs/opcua.md): Basic256Sha256 SignAndEncrypt with the
server's PEM certificate, and user/password users of [opcua.users] who alone may write."""

from __future__ import annotations

import datetime
import hashlib
import ipaddress
from pathlib import Path
from typing import Any

import pytest

from ncgate.gateway import Gateway
from ncgate.gateway.testing.pytest_plugin import ncgate_test_config

from .conftest import IMAGE, UaClient

x509 = pytest.importorskip("cryptography.x509")


def server_certificate(folder: Path, uri: str, name: str = "server") -> tuple[Path, Path]:
    """A self-signed RSA 2048 certificate as OPC 10000-6 6.2.2 wants it for Basic256Sha256:
    the application URI in the subject alternative name, the key usages it lists."""
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"ncgate test {name}")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(days=1))
            .not_valid_after(now + datetime.timedelta(days=30))
            .add_extension(x509.SubjectAlternativeName([
                x509.UniformResourceIdentifier(uri), x509.DNSName("localhost"),
                x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
            .add_extension(x509.KeyUsage(
                digital_signature=True, content_commitment=True, key_encipherment=True,
                data_encipherment=True, key_agreement=False, key_cert_sign=True,
                crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .sign(key, hashes.SHA256()))
    cert_path, key_path = folder / f"{name}.crt", folder / f"{name}.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    return cert_path, key_path


async def test_sign_and_encrypt_offers_only_basic256sha256_and_a_client_reads_through_it(
        tmp_path: Path, ua_client: UaClient) -> None:
    cert, key = server_certificate(tmp_path, "urn:ncgate:ncgate")
    config = ncgate_test_config(**{"opcua.enabled": True, "opcua.security": "sign_encrypt",
                                   "opcua.certificate": str(cert), "opcua.private_key": str(key),
                                   "canopen.enabled": False})
    async with Gateway(config) as gw:
        endpoints = await ua_client.call("endpoints", url=gw.opcua_endpoint)
        assert {(e["mode"], e["policy"].rsplit("#", 1)[1]) for e in endpoints} == {
            ("SignAndEncrypt", "Basic256Sha256")}
        with pytest.raises(AssertionError, match="node-opcua"):
            await ua_client.call("connect", url=gw.opcua_endpoint)  # None: not offered
        await ua_client.call("connect", url=gw.opcua_endpoint, mode="SignAndEncrypt",
                             policy="Basic256Sha256")
        await ua_client.call("subscribe", interval=20)
        await ua_client.call("monitor", tag="syvar", node={"ns": IMAGE, "id": "SYVAR7"})
        gw.write("SYVAR7", -12)
        assert await ua_client.until("syvar", lambda seen: seen[-1:] == [-12]) == [0, -12]


async def test_with_users_set_an_anonymous_session_reads_and_only_a_user_writes(
        tmp_path: Path, ua_client: UaClient) -> None:
    digest = hashlib.pbkdf2_hmac("sha256", b"s3cret", b"pepper", 1000).hex()
    config = ncgate_test_config(**{"opcua.enabled": True, "opcua.writable": ["syvars"],
                                   "opcua.users": {"alice": f"pbkdf2_sha256$1000$pepper${digest}"},
                                   "canopen.enabled": False})
    async with Gateway(config) as gw:
        node = {"ns": IMAGE, "id": "SYVAR7"}
        await ua_client.call("connect", url=gw.opcua_endpoint)
        assert await ua_client.call("write", node=node, type="Int16",
                                    value=5) == "BadUserAccessDenied"
        assert gw.read("SYVAR7") == 0
        await ua_client.call("close")
        with pytest.raises(AssertionError, match="node-opcua"):
            await ua_client.call("connect", url=gw.opcua_endpoint, user="alice",
                                 password="guess")
        await ua_client.call("connect", url=gw.opcua_endpoint, user="alice",
                             password="s3cret")
        assert await ua_client.call("write", node=node, type="Int16", value=5) == "Good"
        assert gw.read("SYVAR7") == 5
        writes = [e for e in gw.trace if e["event"] == "write"]
        assert [(w["var"], w["value"], w["who"]) for w in writes] == [
            ("SYVAR7", 5, "opcua alice")]


async def test_a_certificate_user_writes_and_a_stranger_s_certificate_is_refused(
        tmp_path: Path, ua_client: UaClient) -> None:
    cert, key = server_certificate(tmp_path, "urn:ncgate:ncgate")
    bob, bob_key = server_certificate(tmp_path, "urn:bob", "bob")
    eve, eve_key = server_certificate(tmp_path, "urn:eve", "eve")
    config = ncgate_test_config(**{
        "opcua.enabled": True, "opcua.security": "sign_encrypt", "opcua.certificate": str(cert),
        "opcua.private_key": str(key), "opcua.writable": ["syvars"],
        "opcua.users": {"bob": {"certificate": str(bob)}}, "canopen.enabled": False})
    secure = {"mode": "SignAndEncrypt", "policy": "Basic256Sha256"}
    async with Gateway(config) as gw:
        with pytest.raises(AssertionError, match="node-opcua"):
            await ua_client.call("connect", url=gw.opcua_endpoint, certificate=str(eve),
                                 key=str(eve_key), **secure)
        await ua_client.call("connect", url=gw.opcua_endpoint, certificate=str(bob),
                             key=str(bob_key), **secure)
        assert await ua_client.call("write", node={"ns": IMAGE, "id": "SYVAR7"}, type="Int16",
                                    value=9) == "Good"
        assert gw.read("SYVAR7") == 9
        assert [e["who"] for e in gw.trace if e["event"] == "write"] == ["opcua bob"]


def client_certificate(folder: Path, name: str, issuer: tuple[Any, Any] | None = None,
                       ) -> tuple[Path, Path]:
    """A client's application certificate (OPC 10000-6 6.2.2: its application URI
    ``urn:<name>`` in the subject alternative name), self-signed or signed by ``issuer``
    (a CA's certificate and key)."""
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"ncgate test {name}")])
    ca_cert, ca_key = issuer if issuer is not None else (None, key)
    now = datetime.datetime.now(datetime.UTC)
    builder = (x509.CertificateBuilder().subject_name(subject)
               .issuer_name(ca_cert.subject if ca_cert is not None else subject)
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now - datetime.timedelta(days=1))
               .not_valid_after(now + datetime.timedelta(days=30))
               .add_extension(x509.SubjectAlternativeName([
                   x509.UniformResourceIdentifier(f"urn:{name}"),
                   x509.DNSName("localhost")]), critical=False)
               .add_extension(x509.KeyUsage(
                   digital_signature=True, content_commitment=True, key_encipherment=True,
                   data_encipherment=True, key_agreement=False,
                   key_cert_sign=ca_cert is None, crl_sign=False, encipher_only=False,
                   decipher_only=False), critical=True)
               .add_extension(x509.BasicConstraints(ca=False, path_length=None),
                              critical=True))
    if ca_cert is not None:
        builder = builder.add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(
            ca_key.public_key()), critical=False)
    cert = builder.sign(ca_key, hashes.SHA256())
    cert_path, key_path = folder / f"{name}.pem", folder / f"{name}.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.TraditionalOpenSSL,
                                           serialization.NoEncryption()))
    return cert_path, key_path


def certificate_authority(folder: Path) -> tuple[Any, Any, Path]:
    """A CA (basicConstraints CA, keyCertSign): its certificate, key, and its file as DER."""
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "ncgate test CA")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(days=1))
            .not_valid_after(now + datetime.timedelta(days=30))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(
                digital_signature=True, content_commitment=False, key_encipherment=False,
                data_encipherment=False, key_agreement=False, key_cert_sign=True,
                crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()),
                           critical=False)
            .sign(key, hashes.SHA256()))
    path = folder / "ca.der"
    path.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    return cert, key, path


async def test_a_trusted_client_certificate_connects_and_an_untrusted_one_is_refused(
        tmp_path: Path, ua_client: UaClient) -> None:
    cert, key = server_certificate(tmp_path, "urn:ncgate:ncgate")
    trusted_dir, other = tmp_path / "trusted", tmp_path / "other"
    trusted_dir.mkdir()
    other.mkdir()
    alice_pem, alice_key = client_certificate(trusted_dir, "alice")  # listed by its folder,
    alice = (alice_pem.rename(alice_pem.with_suffix(".crt")), alice_key)  # as *.crt
    ca_cert, ca_key, ca_file = certificate_authority(other)
    carol = client_certificate(other, "carol", issuer=(ca_cert, ca_key))  # by its CA's file
    mallory = client_certificate(other, "mallory")  # listed nowhere
    config = ncgate_test_config(**{
        "opcua.enabled": True, "opcua.security": "sign_encrypt", "opcua.certificate": str(cert),
        "opcua.private_key": str(key), "opcua.trusted": [str(trusted_dir), str(ca_file)],
        "canopen.enabled": False})
    secure = {"mode": "SignAndEncrypt", "policy": "Basic256Sha256"}

    def app(name: str, pair: tuple[Path, Path]) -> dict[str, str]:
        return {"certificate": str(pair[0]), "key": str(pair[1]), "uri": f"urn:{name}"}

    async with Gateway(config) as gw:
        with pytest.raises(AssertionError, match="BadCertificateUntrusted"):
            await ua_client.call("connect", url=gw.opcua_endpoint,
                                 application=app("mallory", mallory), **secure)
        await ua_client.call("close")
        for name, pair in (("alice", alice), ("carol", carol)):
            await ua_client.call("connect", url=gw.opcua_endpoint,
                                 application=app(name, pair), **secure)
            assert await ua_client.call("read", node={"ns": IMAGE, "id": "SYVAR7"}) == 0
            await ua_client.call("close")
