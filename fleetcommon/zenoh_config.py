"""The zenoh flags every fleetsim program takes, and the session config they build.

Same spelling as zenoh's own tools: ``-m/--mode``, ``-l/--listen``, ``-e/--connect``,
``-c/--config``, ``--cfg KEY:VALUE``. Multicast scouting is off unless asked for: it is on
by default in zenoh, fails silently on loopback-only hosts, and would send traffic out of
every interface.
"""

from __future__ import annotations

import argparse
import json
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import zenoh

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: A lost connection is retried every quarter second at first and at least once a second (zenoh:
#: 1 s, doubling up to 4 s), so that a client finds a restarted daemon within about a second.
RECONNECT_DEFAULTS = {
    "connect/retry": '{"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}',
}


@dataclass
class ZenohOptions:
    mode: str
    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)
    config_file: str | None = None
    cfg: list[str] = field(default_factory=list)
    multicast_scouting: bool = False

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> ZenohOptions:
        """The flags' options; the mode is ``-m``'s, else the config file's own, else the
        program's default (a daemon made a client of a router by its file stays one)."""
        mode = str(args.mode or _file_mode(args.config) or getattr(args, "zenoh_default_mode", "client"))
        return cls(
            mode=mode,
            listen=list(args.listen or []),
            connect=list(args.connect or []),
            config_file=args.config,
            cfg=list(args.cfg or []),
            multicast_scouting=args.multicast_scouting,
        )

    def endpoints(self) -> str:
        """The endpoints in use, for messages (a config file's own when no flag gives them)."""
        if self.connect or self.listen:
            return ", ".join(self.connect or self.listen)
        found = self._from_file("connect/endpoints") or self._from_file("listen/endpoints")
        if isinstance(found, dict):  # per-mode lists
            found = found.get(self.mode) or []
        return ", ".join(str(e) for e in found) if isinstance(found, list) and found else "(from the config file)"

    def user(self) -> str | None:
        """The user/password authentication's user of the config file, if it has one."""
        user = self._from_file("transport/auth/usrpwd/user")
        return user if isinstance(user, str) else None

    def no_answer_hint(self) -> str:
        """Why nobody may have answered, for messages: with a secured config, access control
        refuses what a user may not do by not passing the request on at all."""
        user = self.user()
        if user is None:
            return "start one with: simd"
        return (f"is simd running there? If it is, its access control does not let user {user!r} do this "
                "(see docs/security.md)")  # fmt: skip

    def _from_file(self, key: str) -> object:
        if not self.config_file:
            return None
        import zenoh

        try:
            return json.loads(zenoh.Config.from_file(self.config_file).get_json(key))
        except (zenoh.ZError, ValueError):
            return None

    def build(self, defaults: dict[str, str] | None = None) -> zenoh.Config:
        """The session config: file, then flags; ``defaults`` (key -> JSON5) apply only
        without a config file, and ``--cfg`` overrides them. A bad endpoint, file or
        ``--cfg`` raises ValueError with zenoh's complaint in one line (zenoh's own error
        carries the Rust source path it came from)."""
        import zenoh

        try:
            return self._build(defaults)
        except zenoh.ZError as e:
            raise ValueError(config_error_text(e)) from None

    def _build(self, defaults: dict[str, str] | None) -> zenoh.Config:
        import zenoh

        try:
            conf = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
        except zenoh.ZError as e:  # (zenoh's says what is wrong, not with which file)
            raise ValueError(f"{self.config_file}: {config_error_text(e)}") from None
        conf.insert_json5("mode", json.dumps(self.mode))
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(self.listen))
        elif not self.config_file:
            conf.insert_json5("listen/endpoints", "[]")
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(self.connect))
        if not self.config_file or self.multicast_scouting:
            enabled = "true" if self.multicast_scouting else "false"
            conf.insert_json5("scouting/multicast/enabled", enabled)
        if not self.config_file:
            for key, value in {**RECONNECT_DEFAULTS, **(defaults or {})}.items():
                conf.insert_json5(key, value)
        for item in self.cfg:
            key, sep, value = item.partition(":")
            if not sep:
                raise ValueError(f"--cfg expects KEY:VALUE (VALUE in JSON5), got {item!r}")
            try:
                conf.insert_json5(key, value)
            except zenoh.ZError as e:
                raise ValueError(f"--cfg {key}: {config_error_text(e)}") from None
        return conf


def _file_mode(config_file: str | None) -> str | None:
    """The ``mode`` a zenoh config file sets, if it can be read and sets one."""
    if not config_file:
        return None
    import zenoh

    try:
        mode = json.loads(zenoh.Config.from_file(config_file).get_json("mode"))
    except (zenoh.ZError, ValueError):
        return None
    return mode if mode in ("peer", "client", "router") else None


