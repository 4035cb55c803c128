"""Server TLS contexts, for the Modbus/TCP Security port and the console's HTTPS: one loader,
so both take the same PEM files, the same minimum version, the same errors and the same
warning for a certificate that has expired or is about to.

Imports the standard library only (cryptography, the ``tls`` extra, to read a certificate's
dates when it is installed).
"""

from __future__ import annotations

import datetime
import logging
import ssl
from pathlib import Path

log = logging.getLogger("ncgate")
EXPIRES_SOON_DAYS = 14  # a certificate valid fewer days than this is warned about at start


def server_context(cert: Path, key: str | Path, ca: Path | None = None) -> ssl.SSLContext:
    """TLS 1.2 or later with this certificate chain and key; with ``ca``, a client must
    present a certificate that CA signed (mutual authentication)."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.load_cert_chain(cert, key)
    warning = expiry_warning(cert)
    if warning is not None:
        log.warning("%s", warning)
    if ca is not None:
        context.verify_mode = ssl.CERT_REQUIRED
        context.load_verify_locations(cafile=ca)
    return context


def expiry_warning(cert: Path, now: datetime.datetime | None = None) -> str | None:
    """What to say of the first certificate of ``cert`` that has expired (clients refuse it)
    or expires within EXPIRES_SOON_DAYS; None when it is fine, or its dates cannot be read
    (without cryptography)."""
    try:
        from cryptography import x509
    except ImportError:
        return None
    try:
        certificate = x509.load_pem_x509_certificate(Path(cert).read_bytes())
    except (OSError, ValueError):
        return None
    now = now or datetime.datetime.now(datetime.UTC)
    until = certificate.not_valid_after_utc
    if until <= now:
        return (f"TLS certificate {cert} expired on {until:%Y-%m-%d %H:%M} UTC: clients will "
                "refuse it (renew it: docs/security.md)")
    if until - now <= datetime.timedelta(days=EXPIRES_SOON_DAYS):
        return (f"TLS certificate {cert} expires on {until:%Y-%m-%d %H:%M} UTC, in "
                f"{(until - now).days} days (renew it: docs/security.md)")
    return None
