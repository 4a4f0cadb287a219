"""`plc tls`: the certificates of Modbus/TCP Security (MBAPS) for commissioning.

    plc tls ca DIR [--name NAME] [--days N]                  DIR/ca.pem, DIR/ca.key: a CA of this machine
    plc tls server DIR [--name NAME] [--ip ADDR]... [--dns NAME]... [--days N]
                                                             DIR/server.pem, DIR/server.key: the runtime's
    plc tls client DIR --name NAME --role read|host|engineer [--days N]
                                                             DIR/NAME.pem, DIR/NAME.key: a client's, with its role

The server and client certificates are signed by DIR/ca.pem and DIR/ca.key (made first with `plc tls ca`).  A
client certificate carries its role in the MBAPS role extension, OID 1.3.6.1.4.1.50316.802.1, a DER UTF8String
(non-critical), which the runtime reads; the runtime's [modbus.tls] names server.pem, server.key and ca.pem.  Keys
are ECDSA P-256, written mode 0600; an existing file is kept unless --force.

Exit status: 0 the files were written; 1 they were not (a file exists, the CA is missing or unreadable, a
directory cannot be written); 2 a usage error.
"""
from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

ROLE_OID = "1.3.6.1.4.1.50316.802.1"          # the MBAPS role extension (Modbus/TCP Security, section 6)
ROLES = ("read", "host", "engineer")
CA_DAYS, LEAF_DAYS = 3650, 825
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


class TlsError(Exception):
    """What stops a command; str() is the message for the user."""


def _crypto():
    try:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
    except ImportError:
        raise TlsError("the Python package 'cryptography' is missing: run scripts/setup "
                       "(or pip install cryptography)") from None
    return x509, hashes, serialization, ec, ExtendedKeyUsageOID, NameOID


def der_utf8(text: str) -> bytes:
    """`text` as a DER UTF8String (tag 12): the value of the role extension."""
    data = text.encode()
    n = len(data)
    length = bytes([n]) if n < 0x80 else bytes([0x80 | (n.bit_length() + 7) // 8]) + n.to_bytes(
        (n.bit_length() + 7) // 8, "big")
    return b"\x0c" + length + data


@dataclass
class Issued:
    key: object          # the private key (cryptography)
    cert: object         # the certificate (cryptography)

    def pem(self) -> tuple[bytes, bytes]:
        """(certificate, private key) as PEM."""
        _, _, serialization, *_ = _crypto()
        return (self.cert.public_bytes(serialization.Encoding.PEM),
                self.key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                       serialization.NoEncryption()))


def _validity(days: int, not_before: dt.datetime | None, not_after: dt.datetime | None):
    now = dt.datetime.now(dt.timezone.utc)
    start = not_before or now - dt.timedelta(minutes=5)       # a clock a little behind still accepts it
    return start, not_after or now + dt.timedelta(days=days)


def make_ca(name: str = "atc-plc CA", days: int = CA_DAYS, not_before: dt.datetime | None = None,
            not_after: dt.datetime | None = None) -> Issued:
    """A self-signed CA (it signs certificates only, no intermediate CA below it)."""
    x509, hashes, _, ec, _, NameOID = _crypto()
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    start, end = _validity(days, not_before, not_after)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(start).not_valid_after(end)
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                         crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    return Issued(key, cert)


def make_leaf(ca: Issued, name: str, role: str | None = None, server: bool = False, ips: Sequence[str] = (),
              dns: Sequence[str] = (), days: int = LEAF_DAYS, not_before: dt.datetime | None = None,
              not_after: dt.datetime | None = None, role_value: bytes | None = None) -> Issued:
    """A certificate signed by `ca`: the runtime's (`server`: server authentication, the addresses it is reached
    at) or a client's (client authentication, `role` in the MBAPS role extension; `role_value` puts those exact
    bytes there instead, for tests of what the runtime refuses)."""
    x509, hashes, _, ec, EKU, NameOID = _crypto()
    from cryptography.x509.oid import ObjectIdentifier
    key = ec.generate_private_key(ec.SECP256R1())
    start, end = _validity(days, not_before, not_after)
    builder = (x509.CertificateBuilder().subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
               .issuer_name(ca.cert.subject).public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(start).not_valid_after(end)
               .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
               .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                            data_encipherment=False, key_agreement=False, key_cert_sign=False,
                                            crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
               .add_extension(x509.ExtendedKeyUsage([EKU.SERVER_AUTH if server else EKU.CLIENT_AUTH]), critical=False)
               .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca.key.public_key()),
                              critical=False))
    if server:
        names = [x509.IPAddress(ipaddress.ip_address(a)) for a in ips] + [x509.DNSName(d) for d in dns]
        if names:
            builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
    value = role_value if role_value is not None else der_utf8(role) if role is not None else None
    if value is not None:
        builder = builder.add_extension(x509.UnrecognizedExtension(ObjectIdentifier(ROLE_OID), value), critical=False)
    return Issued(key, builder.sign(ca.key, hashes.SHA256()))


