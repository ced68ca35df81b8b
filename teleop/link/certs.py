"""Certificates for the link's mutual TLS, with ``cryptography.x509``: a local CA, the two sides'
certificates, and the checks :func:`teleop.link.keys.load_keys` runs on them.

Keys are EC P-256; certificates are X.509 v3 signed with ECDSA-SHA256. The CA is marked a CA
(path length 0) that may sign certificates only; a side's certificate is for both client and
server authentication (either side may listen), with the hosts given as its subject alternative
names (what TLS checks the address connected to against) and ``teleop-<role>`` as its common
name (the side's name in the handshake).
"""

from __future__ import annotations

import datetime
import ipaddress
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from teleop.link.keys import KeyFileError


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "teleop"),
                      x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _builder(subject: str, issuer: x509.Name, public_key, now: datetime.datetime, days: int):
    return (x509.CertificateBuilder().subject_name(_name(subject)).issuer_name(issuer)
            .public_key(public_key).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=days)))


def make_ca(now: datetime.datetime, days: int, cn: str = "teleop local CA") -> tuple[bytes, bytes]:
    """A self-signed CA valid ``days`` days from ``now``: (private key PEM, certificate PEM)."""
    key = ec.generate_private_key(ec.SECP256R1())
    pub = key.public_key()
    cert = (_builder(cn, _name(cn), pub, now, days)
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(pub), critical=False)
            .sign(key, hashes.SHA256()))
    return _key_pem(key), cert.public_bytes(serialization.Encoding.PEM)


def _san(host: str) -> x509.GeneralName:
    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def issue(ca_key_pem: bytes, ca_cert_pem: bytes, cn: str, hosts: tuple[str, ...],
          now: datetime.datetime, days: int) -> tuple[bytes, bytes]:
    """A side's key and certificate, issued by the CA: (private key PEM, certificate PEM)."""
    ca_key = serialization.load_pem_private_key(ca_key_pem, None)
    ca_cert = x509.load_pem_x509_certificate(ca_cert_pem)
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (_builder(cn, ca_cert.subject, key.public_key(), now, days)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(True, False, False, False, False, False, False, False, False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.SubjectAlternativeName([_san(h) for h in hosts]), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(
                ca_cert.extensions.get_extension_for_class(x509.SubjectKeyIdentifier).value), critical=False)
            .sign(ca_key, hashes.SHA256()))
    return _key_pem(key), cert.public_bytes(serialization.Encoding.PEM)


def _read(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise KeyFileError(f"{path}: no such {what} file (make one with 'teleop keys')") from None
    except OSError as e:
        raise KeyFileError(f"{path}: cannot read the {what} ({e.__class__.__name__}: {e})") from None


def _cert(path: Path, what: str) -> x509.Certificate:
    try:
        return x509.load_pem_x509_certificate(_read(path, what))
    except ValueError:
        raise KeyFileError(f"{path}: not a PEM certificate") from None


def check_pair(ca_path: Path, cert_path: Path, key_path: Path) -> str:
    """Check a side's certificate against the CA (signature, dates) and its private key (the
    same public key, not readable by others); returns the certificate's common name."""
    ca, cert = _cert(ca_path, "CA certificate"), _cert(cert_path, "certificate")
    try:
        cert.verify_directly_issued_by(ca)
    except (InvalidSignature, ValueError, TypeError):
        raise KeyFileError(f"{cert_path}: not issued by the CA in {ca_path}") from None
    now = datetime.datetime.now(datetime.UTC)
    for c, p in ((ca, ca_path), (cert, cert_path)):
        if not c.not_valid_before_utc <= now <= c.not_valid_after_utc:
            raise KeyFileError(f"{p}: not valid now (valid {c.not_valid_before_utc:%Y-%m-%d} to "
                               f"{c.not_valid_after_utc:%Y-%m-%d})")
    if key_path.exists() and key_path.stat().st_mode & 0o077:
        mode = key_path.stat().st_mode & 0o777
        raise KeyFileError(f"{key_path}: readable by others (mode {mode:04o}); 'chmod 600 {key_path}'")
    try:
        key = serialization.load_pem_private_key(_read(key_path, "private key"), None)
    except (ValueError, TypeError):
        raise KeyFileError(f"{key_path}: not an unencrypted PEM private key") from None
    pub = serialization.PublicFormat.SubjectPublicKeyInfo
    if key.public_key().public_bytes(serialization.Encoding.DER, pub) != cert.public_key().public_bytes(
            serialization.Encoding.DER, pub):
        raise KeyFileError(f"{key_path}: does not match the certificate {cert_path}")
    cns = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    if not cns:
        raise KeyFileError(f"{cert_path}: the certificate has no common name (the side's name)")
    return str(cns[0].value)
