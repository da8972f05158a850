"""The OPC UA server's settings, checked before any work, and its application certificate.

`opcua_settings(config_path, config, out_dir)` turns [opcua] into `OpcuaSettings` (None while
it is off): files resolved against the config file's folder, the certificate and its key
readable and a pair (the key not readable by every user, as [serve] key), the folder of
trusted client certificates present; a ConfigError names the file and `opcua.<key>`.

`application_certificate(settings)` gives the certificate the server presents: the configured
one, or (none configured) a self-signed one made once in `<output>/opcua/` (`certificate.der`,
`key.pem` written 0600), used again at every start and made again once expired, so the
thumbprint that clients were told to trust stays the same. Its SHA-1 thumbprint (what UaExpert
and most clients show) is logged at every start. The server's application URI is the one in
the certificate's subject alternative names (OPC UA clients check that they agree).
"""

from __future__ import annotations

import datetime
import hashlib
import logging
import socket
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import quote

from stereopose.config import Config
from stereopose.errors import ConfigError
from stereopose.io.writing import write_private

if TYPE_CHECKING:
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric.types import (
        CertificatePublicKeyTypes,
        PrivateKeyTypes,
        PublicKeyTypes,
    )

__all__ = ["AppCertificate", "OpcuaSettings", "application_certificate", "opcua_settings"]

logger = logging.getLogger(__name__)

CERT_DIR = "opcua"  # in the output folder: the generated certificate and key
CERT_FILE, KEY_FILE = "certificate.der", "key.pem"
CERT_DAYS = 5 * 365  # a generated certificate's life: clients trust it once for years
_MAX_FILE = 1 << 20