def write_pair(issued: Issued, cert_path: Path, key_path: Path, force: bool = False) -> None:
    """The certificate (mode 0644) and its key (mode 0600); TlsError when one exists and not `force`."""
    cert_pem, key_pem = issued.pem()
    for path in (cert_path, key_path):
        if path.exists() and not force:
            raise TlsError(f"{path} exists (--force replaces it)")
    try:
        cert_path.parent.mkdir(parents=True, exist_ok=True)
        for path, data, mode in ((key_path, key_pem, 0o600), (cert_path, cert_pem, 0o644)):
            tmp = path.with_name(path.name + ".tmp")
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.chmod(tmp, mode)
            os.replace(tmp, path)
    except OSError as exc:
        raise TlsError(f"cannot write {exc.filename or cert_path.parent}: {exc.strerror or exc}") from None


def load_ca(directory: Path) -> Issued:
    """DIR/ca.pem and DIR/ca.key, made by `plc tls ca DIR`."""
    x509, _, serialization, *_ = _crypto()
    cert_path, key_path = directory / "ca.pem", directory / "ca.key"
    try:
        cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except FileNotFoundError as exc:
        raise TlsError(f"{exc.filename} does not exist: make the CA first (plc tls ca {directory})") from None
    except OSError as exc:
        raise TlsError(f"cannot read {exc.filename}: {exc.strerror}") from None
    except (ValueError, TypeError) as exc:
        raise TlsError(f"the CA in {directory} does not load (ca.pem, ca.key): {exc}") from None
    if cert.public_key().public_numbers() != key.public_key().public_numbers():
        raise TlsError(f"{key_path} is not the key of {cert_path}")
    return Issued(key, cert)


def _describe(issued: Issued, path: Path) -> str:
    end = issued.cert.not_valid_after_utc.strftime("%Y-%m-%d")
    return f"{path} ({issued.cert.subject.rfc4514_string()}, valid until {end})"


def cmd_ca(args) -> int:
    ca = make_ca(args.name, args.days)
    write_pair(ca, args.dir / "ca.pem", args.dir / "ca.key", args.force)
    print(f"plc tls: wrote the CA {_describe(ca, args.dir / 'ca.pem')} and its key {args.dir / 'ca.key'} "
          "(keep the key off the PLC)")
    return 0


def cmd_server(args) -> int:
    ca = load_ca(args.dir)
    leaf = make_leaf(ca, args.name, server=True, ips=args.ip or ["127.0.0.1"], dns=args.dns or [], days=args.days)
    write_pair(leaf, args.dir / "server.pem", args.dir / "server.key", args.force)
    print(f"plc tls: wrote the runtime's certificate {_describe(leaf, args.dir / 'server.pem')} and key "
          f"{args.dir / 'server.key'}; [modbus.tls]: cert = \"server.pem\", key = \"server.key\", ca = \"ca.pem\"")
    return 0


