"""The zenoh flags every fleetsim program takes, and the session config they build.

Same spelling as zenoh's own tools: ``-m/--mode``, ``-l/--listen``, ``-e/--connect``,
``-c/--config``, ``--cfg KEY:VALUE``. Multicast scouting is off unless asked for: it is on
by default in zenoh, fails silently on loopback-only hosts, and would send traffic out of
every interface.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import zenoh

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


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
        return cls(
            mode=args.mode,
            listen=list(args.listen or []),
            connect=list(args.connect or []),
            config_file=args.config,
            cfg=list(args.cfg or []),
            multicast_scouting=args.multicast_scouting,
        )

    def endpoints(self) -> str:
        """The endpoints in use, for messages."""
        return ", ".join(self.connect or self.listen) or "(from the config file)"

    def build(self, defaults: dict[str, str] | None = None) -> zenoh.Config:
        """The session config: file, then flags; ``defaults`` (key -> JSON5) apply only
        without a config file, and ``--cfg`` overrides them."""
        import zenoh

        conf = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
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
            for key, value in (defaults or {}).items():
                conf.insert_json5(key, value)
        for item in self.cfg:
            key, sep, value = item.partition(":")
            if not sep:
                raise ValueError(f"--cfg expects KEY:VALUE (VALUE in JSON5), got {item!r}")
            conf.insert_json5(key, value)
        return conf


def add_zenoh_args(parser: argparse.ArgumentParser, *, server: bool, default_mode: str | None = None) -> None:
    """Add the zenoh flags. A server (simd) listens by default; a client connects."""
    g = parser.add_argument_group("zenoh")
    g.add_argument(
        "-m",
        "--mode",
        choices=("peer", "client", "router"),
        default=default_mode or ("peer" if server else "client"),
        help="zenoh session mode (default: %(default)s)",
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
        if server and not opts.listen:
            opts.listen = [DEFAULT_ENDPOINT]
        if not server and not opts.connect:
            opts.connect = [DEFAULT_ENDPOINT]
    return opts
