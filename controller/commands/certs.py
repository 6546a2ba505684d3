"""Make a site CA and one certificate per role (controller, valve, stack, monitor) for ``--certs DIR``.

Files: ``DIR/ca.pem`` (the site CA, the only root every party trusts),
``DIR/ca.key`` (the CA's key: keep it offline, it issues new parties),
``DIR/ROLE.pem`` and ``DIR/ROLE.key`` per role. Keys are ECDSA P-256,
written 0600; each role certificate has the role as common name (the access
control reads it), subjectAltName ``DNS:localhost``, ``IP:127.0.0.1`` and
any ``--host``, and may serve and connect (TLS server and client auth).
Existing files are never overwritten.
"""
from __future__ import annotations

import datetime
import ipaddress
import os
import re


def add_arguments(p) -> None:
    p.add_argument("dir", metavar="DIR", help="folder to write ca.pem, ca.key, ROLE.pem, ROLE.key (created if absent)")
    p.add_argument("--host", action="append", default=[], metavar="NAME",
                   help="extra subjectAltName of every role certificate: a DNS name or an IP address (repeatable)")
    p.add_argument("--days", type=int, default=3650, metavar="N", help="validity, days (default %(default)s)")
    p.add_argument("--site", default="valvectl site", metavar="NAME", help="the CA's common name (default %(default)s)")


#: A DNS host name: dot-separated labels of letters, digits and hyphens, no label starting or ending with one.
_DNS = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)(?:\.(?!-)[A-Za-z0-9-]{1,63}(?<!-))*\.?")


def _names(hosts: list[str]):
    from cryptography import x509

    from models.recording import InputError

    out = [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
    for h in hosts:
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            if not _DNS.fullmatch(h) or len(h) > 253:
                raise InputError(f"--host {h[:80]!r}: not a DNS name (labels of 1-63 letters, digits or '-', "
                                 "dot-separated, at most 253 characters; IDN names in their xn-- form) "
                                 "or an IP address") from None
            out.append(x509.DNSName(h))
    return out


def _write(path: str, data: bytes, mode: int) -> None:
    """Create ``path`` (never overwrite) with ``mode`` from the start: a key is never readable by others."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


#: Longest validity asked of ``--days`` (X.509 times end in 9999; a site renews long before).
MAX_DAYS = 36525


def make_site(folder: str, hosts: list[str] = (), days: int = 3650, site: str = "valvectl site") -> list[str]:
    """Write the CA and the role certificates into ``folder``; returns the paths written."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    from controller.transport.security import ROLES

    now = datetime.datetime.now(datetime.timezone.utc)
    start, end = now - datetime.timedelta(minutes=5), now + datetime.timedelta(days=days)
    pem = serialization.Encoding.PEM

    def key_bytes(k) -> bytes:
        return k.private_bytes(pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, site)])
    ca_ski = x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key())
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(start).not_valid_after(end)
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                       data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                       crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
          .add_extension(ca_ski, critical=False)
          .sign(ca_key, hashes.SHA256()))
    files = {"ca.pem": (ca.public_bytes(pem), 0o644), "ca.key": (key_bytes(ca_key), 0o600)}
    names = x509.SubjectAlternativeName(_names(list(hosts)))
    for role in ROLES:
        k = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder()
                .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, role)]))
                .issuer_name(ca_name).public_key(k.public_key())
                .serial_number(x509.random_serial_number()).not_valid_before(start).not_valid_after(end)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                             data_encipherment=False, key_agreement=False, key_cert_sign=False,
                                             crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .add_extension(names, critical=False)
                .add_extension(x509.SubjectKeyIdentifier.from_public_key(k.public_key()), critical=False)
                .add_extension(x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(ca_ski), critical=False)
                .sign(ca_key, hashes.SHA256()))
        files[f"{role}.pem"] = (cert.public_bytes(pem), 0o644)
        files[f"{role}.key"] = (key_bytes(k), 0o600)
    written = []
    for name, (data, mode) in files.items():
        path = os.path.join(folder, name)
        _write(path, data, mode)
        written.append(path)
    return written


def run(args) -> int:
    from controller.transport.security import ROLES
    from models.recording import InputError

    if not 0 < args.days <= MAX_DAYS:
        raise InputError(f"--days: must be within 1..{MAX_DAYS} (100 years), got {args.days}")
    if not 1 <= len(args.site) <= 64:  # X.509 bounds a common name to 64 characters
        raise InputError(f"--site: the CA's common name must have 1 to 64 characters, got {len(args.site)}")
    folder = args.dir
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise InputError(f"{folder}: exists and is not a folder")
    names = ["ca.pem", "ca.key"] + [f"{r}.{e}" for r in ROLES for e in ("pem", "key")]
    taken = [n for n in names if os.path.exists(os.path.join(folder, n))]
    if taken:
        raise InputError(f"{os.path.join(folder, taken[0])}: exists (certs never overwrites; choose a new folder)")
    _names(args.host)  # bad --host before anything is written
    try:
        os.makedirs(folder, exist_ok=True)
        written = make_site(folder, args.host, args.days, args.site)
    except OSError as exc:
        raise InputError(f"{folder}: cannot write ({exc.strerror})") from None
    print(f"site CA and {len(ROLES)} roles ({', '.join(ROLES)}) -> {folder} ({len(written)} files; keep ca.key offline)")
    return 0
