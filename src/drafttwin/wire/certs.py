"""OPC UA and MQTT certificates: self-signed ones for the plant server, the twin client and
the MQTT broker, and the plant server's Basic256Sha256 SignAndEncrypt setup.

``drafttwin twin certs --out DIR`` writes, in DIR:

* ``server_key.pem``, ``server_cert.der``: the plant server's key and certificate;
* ``client_key.pem``, ``client_cert.der``: the twin's;
* ``trusted/client_cert.der``: the client certificates the server accepts (add others here);
* ``mqtt_cert.pem``, ``mqtt_key.pem``: the MQTT broker's TLS certificate and key.

The certificates are self-signed and valid for 365 days (asyncua's ``cert_gen``). With
``plant serve --opcua URL --cert DIR`` the server offers only Basic256Sha256 SignAndEncrypt
and accepts only clients whose certificate lies in ``DIR/trusted``. The twin's side
(:func:`drafttwin.twin.sources.security.secure_client`) connects with
``--source "opcua:URL?cert=DIR"``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from drafttwin.errors import ConfigError
from drafttwin.wire.identity import PLANT_SERVER_URI

SERVER_URI = PLANT_SERVER_URI
CLIENT_URI = "urn:drafttwin:twin:client"
FILES = ("server_key.pem", "server_cert.der", "client_key.pem", "client_cert.der")


HOST_NAME = r"^(?=.{1,64}$)[A-Za-z0-9]([A-Za-z0-9.\-:]*[A-Za-z0-9])?$"
"""A host name or IP address for a certificate: 1-64 characters (X.509's common name), letters,
digits, '.', '-', ':' (IPv6), starting and ending with a letter or digit."""


def check_host(host: str) -> None:
    """Refuse a host a certificate cannot name (it had ended in a traceback from
    ``cryptography``, with half of the folder written)."""
    import re

    if re.fullmatch(HOST_NAME, host) is None:
        raise ConfigError(f"host {host[:80]!r} cannot be named in a certificate", where="--host",
                          fix="give a host name or IP address of 1-64 letters, digits, '.', "
                          "'-' or ':', e.g. 127.0.0.1")  # fmt: skip


async def make_certificates(folder: Path, host: str = "127.0.0.1") -> tuple[list[Path], list[Path]]:
    """Write the server's and the twin's keys and certificates, keeping those still valid for
    ``host``: (the files written, the files kept). Private keys are readable by their owner
    only."""
    import os
    import shutil

    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    check_host(host)
    folder.mkdir(parents=True, exist_ok=True)
    files = [folder / f for f in (*FILES, "mqtt_cert.pem", "mqtt_key.pem")]
    before = {p: p.read_bytes() for p in files if p.is_file()}
    old_mask = os.umask(0o077)  # asyncua writes its keys with the umask (they were 0644)
    try:
        for role, uri, use in (("server", SERVER_URI, ExtendedKeyUsageOID.SERVER_AUTH),
                               ("client", CLIENT_URI, ExtendedKeyUsageOID.CLIENT_AUTH)):  # fmt: skip
            await setup_self_signed_certificate(
                folder / f"{role}_key.pem", folder / f"{role}_cert.der", uri, host, [use],
                {"commonName": f"drafttwin {role}", "organizationName": "drafttwin"},
            )  # fmt: skip
    finally:
        os.umask(old_mask)
    for role in ("server", "client"):  # keys of a folder made before: owner only too
        (folder / f"{role}_key.pem").chmod(0o600)
    (folder / "trusted").mkdir(exist_ok=True)
    shutil.copyfile(folder / "client_cert.der", folder / "trusted" / "client_cert.der")
    if not _mqtt_valid(folder, host):
        _mqtt_tls_certificate(folder, host)
    written = [p for p in files if before.get(p) != p.read_bytes()]
    return written, [p for p in files if p not in written]


def _mqtt_valid(folder: Path, host: str) -> bool:
    """Whether the folder's MQTT TLS certificate and key exist, belong together, name
    ``host`` and stay valid for at least 30 days (a broker and its clients then keep it: a new
    one on every run had cut the clients off)."""
    import datetime as dt

    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    try:
        cert = x509.load_pem_x509_certificate((folder / "mqtt_cert.pem").read_bytes())
        key = serialization.load_pem_private_key((folder / "mqtt_key.pem").read_bytes(), None)
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except (OSError, ValueError, TypeError, x509.ExtensionNotFound):
        return False
    shown = [str(n.value) for n in names]
    same_key = cert.public_key().public_numbers() == key.public_key().public_numbers()  # type: ignore[union-attr]
    lasting = cert.not_valid_after_utc > dt.datetime.now(dt.UTC) + dt.timedelta(days=30)
    return same_key and lasting and host in shown


def _mqtt_tls_certificate(folder: Path, host: str) -> None:
    """A self-signed TLS certificate (PEM, 365 days) for the MQTT broker at ``host``; clients
    trust exactly it (``tls_set(ca_certs=mqtt_cert.pem)``)."""
    import datetime as dt
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    from drafttwin._io import write_bytes_atomic

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, host)])
    try:
        alt: x509.GeneralName = x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        alt = x509.DNSName(host)
    now = dt.datetime.now(dt.UTC)
    cert = (
        x509.CertificateBuilder().subject_name(name).issuer_name(name)
        .public_key(key.public_key()).serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(days=1)).not_valid_after(now + dt.timedelta(days=365))
        .add_extension(x509.SubjectAlternativeName([alt]), critical=False)
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(key, hashes.SHA256())
    )  # fmt: skip
    write_bytes_atomic(folder / "mqtt_cert.pem", cert.public_bytes(serialization.Encoding.PEM))
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())  # fmt: skip
    write_bytes_atomic(folder / "mqtt_key.pem", pem)
    (folder / "mqtt_key.pem").chmod(0o600)


def need_files(folder: Path, *names: str, where: str = "--cert") -> None:
    """Refuse a certificate folder without ``names`` (``where``: the option that named it)."""
    if not folder.is_dir():
        raise ConfigError(f"{folder} is not a folder of certificates", where=where,
                          fix="give the folder 'drafttwin twin certs --out DIR' wrote")  # fmt: skip
    missing = [n for n in names if not (folder / n).is_file()]
    if missing:
        raise ConfigError(f"no {', '.join(missing)} in {folder}", where=where,
                          fix=f"make them with: drafttwin twin certs --out {folder}")  # fmt: skip


async def secure_server(server: Any, folder: Path) -> None:
    """Basic256Sha256 SignAndEncrypt only, the server's certificate, trusted clients only."""
    from asyncua import ua
    from asyncua.crypto.truststore import TrustStore
    from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

    need_files(folder, "server_key.pem", "server_cert.der")
    await server.set_application_uri(SERVER_URI)
    server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
    await server.load_certificate(str(folder / "server_cert.der"))
    await server.load_private_key(str(folder / "server_key.pem"))
    store = TrustStore([folder / "trusted"], [])
    await store.load()
    options = (
        CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT
    )
    server.set_certificate_validator(CertificateValidator(options, store))


__all__ = ["CLIENT_URI", "FILES", "SERVER_URI", "make_certificates", "need_files", "secure_server"]
