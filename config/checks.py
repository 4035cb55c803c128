"""The checks across keys of a config that reads well key by key: overlapping Modbus regions,
an auxiliary function's places, a console or an OPC UA server bound beyond loopback without
its protection, TLS files that do not load.  Each names the dotted key to change."""

from __future__ import annotations

import importlib.util
import ipaddress
import ssl
from pathlib import Path
from typing import TYPE_CHECKING

from ncgate.config.schema import (
    AuxConfig,
    Config,
    ModbusTlsConfig,
    PlcConfig,
    WebTlsConfig,
    _outside_image,
    x509_certificate,
)

if TYPE_CHECKING:
    from ncgate.config.reader import _Reader


def _check_config(r: _Reader, config: Config, serving: bool = True,
                  cell: str = "ncgate") -> None:
    """``cell``: the cell's name (the config file's stem), which the OPC UA server's
    application URI carries."""
    nc, plc, canopen = config.nc, config.plc, config.canopen
    in_image = [(f"nc.ve.{name}.map", ve.map) for name, ve in nc.ve.items()]
    in_image += [(f"nc.{key}", getattr(nc, key))
                 for key in ("feed_hold_input", "cycle_start_inhibit_input") if getattr(nc, key)]
    for key, text in in_image:
        if _outside_image(text, plc):
            raise r.fail(key, f"{text} is outside the image (plc.sa_bits, plc.k_bytes, "
                         "plc.syvars)")
    if nc.aux is not None:
        _check_aux(r, nc.aux, nc.processes, plc)
    modbus = config.modbus
    if (modbus.rtu.port is not None or modbus.rtu_tcp.port is not None) and \
            not modbus.rtu_unit_ids:
        raise r.fail("modbus.rtu.unit_ids", f"missing: modbus.unit_ids "
                     f"({list(modbus.unit_ids)}) has no serial address (1..247) for Modbus "
                     "RTU to answer as")
    if nc.tool_change_s > nc.limits.block_s:
        raise r.fail("nc.tool_change_s", f"{nc.tool_change_s:g} s is longer than a block may "
                     f"take (nc.limits.block_s = {nc.limits.block_s:g})")
    if plc.sa_bits % 8:
        raise r.fail("plc.sa_bits", f"expected a multiple of 8, got {plc.sa_bits}")
    if canopen.enabled:
        # The dictionary's shape (spec 3.3): 0x2000 is one ARRAY of at most 254 entries,
        # 0x2100+j (128 K bytes each) must stay below 0x2200.
        if plc.sa_bits > 254 * 8:
            raise r.fail("plc.sa_bits", f"the CANopen object 0x2000 holds at most 254 SA bytes "
                         f"(2032 bits), got {plc.sa_bits} bits; lower it or set "
                         "canopen.enabled = false")
        if plc.k_bytes > 128 * 256:
            raise r.fail("plc.k_bytes", "the CANopen objects 0x2100..0x21FF hold at most 32768 "
                         f"K bytes, got {plc.k_bytes}")
    _check_tls(r, config.modbus.tls)
    _check_web_tls(r, config.web.tls)
    if config.opcua.enabled:
        _check_ua_certificate(r, config.opcua.certificate, config.opcua.private_key, cell)
    web = config.web
    if serving and web.enabled and not is_loopback(web.host) and not web.token:
        raise r.fail("web.token", f"the console listens on {web.host}, beyond this "
                     "machine: set a token (or web.host = \"127.0.0.1\")")
    if web.token is not None and len(web.token) < 8:
        raise r.fail("web.token", "expected at least 8 characters")
    if web.token is not None and web.token != web.token.strip():
        # A browser or curl sends the token as typed: one pasted with a space never matches.
        raise r.fail("web.token", "has spaces or line breaks around it; remove them")


def _check_aux(r: _Reader, aux: AuxConfig, processes: int, plc: PlcConfig) -> None:
    """Every process's places are inside the image, and no strobe is an acknowledge."""
    settings = aux.settings()
    last = settings.place(processes, "H")
    area, index, _ = last[0]
    index += (settings.words - 1) * (2 if area == "SK" else 1)  # its low word
    size = plc.syvars if area == "SYVAR" else plc.k_bytes - 1
    if index >= size:
        raise r.fail("nc.aux.value", f"{aux.value}: P{processes}'s H value would end at "
                     f"{area}{index}{'.IN' if area == 'SK' else ''}, outside the image "
                     f"({4 * settings.words * processes} words from it; plc.syvars, "
                     "plc.k_bytes)")
    for name, bit in (("strobe", last[1]), ("ack", last[2])):
        if bit >= plc.sa_bits:
            raise r.fail(f"nc.aux.{name}", f"{getattr(aux, name)}: P{processes}'s H bit would "
                         f"be SA{bit}, outside the image ({4 * processes} bits from it; "
                         "plc.sa_bits)")
    strobes = range(settings.strobe, settings.strobe + 4 * processes)
    acks = range(settings.ack, settings.ack + 4 * processes)
    if set(strobes) & set(acks):
        raise r.fail("nc.aux.ack", f"{aux.ack}..SA{acks[-1]} overlaps the strobes "
                     f"{aux.strobe}..SA{strobes[-1]}")