def _loopback(endpoint: str) -> bool:
    """Whether ``proto/host:port`` only accepts connections from this machine."""
    import ipaddress

    host = endpoint.partition("/")[2].rpartition(":")[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: assume it reaches beyond this machine


def exposed_without_authentication(conf: zenoh.Config, mode: str) -> list[str]:
    """The listening endpoints that other machines can reach when the config authenticates
    nobody (no user/password dictionary, no mutual TLS): anyone there could drive the fleet."""

    def read(key: str) -> object:
        try:
            return json.loads(conf.get_json(key))
        except ValueError:
            return None

    if read("transport/auth/usrpwd/dictionary_file") or read("transport/link/tls/enable_mtls") is True:
        return []
    listen = read("listen/endpoints")
    if isinstance(listen, dict):
        listen = listen.get(mode) or []
    return [str(e) for e in listen or [] if not _loopback(str(e))] if isinstance(listen, list) else []


def add_zenoh_args(parser: argparse.ArgumentParser, *, server: bool, default_mode: str | None = None) -> None:
    """Add the zenoh flags. A server (simd) listens by default; a client connects."""
    g = parser.add_argument_group("zenoh")
    mode = default_mode or ("peer" if server else "client")
    parser.set_defaults(zenoh_default_mode=mode)
    g.add_argument(
        "-m",
        "--mode",
        choices=("peer", "client", "router"),
        default=None,
        help=f"zenoh session mode (default: {mode}, or the -c file's own)",
    )
    if server:
        g.add_argument(
            "-l",
            "--listen",
            action="append",
            metavar="ENDPOINT",
            help=f"endpoint to listen on, repeatable (default: {DEFAULT_ENDPOINT}; "
            "use tcp/0.0.0.0:7447 to accept other hosts)",
        )
        g.add_argument(
            "-e",
            "--connect",
            action="append",
            metavar="ENDPOINT",
            help="endpoint to connect to, e.g. a zenoh router (repeatable)",
        )
    else:
        g.add_argument(
            "-e",
            "--connect",
            action="append",
            metavar="ENDPOINT",
            help=f"endpoint of the daemon or a router (default: {DEFAULT_ENDPOINT})",
        )
        g.add_argument(
            "-l",
            "--listen",
            action="append",
            metavar="ENDPOINT",
            help="endpoint to listen on (peer mode only)",
        )
    g.add_argument("-c", "--config", metavar="FILE", help="zenoh JSON5 configuration file")
    g.add_argument(
        "--cfg",
        action="append",
        metavar="KEY:VALUE",
        help="set a zenoh config key to a JSON5 value, e.g. --cfg 'transport/shared_memory/enabled:false'",
    )
    g.add_argument(
        "--multicast-scouting",
        action="store_true",
        help="enable zenoh multicast scouting (off by default)",
    )


def options_from_args(args: argparse.Namespace, *, server: bool) -> ZenohOptions:
    opts = ZenohOptions.from_args(args)
    if not opts.config_file:
        if server and not opts.listen and opts.mode != "client":  # a client connects: it has nothing to listen on
            opts.listen = [DEFAULT_ENDPOINT]
        if not server and not opts.connect:
            opts.connect = [DEFAULT_ENDPOINT]
    return opts


def zenoh_error_text(e: BaseException) -> str:
    """What a zenoh error says, for a one-line message: without the Rust source locations
    (`` at /path/to/file.rs:NN``) and the JSON5 wrapper around a config error's message."""
    msg = str(e).strip().strip("'")
    found = re.search(r'msg: "(.*?)"', msg)
    if found:
        msg = found.group(1)
    msg = re.sub(r"\s+at /\S*?\.rs:\d+\.?", "", msg)
    return msg.strip() or type(e).__name__


def config_error_text(e: BaseException) -> str:
    """A zenoh config error in one line: a JSON5 error's message and place without its drawing
    (``--> 1:1 | 1 | soon | ^--- | = expected array, ...``), a key's error without ``Str("...")``."""
    lines = [line.strip() for line in zenoh_error_text(e).replace("\\n", "\n").splitlines()]
    place = next((line.removeprefix("--> ") for line in lines if line.startswith("--> ")), None)
    said = next((line.removeprefix("= ") for line in lines if line.startswith("= ")), None)
    if said is not None:
        return f"{said} (line:column {place})" if place else said
    text = " ".join(line for line in lines if line)
    quoted = re.fullmatch(r'Str\("(.*)"\)', text)
    return quoted.group(1) if quoted else text
