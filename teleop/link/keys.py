"""The link's key material: the pairing key both sides share, and the certificates for TLS.

:func:`make_keys` writes a folder (``teleop keys`` calls it)::

    pairing.key   the pre-shared pairing key, 32 random bytes (mode 0600)
    ca.pem        a local certificate authority (self-signed, EC P-256)
    ca.key        its private key (mode 0600; keep it off both hosts once the pair is issued)
    master.pem    the master's certificate, issued by the CA, SAN = the hosts given
    master.key    its private key (PKCS#8, mode 0600)
    slave.pem     the slave's, likewise
    slave.key

The pairing key file is two lines of text (``#`` comment lines allowed)::

    teleop pairing key v1
    <64 hex digits>

Copy the whole folder to both hosts (or, leaving out ``ca.key``, ``pairing.key``, ``ca.pem`` and
each side's own pair to its host). :func:`load_keys` reads what a side needs into a
:class:`LinkKeys`; every error is one line naming the file and the reason
(:class:`KeyFileError`). :func:`one_run_keys` makes a random key for one run and writes it to a
private temporary folder, for a parent process that starts both sides itself.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import secrets
import tempfile
from dataclasses import dataclass
from pathlib import Path

from teleop.util.errors import ConfigError

KEY_BYTES = 32
PAIRING_FILE = "pairing.key"
CA_CERT, CA_KEY = "ca.pem", "ca.key"
HEADER = "teleop pairing key v1"
ROLES = ("master", "slave")
DEFAULT_HOSTS = ("127.0.0.1", "localhost")


class KeyFileError(ConfigError):
    """A key or certificate file that cannot be used: names the file and the reason."""


@dataclass(frozen=True)
class LinkKeys:
    """What one side of the link holds.

    secret: the pairing key (32 bytes) both sides share; the per-session MAC keys derive from it.
    name: this side's identity in the handshake (its certificate's common name, or its role).
    ca_pem / cert_pem / key_pem: the CA certificate, this side's certificate and its private
        key, for mutual TLS (None when there are none: loopback only).
    """

    secret: bytes
    name: str
    ca_pem: Path | None = None
    cert_pem: Path | None = None
    key_pem: Path | None = None

    def __post_init__(self):
        if not isinstance(self.secret, bytes) or len(self.secret) != KEY_BYTES:
            raise KeyFileError(f"LinkKeys.secret: expected {KEY_BYTES} bytes")
        if not self.name or len(self.name.encode()) > 64 or any(c in self.name for c in "\r\n"):
            raise KeyFileError(f"LinkKeys.name: a one-line name of at most 64 bytes, got {self.name!r}")

    @property
    def has_tls(self) -> bool:
        """True when the CA, certificate and private key are all there."""
        return None not in (self.ca_pem, self.cert_pem, self.key_pem)

    def __repr__(self) -> str:  # never print the secret
        return f"LinkKeys(name={self.name!r}, tls={self.has_tls})"


def random_secret() -> bytes:
    """A fresh pairing key (32 bytes from the OS's CSPRNG)."""
    return secrets.token_bytes(KEY_BYTES)


def _write_private(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file readable by its owner only (mode 0600, made so at creation)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, data)
    finally:
        os.close(fd)


def write_pairing_key(path: str | Path, secret: bytes | None = None) -> bytes:
    """Write a pairing key file at ``path`` (mode 0600); returns the key (``secret`` or a new one)."""
    secret = random_secret() if secret is None else secret
    if len(secret) != KEY_BYTES:
        raise KeyFileError(f"{path}: a pairing key has {KEY_BYTES} bytes, got {len(secret)}")
    _write_private(Path(path), f"{HEADER}\n{secret.hex()}\n".encode())
    return secret


def load_pairing_key(path: str | Path) -> bytes:
    """The key of a pairing key file; KeyFileError naming the file and the reason."""
    path = Path(path)
    try:
        st = path.stat()
        text = path.read_text(encoding="ascii")
    except FileNotFoundError:
        raise KeyFileError(f"{path}: no such pairing key file (make one with 'teleop keys')") from None
    except (OSError, UnicodeDecodeError) as e:
        raise KeyFileError(f"{path}: cannot read the pairing key ({e.__class__.__name__}: {e})") from None
    if st.st_mode & 0o077:
        raise KeyFileError(f"{path}: readable by others (mode {st.st_mode & 0o777:04o}); 'chmod 600 {path}'")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if len(lines) != 2 or lines[0] != HEADER:
        raise KeyFileError(f"{path}: not a pairing key file (expected the line {HEADER!r} and one line of hex)")
    try:
        secret = bytes.fromhex(lines[1])
    except ValueError:
        raise KeyFileError(f"{path}: the key is not hexadecimal") from None
    if len(secret) != KEY_BYTES:
        raise KeyFileError(f"{path}: the key has {len(secret)} bytes, expected {KEY_BYTES}")
    return secret


def one_run_keys(role_names: tuple[str, str] = ROLES) -> tuple[Path, LinkKeys, LinkKeys]:
    """A random pairing key for one run, written to ``pairing.key`` in a new private temporary
    folder (mode 0700, the file 0600), for a parent that starts both sides: returns the file
    (pass it to the children; delete its folder afterwards) and the master's and the slave's keys."""
    folder = Path(tempfile.mkdtemp(prefix="teleop-link-"))
    path = folder / PAIRING_FILE
    secret = write_pairing_key(path)
    return path, LinkKeys(secret, role_names[0]), LinkKeys(secret, role_names[1])


def load_keys(folder: str | Path, role: str, pairing_key: str | Path | None = None) -> LinkKeys:
    """What ``role`` needs from a keys folder (:func:`make_keys`): the pairing key (``pairing_key``
    or ``folder/pairing.key``) and, when ``folder/<role>.pem`` exists, the CA, the certificate and
    its private key, checked (issued by the CA, in date, the key matching); the side's name is the
    certificate's common name, else the role."""
    from teleop.link import certs

    if role not in ROLES:
        raise ConfigError(f"load_keys.role: expected one of {ROLES}, got {role!r}")
    folder = Path(folder)
    if not folder.is_dir():
        raise KeyFileError(f"{folder}: no such keys folder (make one with 'teleop keys')")
    secret = load_pairing_key(pairing_key if pairing_key is not None else folder / PAIRING_FILE)
    cert = folder / f"{role}.pem"
    if not cert.exists():
        return LinkKeys(secret, role)
    ca, key = folder / CA_CERT, folder / f"{role}.key"
    name = certs.check_pair(ca, cert, key)
    return LinkKeys(secret, name, ca, cert, key)


def make_keys(folder: str | Path, hosts: tuple[str, ...] | list[str] = DEFAULT_HOSTS, tls: bool = True,
              days: int = 365, overwrite: bool = False) -> dict[str, Path]:
    """Write a keys folder (see the module docstring): the pairing key and, with ``tls``, a local
    CA and a master and a slave certificate valid ``days`` days, whose subject alternative names
    are ``hosts`` (IP addresses or DNS names: every address either side is reached at). Refuses
    to replace existing files unless ``overwrite``. Returns the files written, by name."""
    from teleop.link import certs

    folder = Path(folder)
    hosts = tuple(hosts)
    if tls and not hosts:
        raise ConfigError("make_keys: give at least one host for the certificates' names")
    for h in hosts:
        _check_host(h)
    names = [PAIRING_FILE] + ([CA_CERT, CA_KEY] + [f"{r}.{x}" for r in ROLES for x in ("pem", "key")] if tls else [])
    folder.mkdir(parents=True, exist_ok=True)
    existing = [n for n in names if (folder / n).exists()]
    if existing and not overwrite:
        raise KeyFileError(f"{folder / existing[0]}: exists; not replaced "
                           "(teleop keys --force, or overwrite=True, makes new keys)")
    out = {PAIRING_FILE: folder / PAIRING_FILE}
    write_pairing_key(out[PAIRING_FILE])
    if tls:
        now = datetime.datetime.now(datetime.UTC)
        ca_key, ca_cert = certs.make_ca(now, days)
        out.update(_write_pair(folder, "ca", ca_key, ca_cert))
        for role in ROLES:
            key, cert = certs.issue(ca_key, ca_cert, f"teleop-{role}", hosts, now, days)
            out.update(_write_pair(folder, role, key, cert))
    return out


def _write_pair(folder: Path, stem: str, key_pem: bytes, cert_pem: bytes) -> dict[str, Path]:
    cert, key = folder / f"{stem}.pem", folder / f"{stem}.key"
    _write_private(key, key_pem)
    cert.write_bytes(cert_pem)
    return {cert.name: cert, key.name: key}


def _check_host(h: str) -> None:
    try:
        ipaddress.ip_address(h)
        return
    except ValueError:
        pass
    labels = h.rstrip(".").split(".")
    if not h or not all(lb and len(lb) <= 63 and lb.replace("-", "").isalnum() for lb in labels):
        raise ConfigError(f"make_keys.hosts: {h!r} is neither an IP address nor a DNS name")
