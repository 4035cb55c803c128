"""[opcua]'s keys and refusals without a client: the one refusal table, a public bind without
security, security without a certificate, the regions and users it takes."""

from __future__ import annotations

import hashlib

import pytest

from ncgate.config import ConfigError, load_config
from ncgate.errors import Reason
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
