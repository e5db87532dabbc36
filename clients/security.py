"""``fleet-security``: everything a secured fleet needs, made in one command.

    fleet-security init secure/ --robots tb3_0,tb3_1 --host localhost --host 192.168.1.20
    simd -c secure/simd/simd.json5                   # TLS on 7447, users checked, access control on
    fleet -c secure/operator.json5 spawn tb3_0 -2 -0.5
    fleet-teleop tb3_0 -c secure/driver_tb3_0.json5
    fleet-view -c secure/observer.json5

It writes, into a new directory:

- a local certificate authority (``ca.pem``, ``ca-key.pem``), made with the ``cryptography``
  library (ECDSA P-256, a year of validity);
- one zenoh configuration for each user, which every fleetsim client takes with ``-c``;
- ``simd/``, the daemon's own files, all that a container mounts: its certificate
  (``simd.pem``, ``simd-key.pem``) for the host names and addresses given (and localhost),
  ``users.txt`` (one random password per user, for zenoh's user/password authentication),
  ``simd.json5`` (TLS listener, the password file, access control), ``health.json5`` for the
  container's healthcheck (``SIMD_HEALTH_CONFIG``) and a copy of ``ca.pem``.

The users are the roles of the access control (``simd`` enforces it on every message that
reaches it):

- ``operator``: spawn, delete, pause, resume, reset, step; drive any robot; read everything;
- ``observer``: read everything (list, world, clock, every topic), change nothing;
- ``driver_<ns>`` (one per ``--robots`` name): drive robot ``<ns>`` and read its topics, plus
  the fleet's list, world and clock;
- no remote user may answer the fleet's queries or publish on its topics (odometry, scans,
  clock, liveliness): only the daemon does, so nobody can impersonate it.

Private keys and ``users.txt`` are readable by their owner only; the directory is refused if it
exists and is not empty (``--force`` replaces the files).
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import json
import os
import re
import secrets
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from protocol.errors import FleetError
from protocol.keys import DEFAULT_PREFIX
from protocol.names import check_name

PORT = 7447
VALID_DAYS = 365
#: what may reach the daemon from each role (ingress), by message kind and key under the prefix
READ_QUERIES = ["robots", "world", "clock", "daemons", "daemons/*/clock"]
CONTROL_QUERIES = ["spawn", "delete", "sim/pause", "sim/resume", "sim/reset", "sim/step"]
SUBSCRIBE = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
#: every kind of message zenoh's access control tells apart
EVERYTHING = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply", "liveliness_token",
              "declare_liveliness_subscriber", "liveliness_query"]  # fmt: skip


class SecurityError(Exception):
    """A request fleet-security cannot carry out; the message is one line."""


def acl(prefix: str, drivers: Sequence[str], daemons: Sequence[str] = ()) -> dict[str, Any]:
    """The daemon's access control (or, for a fleet of ``daemons``, the router's): deny by
    default; each role's ingress allowed explicitly; everything the daemon itself sends
    (replies, topics, declarations) allowed out. Behind a router the daemons' users
    (``daemon_<id>``) may send and receive anything under the prefix: they answer the fleet's
    queries, publish its topics and its robots' tokens, and hear each other (spawn placement,
    ghosts, the one clock)."""
    p = prefix
    rules: list[dict[str, Any]] = [
        {"id": "out", "permission": "allow", "flows": ["egress"],
         "messages": ["put", "delete", "reply", "query", "declare_subscriber", "declare_queryable", "liveliness_token",
                      "declare_liveliness_subscriber", "liveliness_query"],
         "key_exprs": [f"{p}/**"]},
        {"id": "read", "permission": "allow", "flows": ["ingress"], "messages": ["query"],
         "key_exprs": [f"{p}/{k}" for k in READ_QUERIES]},
        {"id": "watch", "permission": "allow", "flows": ["ingress"], "messages": SUBSCRIBE, "key_exprs": [f"{p}/**"]},
        {"id": "control", "permission": "allow", "flows": ["ingress"], "messages": ["query"],
         "key_exprs": [f"{p}/{k}" for k in CONTROL_QUERIES]},
        {"id": "drive-any", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
         "key_exprs": [f"{p}/*/cmd_vel", f"{p}/commands"]},
        {"id": "presence", "permission": "allow", "flows": ["ingress"],
         "messages": ["declare_liveliness_subscriber", "liveliness_query"], "key_exprs": [f"{p}/*/alive"]},
    ]  # fmt: skip
    subjects: list[dict[str, Any]] = [
        {"id": "operator", "usernames": ["operator"]},
        {"id": "observer", "usernames": ["observer"]},
    ]
    policies: list[dict[str, Any]] = [
        {"id": "operator", "rules": ["out", "read", "watch", "control", "drive-any"], "subjects": ["operator"]},
        {"id": "observer", "rules": ["out", "read", "watch"], "subjects": ["observer"]},
    ]
    for ns in drivers:
        user = f"driver_{ns}"
        rules += [
            {"id": f"drive-{ns}", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
             "key_exprs": [f"{p}/{ns}/cmd_vel"]},
            {"id": f"watch-{ns}", "permission": "allow", "flows": ["ingress"], "messages": SUBSCRIBE,
             "key_exprs": [f"{p}/{ns}/**"]},
        ]  # fmt: skip
        subjects.append({"id": user, "usernames": [user]})
        policies.append({"id": user, "rules": ["out", "read", "presence", f"drive-{ns}", f"watch-{ns}"],
                         "subjects": [user]})  # fmt: skip
    if daemons:
        rules += [
            {"id": "daemon-in", "permission": "allow", "flows": ["ingress"], "messages": EVERYTHING,
             "key_exprs": [f"{p}/**"]},
            {"id": "daemon-out", "permission": "allow", "flows": ["egress"], "messages": EVERYTHING,
             "key_exprs": [f"{p}/**"]},
        ]  # fmt: skip
        subjects.append({"id": "daemons", "usernames": [f"daemon_{d}" for d in daemons]})
        policies.append({"id": "daemons", "rules": ["daemon-in", "daemon-out"], "subjects": ["daemons"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def _certificates(hosts: Sequence[str], common_name: str = "simd") -> tuple[bytes, bytes, bytes, bytes]:
    """(CA certificate, CA key, the server's certificate, its key), PEM: the server is the
    daemon, or the router of a fleet of daemons."""
    try:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
    except ImportError:
        raise SecurityError("the cryptography package is missing: pip install 'fleetsim[security]'") from None

    now = datetime.datetime.now(datetime.UTC)

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def pem_key(key: ec.EllipticCurvePrivateKey) -> bytes:
        return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                 serialization.NoEncryption())  # fmt: skip

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder()
        .subject_name(name("fleetsim local CA"))
        .issuer_name(name("fleetsim local CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                key_cert_sign=True,
                crl_sign=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(ca_key, hashes.SHA256())
    )
    names: list[x509.GeneralName] = []
    for h in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            names.append(x509.DNSName(h))
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (
        x509.CertificateBuilder()
        .subject_name(name(common_name))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    pem = serialization.Encoding.PEM
    return ca.public_bytes(pem), pem_key(ca_key), cert.public_bytes(pem), pem_key(key)


def _write(path: Path, data: bytes | str, private: bool = False) -> None:
    raw = data.encode() if isinstance(data, str) else data
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(raw)
    os.chmod(path, 0o600 if private else 0o644)


def _json5(obj: dict[str, Any], comment: str) -> str:
    return "".join(f"// {line}\n" for line in comment.splitlines()) + json.dumps(obj, indent=2) + "\n"


def init(directory: Path, robots: Sequence[str], hosts: Sequence[str], simd_dir: Path | None, port: int,
         prefix: str = DEFAULT_PREFIX, force: bool = False, daemons: Sequence[str] = ()) -> list[str]:  # fmt: skip
    """Write the files (see the module docstring); the users made. With ``daemons``, a fleet
    of daemons behind a router: the router's files instead of the daemon's, and one directory
    per daemon."""
    for ns in robots:
        check_name(ns, "robot namespace")
    for d in daemons:
        try:
            check_name(d, "daemon id")
        except FleetError as e:
            raise SecurityError(f"--daemons: {e.message}") from None
    if len(set(daemons)) != len(daemons):
        raise SecurityError("--daemons names a daemon twice")
    if not hosts:
        raise SecurityError("give at least one --host (the name or address clients connect to)")
    if directory.exists() and not directory.is_dir():
        raise SecurityError(f"{directory} exists and is not a directory")
    if directory.is_dir() and any(directory.iterdir()) and not force:
        raise SecurityError(f"{directory} is not empty: choose a new directory, or --force to replace its files")
    if not directory.parent.is_dir():
        raise SecurityError(f"{directory.parent} does not exist: create it first")
    # this machine's names too: simd's own healthcheck (and anyone on its host) connects through them
    server = "router" if daemons else "simd"  # who listens: the daemon, or the router of a fleet
    ca, ca_key, cert, key = _certificates(list(dict.fromkeys([*hosts, "localhost", "127.0.0.1"])),
                                          "fleet-router" if daemons else "simd")  # fmt: skip
    directory.mkdir(exist_ok=True)
    here = directory.resolve()
    server_dir = directory / server  # the server's own files, apart: they are all a container mounts
    server_dir.mkdir(exist_ok=True)
    where = (None if daemons else simd_dir) or server_dir.resolve()  # where it finds them (a container: its mount)
    users = ["operator", "observer", *(f"driver_{ns}" for ns in robots)]
    passwords = {u: secrets.token_urlsafe(18) for u in [*users, *(f"daemon_{d}" for d in daemons)]}
    _write(directory / "ca.pem", ca)
    _write(directory / "ca-key.pem", ca_key, private=True)
    _write(server_dir / "ca.pem", ca)
    _write(server_dir / f"{server}.pem", cert)
    _write(server_dir / f"{server}-key.pem", key, private=True)
    _write(server_dir / "users.txt", "".join(f"{u}:{pw}\n" for u, pw in passwords.items()), private=True)
    tls_server = {"root_ca_certificate": str(where / "ca.pem"), "listen_certificate": str(where / f"{server}.pem"),
                  "listen_private_key": str(where / f"{server}-key.pem")}  # fmt: skip
    listener = {
        "mode": "router" if daemons else "peer",
        "listen": {"endpoints": [f"tls/0.0.0.0:{port}"]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": tls_server}, "auth": {"usrpwd": {"dictionary_file": str(where / "users.txt")}}},
        "access_control": acl(prefix, robots, daemons),
    }
    how = "fleet-router -c router.json5" if daemons else "simd -c simd.json5"
    _write(server_dir / f"{server}.json5", _json5(listener, f"{how}: TLS on every link, user/password, access "
                                                  "control (made by fleet-security init)"), private=True)  # fmt: skip

    def client(user: str, ca_path: Path, endpoint: str) -> dict[str, Any]:
        return {
            "mode": "client",
            "connect": {"endpoints": [endpoint]},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {"link": {"tls": {"root_ca_certificate": str(ca_path)}},
                          "auth": {"usrpwd": {"user": user, "password": passwords[user]}}},
        }  # fmt: skip

    for u in users:
        conf = client(u, here / "ca.pem", f"tls/{hosts[0]}:{port}")
        _write(directory / f"{u}.json5", _json5(conf, f"fleetsim client as {u}: fleet -c {u}.json5 ..."), private=True)
    for d in daemons:  # each daemon a client of the router, as its own user
        mine = directory / f"simd_{d}"
        mine.mkdir(exist_ok=True)
        at = simd_dir or mine.resolve()
        _write(mine / "ca.pem", ca)
        conf = client(f"daemon_{d}", at / "ca.pem", f"tls/{hosts[0]}:{port}")
        said = f"simd -c simd.json5 --join --id {d}: daemon {d} of the fleet, through the router (fleet-security init)"
        _write(mine / "simd.json5", _json5(conf, said), private=True)
        health = client("observer", at / "ca.pem", f"tls/{hosts[0]}:{port}")
        _write(mine / "health.json5", _json5(health, f"daemon {d}'s healthcheck (SIMD_HEALTH_CONFIG, --id {d}): "
                                             "observer, through the router"), private=True)  # fmt: skip
    if not daemons:
        health = client("observer", where / "ca.pem", f"tls/localhost:{port}")
        _write(server_dir / "health.json5", _json5(health, "simd's healthcheck beside it (SIMD_HEALTH_CONFIG): "
                                                   "observer, through localhost"), private=True)  # fmt: skip
    return users


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fleet-security", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    i = sub.add_parser("init", help="make a CA, the daemon's certificate, users and zenoh configs in DIR")
    i.add_argument("directory", metavar="DIR", help="a new (or empty) directory")
    i.add_argument("--robots", default="", metavar="NS,...", help="one driver_<ns> user per robot namespace")
    i.add_argument("--host", action="append", metavar="NAME|IP",
                   help="name or address clients reach simd at; repeatable, the first goes into the client configs "
                        "(default: localhost, 127.0.0.1)")  # fmt: skip
    i.add_argument("--port", type=int, default=PORT, help=f"TLS port (default: {PORT})")
    i.add_argument("--prefix", default=DEFAULT_PREFIX, help="the fleet's key prefix (default: %(default)s)")
    i.add_argument("--simd-dir", metavar="PATH",
                   help="where simd will find DIR/simd, e.g. /security when it is mounted there in a container "
                        "(default: its absolute path)")  # fmt: skip
    i.add_argument("--daemons", default="", metavar="ID,...",
                   help="a fleet of daemons behind fleet-router (simd --join --id ID): the router's files and one "
                        "directory per daemon instead of the daemon's (docs/security.md)")  # fmt: skip
    i.add_argument("--force", action="store_true", help="replace the files of a non-empty DIR")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    robots = [r.strip().strip("/") for r in args.robots.split(",") if r.strip()]
    hosts = args.host or ["localhost", "127.0.0.1"]
    try:
        if not 0 < args.port < 65536:
            raise SecurityError(f"--port must be in 1..65535, got {args.port}")
        if not re.fullmatch(r"[A-Za-z0-9_]+", args.prefix):
            raise SecurityError(f"--prefix must be one key chunk of letters, digits and _, got {args.prefix!r}")
        simd_dir = Path(args.simd_dir) if args.simd_dir else None
        if simd_dir is not None and not simd_dir.is_absolute():
            raise SecurityError(f"--simd-dir must be an absolute path, got {args.simd_dir}")
        daemons = [x.strip() for x in args.daemons.split(",") if x.strip()]
        users = init(Path(args.directory), robots, hosts, simd_dir, args.port, args.prefix, args.force, daemons)
    except SecurityError as e:
        print(f"fleet-security: error: {e}", file=sys.stderr)
        return 2
    except FleetError as e:  # a robot name the fleet would refuse
        print(f"fleet-security: error: --robots: {e.message}", file=sys.stderr)
        return 2
    except OSError as e:  # a directory that cannot be made or written (read-only, full, /proc)
        print(f"fleet-security: error: {e.filename or args.directory}: {e.strerror or e}", file=sys.stderr)
        return 1
    d = args.directory
    server = "the router" if daemons else "simd"
    print(f"fleet-security: wrote a CA, {server}'s certificate for {', '.join(hosts)}, {len(users)} users and their "
          f"configs to {d}/")  # fmt: skip
    if daemons:
        print(f"  fleet-router -c {d}/router/router.json5")
        for i in daemons:
            print(f"  simd -c {d}/simd_{i}/simd.json5 --join --id {i}")
    else:
        print(f"  simd -c {d}/simd/simd.json5")
    print(f"  fleet -c {d}/operator.json5 spawn tb3_0 -2 -0.5        # operator: everything")
    print(f"  fleet-view -c {d}/observer.json5                       # observer: read only")
    for ns in robots:
        print(f"  fleet-teleop {ns} -c {d}/driver_{ns}.json5")
    own = (
        f"{d}/router/ is the router's alone, each {d}/simd_<id>/ its daemon's"
        if daemons
        else (f"{d}/simd/ is the daemon's alone")
    )
    print(
        f"  give each user ca.pem and their own .json5 (it holds their password); {own}, {d}/ca-key.pem best kept "
        "offline"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
