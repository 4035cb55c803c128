"""Modbus/TCP Security (the Modbus Organization's MB-TCP-Security): TLS and roles.

- TLS 1.2 or later with mutual authentication: the client must present a certificate that the
  configured CA signed (and that is valid now); a client that does not gets no Modbus answer.
- The client's role is the X.509v3 extension ``1.3.6.1.4.1.50316.802.1`` (ModbusRole), a
  UTF8String, of its certificate.  ``[modbus.roles]`` says which map regions each role may
  write; any authenticated client may read.  An unauthorised request is exception 01.

TLS runs over our own transport through ``ssl.MemoryBIO`` (as asyncio's own TLS layer does)
rather than asyncio's ``ssl=``: the server then sees why a handshake failed, and times the
handshake with the same clock as a partial frame.  The certificate's extension is read with
the ``cryptography`` package (``pip install 'ncgate[tls]'``).
"""

from __future__ import annotations

import ssl
from typing import Final

from ncgate.config import ModbusTlsConfig
from ncgate.gateway.tls import server_context as tls_context

ROLE_OID: Final = "1.3.6.1.4.1.50316.802.1"
_UTF8STRING: Final = 0x0C


def server_context(tls: ModbusTlsConfig) -> ssl.SSLContext:
    """The server's TLS context: TLS >= 1.2, a client certificate signed by ``tls.ca``."""
    assert tls.cert is not None and tls.key is not None and tls.ca is not None
    return tls_context(tls.cert, tls.key, tls.ca)


def role_of(der: bytes) -> str | None:
    """The ModbusRole of a DER certificate; None when it has none (or not as a UTF8String)."""
    from cryptography import x509

    cert = x509.load_der_x509_certificate(der)
    try:
        extension = cert.extensions.get_extension_for_oid(x509.ObjectIdentifier(ROLE_OID))
    except x509.ExtensionNotFound:
        return None
    value = extension.value
    raw = value.value if isinstance(value, x509.UnrecognizedExtension) else b""
    return _utf8string(raw)


def _utf8string(der: bytes) -> str | None:
    """A DER UTF8String's text (tag 0x0C, a short or long length); None if it is not one."""
    if len(der) < 2 or der[0] != _UTF8STRING:
        return None
    length, at = der[1], 2
    if length & 0x80:
        size = length & 0x7F
        if not 1 <= size <= 4 or len(der) < 2 + size:
            return None
        length, at = int.from_bytes(der[2:2 + size], "big"), 2 + size
    if at + length != len(der):
        return None
    try:
        return der[at:].decode("utf-8")
    except UnicodeDecodeError:
        return None


class TlsSession:
    """One server-side TLS session over a byte stream: ciphertext in, plaintext out."""

    def __init__(self, context: ssl.SSLContext) -> None:
        self._in = ssl.MemoryBIO()
        self._out = ssl.MemoryBIO()
        self._tls = context.wrap_bio(self._in, self._out, server_side=True)
        self.established = False
        self.closed = False  # the client sent close_notify

    def feed(self, data: bytes) -> bytes:
        """Take ciphertext; return the plaintext it completes.  Raises ssl.SSLError when the
        handshake fails (then :meth:`outgoing` holds the alert for the client)."""
        self._in.write(data)
        if not self.established:
            try:
                self._tls.do_handshake()
            except ssl.SSLWantReadError:
                return b""
            self.established = True
        chunks = []
        while True:
            try:
                chunk = self._tls.read(65536)
            except ssl.SSLWantReadError:
                break
            except ssl.SSLZeroReturnError:
                self.closed = True
                break
            if not chunk:
                break
            chunks.append(chunk)
        return b"".join(chunks)

    def outgoing(self) -> bytes:
        """Ciphertext to send: handshake messages, alerts, session tickets, answers."""
        return self._out.read()

    def encrypt(self, data: bytes) -> bytes:
        self._tls.write(data)
        return self._out.read()

    def peer_certificate(self) -> bytes | None:
        return self._tls.getpeercert(binary_form=True)

    def version(self) -> str | None:
        return self._tls.version()