def cmd_client(args) -> int:
    ca = load_ca(args.dir)
    leaf = make_leaf(ca, args.name, role=args.role, days=args.days)
    cert, key = args.dir / f"{args.name}.pem", args.dir / f"{args.name}.key"
    write_pair(leaf, cert, key, args.force)
    print(f"plc tls: wrote the client certificate {_describe(leaf, cert)}, role {args.role}, and its key {key}")
    return 0


def _name(value: str) -> str:
    if not NAME.fullmatch(value):
        raise argparse.ArgumentTypeError(f"'{value}' is not a name of letters, digits, '.', '_' and '-' "
                                         "(at most 64, the first a letter or digit)")
    return value


def _days(value: str) -> int:
    if not value.isdigit() or not 1 <= int(value) <= 36500:
        raise argparse.ArgumentTypeError(f"'{value}' is not a number of days 1..36500")
    return int(value)


def _ip(value: str) -> str:
    try:
        return str(ipaddress.ip_address(value))
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{value}' is not an IP address") from None


EXIT = ("Exit status: 0 the files were written; 1 they were not (a file exists, the CA is missing or unreadable, "
        "a directory cannot be written); 2 a usage error.")


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="plc tls", description="Certificates of Modbus/TCP Security (MBAPS, the "
                                 "runtime's [modbus.tls]) for commissioning: a CA, the runtime's certificate, and "
                                 "client certificates carrying a role (read, host or engineer) in the MBAPS role "
                                 f"extension {ROLE_OID}. Keys: ECDSA P-256, mode 0600.", epilog=EXIT)
    sub = ap.add_subparsers(dest="what", metavar="ca|server|client")
    sub.required = True
    p = sub.add_parser("ca", help="make a CA: DIR/ca.pem and DIR/ca.key", epilog=EXIT,
                       description="Make a self-signed CA, DIR/ca.pem and its key DIR/ca.key; it signs the "
                                   "runtime's and the clients' certificates. Keep ca.key off the PLC.")
    p.add_argument("dir", type=Path, metavar="DIR")
    p.add_argument("--name", default="atc-plc CA", help="its common name (default 'atc-plc CA')")
    p.add_argument("--days", type=_days, default=CA_DAYS, help=f"valid this many days (default {CA_DAYS})")
    p.add_argument("--force", action="store_true", help="replace existing files")
    p.set_defaults(func=cmd_ca)
    p = sub.add_parser("server", help="the runtime's certificate: DIR/server.pem and DIR/server.key", epilog=EXIT,
                       description="Make the runtime's certificate DIR/server.pem and key DIR/server.key, signed by "
                                   "the CA of DIR, for the addresses clients reach the PLC at.")
    p.add_argument("dir", type=Path, metavar="DIR")
    p.add_argument("--name", type=_name, default="atc-plc", help="its common name (default atc-plc)")
    p.add_argument("--ip", type=_ip, action="append", metavar="ADDR",
                   help="an address of the PLC (repeatable; default 127.0.0.1)")
    p.add_argument("--dns", action="append", metavar="NAME", help="a host name of the PLC (repeatable)")
    p.add_argument("--days", type=_days, default=LEAF_DAYS, help=f"valid this many days (default {LEAF_DAYS})")
    p.add_argument("--force", action="store_true", help="replace existing files")
    p.set_defaults(func=cmd_server)
    p = sub.add_parser("client", help="a client's certificate with a role: DIR/NAME.pem and DIR/NAME.key",
                       epilog=EXIT, description="Make a client certificate DIR/NAME.pem and key DIR/NAME.key, "
                       "signed by the CA of DIR, with the role the runtime gives the client: read (no write), host "
                       "(the host's command signals) or engineer (every writable coil and register).")
    p.add_argument("dir", type=Path, metavar="DIR")
    p.add_argument("--name", type=_name, required=True, help="the client's common name, also the files' name")
    p.add_argument("--role", choices=ROLES, required=True, help="what the client may write")
    p.add_argument("--days", type=_days, default=LEAF_DAYS, help=f"valid this many days (default {LEAF_DAYS})")
    p.add_argument("--force", action="store_true", help="replace existing files")
    p.set_defaults(func=cmd_client)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        return args.func(args)
    except TlsError as exc:
        print(f"plc tls: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