def is_loopback(host: str) -> bool:
    """A loopback address, or ``localhost`` (any other name may resolve to anything)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: it may resolve to anything


def _load_pair(r: _Reader, key: str, cert: Path | None, private: Path | None,
               *more: Path | None) -> ssl.SSLContext:
    """A server's certificate and key (and ``more`` files) exist and load as a pair: a
    server context holding them, or the error naming ``key``.cert / .key."""
    names = ("cert", "key", "ca")
    for name, path in zip(names, (cert, private, *more), strict=False):
        if path is not None:
            r.regular(f"{key}.{name}", path)
    assert cert is not None and private is not None
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    try:
        context.load_cert_chain(cert, private)
    except (ssl.SSLError, ValueError) as exc:
        raise r.fail(f"{key}.key", f"the certificate {cert.name} and key {private.name} do "
                     f"not load as a pair: {exc}") from None
    return context


def _check_ua_certificate(r: _Reader, cert: Path | None, private: Path | None,
                          cell: str) -> None:
    """The OPC UA server's certificate and key load, are a pair, and the certificate names the
    server's application URI: asyncua took any, and then every secure client timed out (a
    key of another certificate: the server failed to decrypt) or a strict one refused the
    server (Bad_CertificateUriInvalid)."""
    if cert is None or private is None:
        return
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    r.regular("opcua.certificate", cert)
    r.regular("opcua.private_key", private)
    try:
        loaded = x509_certificate(cert.read_bytes())
    except ValueError as exc:
        raise r.fail("opcua.certificate", f"{cert.name} is not a certificate (PEM or DER): "
                     f"{exc}") from None
    try:
        key = serialization.load_pem_private_key(private.read_bytes(), None)
    except (ValueError, TypeError) as exc:
        raise r.fail("opcua.private_key", f"{private.name} is not a private key (PEM, "
                     f"unencrypted): {exc}") from None
    spki = (serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo)
    if key.public_key().public_bytes(*spki) != loaded.public_key().public_bytes(*spki):
        raise r.fail("opcua.private_key", f"{private.name} is not the key of the certificate "
                     f"{cert.name}")
    uri = f"urn:ncgate:{cell}"
    try:
        names = loaded.extensions.get_extension_for_class(x509.SubjectAlternativeName)
        uris = names.value.get_values_for_type(x509.UniformResourceIdentifier)
    except x509.ExtensionNotFound:
        uris = []
    if uri not in uris:
        raise r.fail("opcua.certificate", f"{cert.name}'s subjectAltName holds "
                     f"{', '.join(uris) or 'no URI'}, not the server's application URI "
                     f"{uri} (the config file's name: docs/opcua.md): clients refuse it")


def _check_web_tls(r: _Reader, tls: WebTlsConfig) -> None:
    """[web.tls]: both files or neither, and they load (the Modbus TLS loader's check)."""
    if tls.cert is None and tls.key is None:
        return
    if tls.cert is None:
        raise r.fail("web.tls.cert", "missing (web.tls.key is set: HTTPS needs cert and key)")
    if tls.key is None:
        raise r.fail("web.tls.key", "missing (HTTPS needs cert and key)")
    _load_pair(r, "web.tls", tls.cert, tls.key)


def _check_tls(r: _Reader, tls: ModbusTlsConfig) -> None:
    """The TLS files exist and load (so that a bad one is named before anything starts)."""
    if not tls.enabled:
        for name in ("key", "ca"):
            if getattr(tls, name) is not None:
                raise r.fail("modbus.tls.cert", f"missing (modbus.tls.{name} is set: TLS "
                             "needs cert, key and ca)")
        if not tls.plain:
            raise r.fail("modbus.tls.plain", "false needs TLS on (modbus.tls.cert, key, ca): "
                         "Modbus would have no listener; set modbus.enabled = false instead")
        return
    for name in ("key", "ca"):
        if getattr(tls, name) is None:
            raise r.fail(f"modbus.tls.{name}", "missing (TLS needs cert, key and ca)")
    context = _load_pair(r, "modbus.tls", tls.cert, tls.key, tls.ca)
    try:
        context.load_verify_locations(cafile=tls.ca)
    except (ssl.SSLError, ValueError) as exc:
        raise r.fail("modbus.tls.ca", f"not a PEM CA certificate: {exc}") from None
    if importlib.util.find_spec("cryptography") is None:
        raise r.fail("modbus.tls.cert", "Modbus/TCP Security reads the client's role from its "
                     "certificate with the cryptography package: pip install 'ncgate[tls]'")