@dataclass(frozen=True)
class OpcuaSettings:
    """[opcua] checked (see the module); certificate/key None: generated into cert_dir."""

    host: str
    port: int
    path: str
    site: str
    certificate: Path | None
    key: Path | None
    cert_dir: Path
    trusted_clients: Path | None
    security: tuple[str, ...]
    allow_anonymous: bool
    max_connections: int
    queue_size: int

    @property
    def endpoint(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"opc.tcp://{host}:{self.port}{self.path}"


@dataclass(frozen=True)
class AppCertificate:
    """The server's certificate and key (cryptography objects), where they are, their SHA-1
    thumbprint (hex, colon-separated) and the application URI they name."""

    certificate: object
    key: object
    path: Path
    thumbprint: str
    application_uri: str
    generated: bool


def _resolve(base: Path, value: str) -> Path:
    p = Path(value).expanduser()
    return p if p.is_absolute() else base / p


def _readable(path: Path, file: Path, key: str, private: bool = False) -> bytes:
    try:
        st = file.stat()
        if not stat.S_ISREG(st.st_mode) or st.st_size > _MAX_FILE:
            raise ConfigError(f"{path}: {key}: {file} is not a small regular file")
        if private and st.st_mode & 0o007:
            raise ConfigError(f"{path}: {key}: {file} is readable by every user; chmod o-rwx it")
        return file.read_bytes()
    except OSError as e:
        raise ConfigError(f"{path}: {key}: cannot read {file}: {e.strerror}") from None


def opcua_settings(config_path: str | Path, config: Config, out_dir: Path) -> OpcuaSettings | None:
    """[opcua] of `config` (read from config_path) checked, or None while it is off."""
    o = config.opcua
    if not o.enabled:
        return None
    path = Path(config_path)
    try:
        import asyncua  # noqa: F401
    except ImportError:
        raise ConfigError(
            f"{path}: opcua.enabled: the OPC UA server needs the 'scada' extra "
            "(pip install 'stereopose[scada]': asyncua)"
        ) from None
    base = path.resolve().parent
    cert = key = trusted = None
    if o.certificate and o.key:
        cert, key = _resolve(base, o.certificate), _resolve(base, o.key)
        _load_pair(
            path,
            _readable(path, cert, "opcua.certificate"),
            _readable(path, key, "opcua.key", private=True),
            cert,
            key,
        )
    if o.trusted_clients:
        trusted = _resolve(base, o.trusted_clients)
        if not trusted.is_dir():
            raise ConfigError(f"{path}: opcua.trusted_clients: {trusted} is not a folder")
    return OpcuaSettings(
        host=o.host,
        port=o.port,
        path=o.path,
        site=o.site,
        certificate=cert,
        key=key,
        cert_dir=out_dir / CERT_DIR,
        trusted_clients=trusted,
        security=tuple(o.security),
        allow_anonymous=o.allow_anonymous,
        max_connections=o.max_connections,
        queue_size=o.queue_size,
    )


def _load_pair(
    path: Path | None, cert_bytes: bytes, key_bytes: bytes, cert: Path, key: Path
) -> tuple[x509.Certificate, PrivateKeyTypes]:
    """(certificate, key) parsed and checked to be a pair; a ConfigError otherwise."""
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    where = f"{path}: " if path is not None else ""
    try:
        c = (
            x509.load_pem_x509_certificate(cert_bytes)
            if cert_bytes.lstrip().startswith(b"-----")
            else x509.load_der_x509_certificate(cert_bytes)
        )
    except ValueError as e:
        raise ConfigError(
            f"{where}opcua.certificate: {cert} is not a DER or PEM X.509 certificate: {e}"
        ) from None
    try:
        k = load_pem_private_key(key_bytes, password=None)
    except (ValueError, TypeError) as e:
        raise ConfigError(
            f"{where}opcua.key: {key} is not an unencrypted PEM private key: {e}"
        ) from None
    if _spki(c.public_key()) != _spki(k.public_key()):
        raise ConfigError(
            f"{where}opcua.certificate {cert} and opcua.key {key}: the key is not the certificate's"
        )
    return c, k


def thumbprint(cert: x509.Certificate) -> str:
    """The certificate's SHA-1 thumbprint as OPC UA clients show it (AB:CD:...)."""
    from cryptography.hazmat.primitives.serialization import Encoding

    digest = hashlib.sha1(cert.public_bytes(Encoding.DER)).hexdigest().upper()
    return ":".join(digest[i : i + 2] for i in range(0, len(digest), 2))


def _uri(cert: x509.Certificate) -> str | None:
    from cryptography import x509

    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None


def application_certificate(settings: OpcuaSettings) -> AppCertificate:
    """The certificate the server presents (see the module); logs its thumbprint."""
    if settings.certificate is not None and settings.key is not None:
        c, k = _load_pair(
            None,
            settings.certificate.read_bytes(),
            settings.key.read_bytes(),
            settings.certificate,
            settings.key,
        )
        uri = _uri(c) or _default_uri(settings.site)
        app = AppCertificate(c, k, settings.certificate, thumbprint(c), uri, generated=False)
        logger.info("OPC UA: certificate %s (SHA-1 thumbprint %s)", app.path, app.thumbprint)
        return app
    app = _generated(settings)
    return app


def _default_uri(site: str) -> str:
    return f"urn:stereopose:{quote(socket.gethostname(), safe='')}:{quote(site, safe='')}"


def _generated(settings: OpcuaSettings) -> AppCertificate:
    folder = settings.cert_dir
    cert_path, key_path = folder / CERT_FILE, folder / KEY_FILE
    if cert_path.is_file() and key_path.is_file():
        try:
            c, k = _load_pair(
                None, cert_path.read_bytes(), key_path.read_bytes(), cert_path, key_path
            )
        except (ConfigError, OSError) as e:
            logger.warning(
                "OPC UA: the generated certificate in %s cannot be used (%s): making a new one",
                folder,
                e,
            )
        else:
            if c.not_valid_after_utc > datetime.datetime.now(datetime.UTC):
                app = AppCertificate(c, k, cert_path, thumbprint(c), _uri(c) or "", True)
                logger.info(
                    "OPC UA: self-signed certificate %s (SHA-1 thumbprint %s)",
                    cert_path,
                    app.thumbprint,
                )
                return app
            logger.warning(
                "OPC UA: the generated certificate %s expired: making a new one "
                "(clients must trust the new thumbprint)",
                cert_path,
            )
    return _make(settings, cert_path, key_path)


def _make(settings: OpcuaSettings, cert_path: Path, key_path: Path) -> AppCertificate:
    from asyncua.crypto.cert_gen import (
        dump_private_key_as_pem,
        generate_private_key,
        generate_self_signed_app_certificate,
    )
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding
    from cryptography.x509.oid import ExtendedKeyUsageOID

    uri = _default_uri(settings.site)
    host = socket.gethostname()
    names: list[x509.GeneralName] = [x509.UniformResourceIdentifier(uri), x509.DNSName(host)]
    if host != "localhost":
        names.append(x509.DNSName("localhost"))
    key = generate_private_key()
    cert = generate_self_signed_app_certificate(
        key,
        f"stereopose {settings.site}",
        {"organizationName": "stereopose"},
        names,
        [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
        days=CERT_DAYS,
    )
    cert_path.parent.mkdir(parents=True, exist_ok=True)
    write_private(key_path, dump_private_key_as_pem(key))
    write_private(cert_path, cert.public_bytes(Encoding.DER))
    app = AppCertificate(cert, key, cert_path, thumbprint(cert), uri, generated=True)
    logger.warning(
        "OPC UA: made a self-signed certificate %s (SHA-1 thumbprint %s): clients "
        "must trust it; [opcua] certificate and key give your own",
        cert_path,
        app.thumbprint,
    )
    return app


def _spki(key: CertificatePublicKeyTypes | PublicKeyTypes) -> bytes:
    """A public key as its DER SubjectPublicKeyInfo: the same key, the same bytes."""
    from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

    return key.public_bytes(Encoding.DER, PublicFormat.SubjectPublicKeyInfo)
