"""The zenoh session through which the daemon joins a ROS 2 domain, configured as rmw_zenoh's peers.

An rmw_zenoh process opens a peer session that connects to the router (``rmw_zenohd`` on
``tcp/localhost:7447``), listens on a free local port, and learns the other peers' locators by
gossip (multicast scouting off), so data then flows peer to peer. The daemon does the same on a
session of its own, beside the fleet protocol's. With no ROS router around (a fleet driven by
ROS tools from elsewhere, or a test), ``serve`` makes that session the router itself.

A peer is reached at the addresses it listens on, which gossip hands to the others; a daemon in
a container listens on its own loopback, which no other peer reaches, and a router does not pass
data, tokens or queries between two peers (checked with zenoh 1.10). ``mode="client"`` then
makes the session a client of the router, which passes everything between its clients and its
peers (the router is on the data path, as for any client).

From rmw_zenoh's own configs (``config/DEFAULT_RMW_ZENOH_SESSION_CONFIG.json5`` and
``DEFAULT_RMW_ZENOH_ROUTER_CONFIG.json5``, jazzy 0.2.10) the built-in config takes what shapes
the session's behaviour towards the others: samples timestamped in every mode; a 60 s link lease
with two keep-alives in it (zenoh's default is 10 s; rmw_zenoh raised it so that links survive
many nodes starting at once), which is also how long a frozen daemon's tokens outlive it; as the
router, no failover brokering between peers. One thing it does not take: rmw_zenohd listens on
``tcp/[::]:7447``, every interface, while simd serves on ``--ros-router``'s endpoint, loopback
unless told otherwise, as every simd endpoint (docs/security.md: nothing answers the network by
default, and the ROS side has no authentication of its own).

The environment is read as rmw_zenoh reads it (``src/detail/zenoh_config.cpp``):
``ZENOH_SESSION_CONFIG_URI`` names a JSON5 file that replaces the session's config whole
(``ZENOH_ROUTER_CONFIG_URI`` with ``serve``, as for rmw_zenohd), and ``ZENOH_CONFIG_OVERRIDE``
(``key=value;key=value``, each value JSON5, split at its first ``=``) sets keys over that. So the
daemon joins a secured or remote ROS domain with the files its ROS processes use. The flags given
explicitly (``--ros-router``, ``--ros-mode``, ``--ros-serve-router``) apply over the file, the
overrides over both. rmw_zenoh skips an override it cannot apply with a warning; the daemon
refuses to start on it instead, as on any bad setting.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass

import zenoh

from fleetcommon.zenoh_config import config_error_text

DEFAULT_ROUTER = "tcp/localhost:7447"
SESSION_CONFIG_URI = "ZENOH_SESSION_CONFIG_URI"
ROUTER_CONFIG_URI = "ZENOH_ROUTER_CONFIG_URI"
CONFIG_OVERRIDE = "ZENOH_CONFIG_OVERRIDE"

#: rmw_zenoh's settings of the built-in config (key -> JSON5)
RMW_ZENOH_SETTINGS = {
    "timestamping/enabled": '{"router": true, "peer": true, "client": true}',
    "transport/link/tx/lease": "60000",
    "transport/link/tx/keep_alive": "2",
}


class RosConfigError(ValueError):
    """A ROS session setting that cannot be used; the message is one line for the user."""


@dataclass(frozen=True)
class RosSessionConfig:
    config: zenoh.Config
    #: the router's endpoint, joined or served (None: the config names none)
    router: str | None
    #: where the config came from, for the start-up line: the built-in one, or the environment's
    source: str
    mode: str  # peer, client or router


def ros_config(router: str = DEFAULT_ROUTER, *, serve: bool = False, mode: str = "peer") -> zenoh.Config:
    """The built-in config: an rmw_zenoh peer (or client) of ``router``, or with ``serve`` the router."""
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "true")
    if serve:
        conf.insert_json5("mode", json.dumps("router"))
        conf.insert_json5("listen/endpoints", json.dumps([router]))
        conf.insert_json5("routing/router/peers_failover_brokering", "false")  # as rmw_zenohd
    elif mode == "client":
        conf.insert_json5("mode", json.dumps("client"))
        conf.insert_json5("connect/endpoints", json.dumps([router]))
    else:
        conf.insert_json5("mode", json.dumps("peer"))
        conf.insert_json5("connect/endpoints", json.dumps([router]))
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/localhost:0"]))
    for key, value in RMW_ZENOH_SETTINGS.items():
        conf.insert_json5(key, value)
    # a tick's messages leave back to back: the fleet session's larger send queues (simd/daemon.py)
    conf.insert_json5("transport/link/tx/queue/size/data", "16")
    conf.insert_json5("transport/link/tx/queue/size/data_low", "16")
    # as rmw_zenoh's peers: keep retrying the router instead of failing when it starts later (and
    # a client too: a daemon in a container may well start before the router)
    conf.insert_json5("connect/timeout_ms", "-1")
    conf.insert_json5("connect/exit_on_failure", "false")
    return conf


def session_config(router: str | None, *, serve: bool = False, mode: str | None = None,
                   env: Mapping[str, str]) -> RosSessionConfig:  # fmt: skip
    """The ROS session's config: the environment's file or the built-in one, then the flags that
    were given (``router``, ``mode``: None when not), then the environment's overrides.
    RosConfigError for a file or an override that cannot be used."""
    variable = ROUTER_CONFIG_URI if serve else SESSION_CONFIG_URI
    path = env.get(variable, "")
    sources = []
    if path:
        conf = _from_file(variable, path)
        sources.append(f"{variable}={path}")
        if serve:
            conf.insert_json5("mode", json.dumps("router"))
        elif mode is not None:
            conf.insert_json5("mode", json.dumps(mode))
        if router is not None:
            conf.insert_json5("listen/endpoints" if serve else "connect/endpoints", json.dumps([router]))
    else:
        conf = ros_config(router or DEFAULT_ROUTER, serve=serve, mode=mode or "peer")
    overrides = env.get(CONFIG_OVERRIDE, "")
    if apply_overrides(conf, overrides):
        sources.append(f"{CONFIG_OVERRIDE}={overrides}")
    mode = str(_read(conf, "mode") or "peer")
    return RosSessionConfig(conf, _router_of(conf, serve, mode), ", ".join(sources) or "built-in", mode)


def apply_overrides(conf: zenoh.Config, overrides: str) -> list[str]:
    """Set ``key=value;key=value`` (``ZENOH_CONFIG_OVERRIDE``) on ``conf``, as rmw_zenoh does:
    pairs split at ``;``, each at its first ``=``, the value JSON5; empty pieces skipped. The
    keys set, or RosConfigError naming the first pair that is not a usable setting."""
    keys = []
    for pair in overrides.split(";"):
        if not pair:
            continue
        key, sep, value = pair.partition("=")
        if not (key and sep and value):
            raise RosConfigError(
                f"{CONFIG_OVERRIDE}: {pair!r} is not KEY=VALUE (pairs are separated by ';', "
                "e.g. 'transport/link/tx/lease=10000;scouting/multicast/enabled=false')"
            )
        try:
            conf.insert_json5(key, value)
        except (zenoh.ZError, ValueError) as e:
            raise RosConfigError(f"{CONFIG_OVERRIDE}: cannot set {key} to {value}: {config_error_text(e)}") from e
        keys.append(key)
    return keys


def _from_file(variable: str, path: str) -> zenoh.Config:
    try:
        return zenoh.Config.from_file(path)
    except (zenoh.ZError, ValueError, OSError) as e:
        raise RosConfigError(f"{variable}={path}: not a usable zenoh config file: {config_error_text(e)}") from e


def _read(conf: zenoh.Config, key: str) -> object:
    try:
        return json.loads(conf.get_json(key))
    except (zenoh.ZError, ValueError):
        return None


def _router_of(conf: zenoh.Config, serve: bool, mode: str) -> str | None:
    """The first endpoint the session listens on (serving) or connects to, in its mode."""
    endpoints = _read(conf, "listen/endpoints" if serve else "connect/endpoints")
    if isinstance(endpoints, dict):  # a list per mode
        endpoints = endpoints.get(mode)
    return str(endpoints[0]) if isinstance(endpoints, list) and endpoints else None
