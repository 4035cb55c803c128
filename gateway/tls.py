"""Server TLS contexts, for the Modbus/TCP Security port and the console's HTTPS: one loader,
so both take the same PEM files, the same minimum version and the same errors.

Imports the standard library only.
"""

from __future__ import annotations

import ssl
from pathlib import Path


def server_context(cert: Path, key: str | Path, ca: Path | None = None) -> ssl.SSLContext:
    """TLS 1.2 or later with this certificate chain and key; with ``ca``, a client must
    present a certificate that CA signed (mutual authentication)."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.load_cert_chain(cert, key)
    if ca is not None:
        context.verify_mode = ssl.CERT_REQUIRED
        context.load_verify_locations(cafile=ca)
    return context
