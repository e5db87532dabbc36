"""The ROS session's config as rmw_zenoh's: the built-in one (rmw_zenoh's session and router
configs, jazzy 0.2.10), and ZENOH_SESSION_CONFIG_URI, ZENOH_ROUTER_CONFIG_URI and
ZENOH_CONFIG_OVERRIDE read as rmw_zenoh's zenoh_config.cpp reads them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import zenoh
import zenoh.ext

from simd.adapters import zenoh_entities
from simd.adapters.ros2 import session
from simd.adapters.ros2.session import RosConfigError, session_config

ROUTER = "tcp/127.0.0.1:7999"


def get(conf: zenoh.Config, key: str) -> Any:
    return json.loads(conf.get_json(key))


@pytest.mark.parametrize("mode", ["peer", "client", "router"])
def test_the_built_in_config_has_rmw_zenohs_timestamps_and_lease(mode: str) -> None:
    ros = session_config(ROUTER, serve=mode == "router", mode=None if mode == "router" else mode, env={})
    conf = ros.config
    assert get(conf, "mode") == mode
    assert get(conf, "timestamping/enabled") == {"router": True, "peer": True, "client": True}
    assert get(conf, "transport/link/tx/lease") == 60000
    assert get(conf, "transport/link/tx/keep_alive") == 2
    assert get(conf, "scouting/multicast/enabled") is False
    assert (ros.router, ros.source) == (ROUTER, "built-in")


def test_the_router_brokers_no_failover_and_listens_where_it_is_told() -> None:
    conf = session_config(None, serve=True, env={}).config
    assert get(conf, "routing/router/peers_failover_brokering") is False  # as rmw_zenohd
    assert get(conf, "listen/endpoints") == ["tcp/localhost:7447"]  # loopback: rmw_zenohd's is tcp/[::]:7447
    peer = session_config(None, env={}).config
    assert get(peer, "connect/endpoints") == ["tcp/localhost:7447"]
    assert get(peer, "listen/endpoints") == ["tcp/localhost:0"]


def _file(tmp_path: Path, text: str, name: str = "ros.json5") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_a_session_config_file_replaces_the_built_in_one(tmp_path: Path) -> None:
    path = _file(tmp_path, '{mode: "client", connect: {endpoints: ["tcp/10.1.2.3:7447"]}, '
                           "transport: {link: {tx: {lease: 12000}}}}")  # fmt: skip
    ros = session_config(None, env={session.SESSION_CONFIG_URI: path})
    assert get(ros.config, "mode") == "client"  # the file's, no --ros-mode given
    assert get(ros.config, "transport/link/tx/lease") == 12000
    assert get(ros.config, "timestamping/enabled") != {"router": True, "peer": True, "client": True}
    assert (ros.router, ros.source) == ("tcp/10.1.2.3:7447", f"ZENOH_SESSION_CONFIG_URI={path}")
    # flags given explicitly apply over the file
    ros = session_config(ROUTER, mode="peer", env={session.SESSION_CONFIG_URI: path})
    assert (get(ros.config, "mode"), get(ros.config, "connect/endpoints"), ros.router) == ("peer", [ROUTER], ROUTER)


def test_serving_reads_the_router_config_file_as_rmw_zenohd_does(tmp_path: Path) -> None:
    peer_file = _file(tmp_path, '{mode: "peer"}', "session.json5")
    router_file = _file(tmp_path, '{mode: "peer", listen: {endpoints: {router: ["tcp/127.0.0.1:7450"]}}}')
    env = {session.SESSION_CONFIG_URI: peer_file, session.ROUTER_CONFIG_URI: router_file}
    ros = session_config(None, serve=True, env=env)
    assert get(ros.config, "mode") == "router"  # --ros-serve-router says so
    assert ros.router == "tcp/127.0.0.1:7450"  # the per-mode list of the file
    assert ros.source == f"ZENOH_ROUTER_CONFIG_URI={router_file}"
    assert session_config(None, serve=True, env={session.SESSION_CONFIG_URI: peer_file}).source == "built-in"


def test_an_empty_variable_is_unset() -> None:
    ros = session_config(None, env={session.SESSION_CONFIG_URI: "", session.CONFIG_OVERRIDE: ""})
    assert ros.source == "built-in"


def test_overrides_apply_last_split_as_rmw_zenoh_splits_them(tmp_path: Path) -> None:
    path = _file(tmp_path, '{mode: "peer", connect: {endpoints: ["tcp/127.0.0.1:1"]}}')
    overrides = f'connect/endpoints=["{ROUTER}"];;transport/link/tx/lease=10000;metadata={{"a": "x=y"}};'
    ros = session_config(None, env={session.SESSION_CONFIG_URI: path, session.CONFIG_OVERRIDE: overrides})
    assert get(ros.config, "connect/endpoints") == [ROUTER]
    assert get(ros.config, "transport/link/tx/lease") == 10000
    assert get(ros.config, "metadata") == {"a": "x=y"}  # split at the first '=' only
    assert ros.router == ROUTER  # the endpoint the overrides set
    assert ros.source == f"ZENOH_SESSION_CONFIG_URI={path}, ZENOH_CONFIG_OVERRIDE={overrides}"
    built_in = session_config(ROUTER, serve=True, env={session.CONFIG_OVERRIDE: "transport/link/tx/lease=5000"})
    assert get(built_in.config, "transport/link/tx/lease") == 5000


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ("transport/link/tx/lease", "'transport/link/tx/lease' is not KEY=VALUE"),
        ("transport/link/tx/lease=", "is not KEY=VALUE"),
        ("=10000", "is not KEY=VALUE"),
        ("transport/link/tx/lease=soon", "ZENOH_CONFIG_OVERRIDE: cannot set transport/link/tx/lease to soon"),
        ("no/such/key=1", "ZENOH_CONFIG_OVERRIDE: cannot set no/such/key to 1"),
    ],
)
def test_a_bad_override_is_refused_with_one_line(overrides: str, message: str) -> None:
    with pytest.raises(RosConfigError) as e:
        session_config(None, env={session.CONFIG_OVERRIDE: overrides})
    assert message in str(e.value) and "\n" not in str(e.value)


def test_a_bad_config_file_is_refused_with_one_line(tmp_path: Path) -> None:
    for path in (str(tmp_path / "missing.json5"), _file(tmp_path, "{mode: ")):
        with pytest.raises(RosConfigError) as e:
            session_config(None, env={session.SESSION_CONFIG_URI: path})
        assert str(e.value).startswith(f"ZENOH_SESSION_CONFIG_URI={path}: not a usable zenoh config file")
        assert "\n" not in str(e.value)


def test_this_zenoh_has_what_simd_needs() -> None:
    assert zenoh_entities.missing_features() == []
    assert zenoh_entities.zenoh_too_old() is None


def test_an_older_zenoh_is_named_with_what_it_lacks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delattr(zenoh.ext, "declare_advanced_publisher")
    # zenoh's classes are immutable: a name it never had stands for a method an older one lacks
    features = (*zenoh_entities.REQUIRED_FEATURES, ("zenoh.Publisher", "nope"))
    monkeypatch.setattr(zenoh_entities, "REQUIRED_FEATURES", features)
    why = zenoh_entities.zenoh_too_old()
    assert why is not None and why.startswith("simd needs eclipse-zenoh >= 1.6.1")
    assert "without zenoh.ext.declare_advanced_publisher, zenoh.Publisher.nope)" in why


@pytest.mark.parametrize(("installed", "refused"), [("1.5.1", True), ("1.5.0", True), ("1.6.1", False),
                                                   ("1.10.2", False), ("2.0.0rc1", False), (None, False)])  # fmt: skip
def test_a_zenoh_with_every_name_but_older_than_the_floor_is_refused(
    monkeypatch: pytest.MonkeyPatch, installed: str | None, refused: bool
) -> None:
    """1.5.x has the names but loses samples through a router (MINIMUM_ZENOH says where it was seen)."""
    monkeypatch.setattr(zenoh_entities, "installed_zenoh", lambda: installed)
    why = zenoh_entities.zenoh_too_old()
    if refused:
        assert why == (f"simd needs eclipse-zenoh >= 1.6.1 ({installed} is installed, which loses samples through "
                       "a router): pip install 'eclipse-zenoh>=1.6.1,<2'")  # fmt: skip
    else:
        assert why is None


#: simd in its own process, on a zenoh whose zenoh.ext lacks the advanced publisher (as 1.0-1.4's)
OLD_ZENOH_SIMD = """
import sys, zenoh.ext
del zenoh.ext.declare_advanced_publisher
from simd.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("flags", [[], ["--ros2"]])
def test_simd_on_an_older_zenoh_stops_with_one_line(flags: list[str]) -> None:
    """Before it opens a session or binds a port, with or without --ros2 (the fleet topics'
    matching listeners need 1.5.0 too)."""
    done = subprocess.run([sys.executable, "-c", OLD_ZENOH_SIMD, *flags],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simd: error: simd needs eclipse-zenoh >= 1.6.1"), lines
    assert "declare_advanced_publisher" in lines[0]
