"""Every input key gets bad input: each is refused with a structured error (or, for
cmd_vel, dropped and counted), the world is unchanged and the daemon stays alive."""

from __future__ import annotations

import json
import math
from typing import Any

import msgspec
import pytest
import zenoh

from clients import FleetClient, wait_until
from tests.conftest import Daemon
from tests.zraw import get, get_json, ignore_reply, matching, raw_session

LONG = "x" * 65
SPAWN_CASES: list[tuple[str, bytes | None, str]] = [
    # (case, payload, expected error code)
    ("garbage", b"\x00\xffnot a message", "malformed"),
    ("truncated json", b'{"name": "a", "x": ', "malformed"),
    ("json array", b'["a", 1, 2]', "malformed"),
    ("json string", b'"tb3_0"', "malformed"),
    ("empty", None, "malformed"),
    ("empty object", b"{}", "malformed"),
    ("name wrong type", b'{"name": 7}', "malformed"),
    ("x wrong type", b'{"name": "a", "x": "far"}', "malformed"),
    ("x null", b'{"name": "a", "x": null}', "malformed"),
    ("nested garbage", b'{"name": {"first": "a"}}', "malformed"),
    (
        "msgpack positional",
        msgspec.msgpack.encode(["a", None, "burger", 0.0, 0.0, 0.0]),
        "malformed",
    ),
    ("msgpack nan", msgspec.msgpack.encode({"name": "a", "x": math.nan}), "non_finite"),
    ("msgpack inf", msgspec.msgpack.encode({"name": "a", "y": math.inf}), "non_finite"),
    ("msgpack -inf yaw", msgspec.msgpack.encode({"name": "a", "yaw": -math.inf}), "non_finite"),
    ("huge x", b'{"name": "a", "x": 1e308}', "out_of_bounds"),
    ("huge int x", b'{"name": "a", "x": 100000000000000000000}', "out_of_bounds"),
    ("outside the world", b'{"name": "a", "x": 10, "y": 0}', "out_of_bounds"),
    ("inside a pillar", b'{"name": "a", "x": 1.1, "y": 1.1}', "collision"),
    ("inside the outer wall", b'{"name": "a", "x": 0, "y": 2.7}', "collision"),
    ("inside a hexagon", b'{"name": "a", "x": 3.0, "y": 0.0}', "collision"),
    ("on another robot", b'{"name": "a", "x": -1.95, "y": -0.5}', "collision"),
    ("slash", b'{"name": "a/b"}', "invalid_name"),
    ("star", b'{"name": "a*"}', "invalid_name"),
    ("double star", b'{"name": "**"}', "invalid_name"),
    ("dollar", b'{"name": "$*"}', "invalid_name"),
    ("question mark", b'{"name": "a?x=1"}', "invalid_name"),
    ("hash", b'{"name": "a#"}', "invalid_name"),
    ("space", b'{"name": "tb3 0"}', "invalid_name"),
    ("newline", b'{"name": "tb3\\n0"}', "invalid_name"),
    ("unicode", '{"name": "robot_é"}'.encode(), "invalid_name"),
    ("cjk", '{"name": "机器人"}'.encode(), "invalid_name"),
    ("empty name", b'{"name": ""}', "invalid_name"),
    ("leading digit", b'{"name": "0tb3"}', "invalid_name"),
    ("too long", json.dumps({"name": LONG}).encode(), "invalid_name"),
    ("dot", b'{"name": "."}', "invalid_name"),
    ("reserved spawn", b'{"name": "spawn"}', "reserved_name"),
    ("reserved sim", b'{"name": "sim"}', "reserved_name"),
    ("reserved fleet topic", b'{"name": "ok", "namespace": "odometry"}', "reserved_name"),
    ("reserved namespace", b'{"name": "ok", "namespace": "world"}', "reserved_name"),
    ("bad namespace", b'{"name": "ok", "namespace": "a/b"}', "invalid_name"),
    ("duplicate name", b'{"name": "tb3_0", "x": 0.5, "y": -2}', "already_exists"),
    (
        "duplicate namespace",
        b'{"name": "other", "namespace": "tb3_0", "x": 0.5, "y": -2}',
        "already_exists",
    ),
    ("name equals a namespace", b'{"name": "ns_of_b", "x": 0.5, "y": -2}', "already_exists"),
    ("unknown model", b'{"name": "a", "model": "waffle_pi2", "x": 0.5, "y": -2}', "unknown_model"),
    ("model wrong type", b'{"name": "a", "model": 3}', "malformed"),
]


def decode_reply(raw: bytes) -> dict[str, Any]:
    """Replies mirror the request's encoding: JSON for JSON, MessagePack otherwise."""
    out: dict[str, Any] = json.loads(raw) if raw[:1] == b"{" else msgspec.msgpack.decode(raw)
    return out


def world_state(c: FleetClient) -> list[tuple[str, str, str, float, float, float]]:
    return [(r.name, r.namespace, r.model, r.pose.x, r.pose.y, r.pose.yaw) for r in c.robots()]


@pytest.fixture
def populated(daemon_factory: Any) -> tuple[Daemon, FleetClient]:
    d = daemon_factory("--lockstep")  # nothing moves between checks: "unchanged" is exact
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("b", 0.5, -2.0, namespace="ns_of_b")
    return d, c


def test_every_bad_spawn_is_refused_with_a_structured_error(
    populated: tuple[Daemon, FleetClient],
) -> None:
    d, c = populated
    before = world_state(c)
    failures = []
    with raw_session(d.endpoint) as s:
        for case, payload, code in SPAWN_CASES:
            ok, err = get(s, "fleet/spawn", payload)
            if ok is not None or err is None:
                failures.append(f"{case}: accepted or unanswered ({ok!r})")
                continue
            reply = decode_reply(err)
            if reply.get("code") != code or not reply.get("message"):
                failures.append(f"{case}: got {reply}, wanted {code}")
    assert not failures, "\n".join(failures)
    assert d.alive()
    assert world_state(c) == before
    assert c.alive() == ["ns_of_b", "tb3_0"]


def test_errors_come_back_in_the_request_encoding(populated: tuple[Daemon, FleetClient]) -> None:
    d, _ = populated
    with raw_session(d.endpoint) as s:
        _, err_json = get(s, "fleet/spawn", b'{"name": "a b"}')
        _, err_mp = get(s, "fleet/spawn", msgspec.msgpack.encode({"name": "a b"}))
    assert err_json is not None and json.loads(err_json)["code"] == "invalid_name"
    assert err_mp is not None and msgspec.msgpack.decode(err_mp)["code"] == "invalid_name"
    assert json.loads(err_json)["field"] == "name"


@pytest.mark.parametrize(
    ("key", "payload", "code"),
    [
        ("fleet/delete", None, "malformed"),
        ("fleet/delete", b'{"name": 3}', "malformed"),
        ("fleet/delete", b'{"name": "nobody"}', "not_found"),
        ("fleet/delete", b'{"name": "*"}', "not_found"),
        ("fleet/delete", b"\xc1", "malformed"),
        ("fleet/sim/step", b'{"ticks": 0}', "invalid_value"),
        ("fleet/sim/step", b'{"ticks": -5}', "invalid_value"),
        ("fleet/sim/step", b'{"ticks": 100000000000}', "invalid_value"),
        ("fleet/sim/step", b'{"ticks": "many"}', "malformed"),
        ("fleet/sim/step", b'{"ticks": 1.5}', "malformed"),
        (
            "fleet/sim/step",
            msgspec.msgpack.encode({"ticks": 1, "cmd_vel": {"tb3_0": {"linear": {"x": math.nan}}}}),
            "non_finite",
        ),
        (
            "fleet/sim/step",
            b'{"ticks": 1, "cmd_vel": {"ghost": {"linear": {"x": 0.1}}}}',
            "not_found",
        ),
        ("fleet/sim/reset", b'{"seed": -1}', "invalid_value"),
        ("fleet/sim/reset", b'{"seed": "abc"}', "malformed"),
        ("fleet/sim/resume", None, "not_allowed"),
    ],
)
def test_bad_control_requests(
    populated: tuple[Daemon, FleetClient], key: str, payload: bytes | None, code: str
) -> None:
    d, c = populated
    before = world_state(c)
    tick = c.clock().tick
    with raw_session(d.endpoint) as s:
        ok, err = get(s, key, payload)
    assert ok is None and err is not None
    assert decode_reply(err)["code"] == code
    assert world_state(c) == before
    assert c.clock().tick == tick
    assert d.alive()


def test_bad_cmd_vel_is_dropped_and_counted(populated: tuple[Daemon, FleetClient]) -> None:
    d, c = populated
    before = world_state(c)
    bad = [
        b"garbage",
        b'{"linear": {"x": "fast"}}',
        b'{"linear": 5}',
        b"[0.1, 0.2]",
        msgspec.msgpack.encode({"linear": {"x": math.nan}}),
        msgspec.msgpack.encode({"angular": {"z": math.inf}}),
        msgspec.msgpack.encode({"linear": {"x": -math.inf}}),
        b"\xc1\xc1",
    ]
    with raw_session(d.endpoint) as s:
        for p in bad:
            s.put("fleet/tb3_0/cmd_vel", p)
        s.put("fleet/*/cmd_vel", b'{"linear": {"x": 0.2}}')  # a wildcard put reaches us literally
        s.put("fleet/**/cmd_vel", b'{"linear": {"x": 0.2}}')
        assert wait_until(lambda: c.clock().dropped_commands >= len(bad) + 1, 3.0)
        c.step(30)
    assert world_state(c) == before  # nothing moved
    assert d.alive()


def test_huge_cmd_vel_is_clamped_to_the_model_limit(populated: tuple[Daemon, FleetClient]) -> None:
    _, c = populated
    # the left rim needs 0.447 m/s: 14 ramp updates, inside the 15-tick watchdog
    c.step(14, cmd_vel={"tb3_0": (1e300, -1e300)})
    r = c.robot("tb3_0")
    assert r is not None
    assert r.linear_velocity == pytest.approx(0.22) and r.angular_velocity == pytest.approx(-2.84)


def test_cmd_vel_for_unknown_or_invalid_namespaces_is_harmless(
    populated: tuple[Daemon, FleetClient],
) -> None:
    d, c = populated
    before = world_state(c)
    with raw_session(d.endpoint) as s:
        for key in (
            "fleet/ghost/cmd_vel",
            "fleet/spawn/cmd_vel",
            "fleet/a b/cmd_vel",
            "fleet/é/cmd_vel",
        ):
            s.put(key, b'{"linear": {"x": 0.2}}')
    c.step(10)
    assert world_state(c) == before
    assert d.alive()


def test_floods_leave_the_daemon_serving(populated: tuple[Daemon, FleetClient]) -> None:
    d, c = populated
    before = world_state(c)
    answered = 0
    with raw_session(d.endpoint) as s:
        for i in range(3000):  # cmd_vel flood, good and bad mixed
            s.put("fleet/tb3_0/cmd_vel", b"junk" if i % 2 else b'{"linear": {"x": 0.0}}')
        done: list[int] = []

        def on_reply(r: zenoh.Reply) -> None:
            done.append(1)

        for i in range(500):  # concurrent bad spawn queries
            s.get(
                "fleet/spawn",
                zenoh.handlers.Callback(on_reply),
                payload=b'{"name": "bad name %d"}' % i,
                timeout=10,
            )
        assert wait_until(lambda: len(done) >= 500, 15.0)
        answered = len(done)
    assert answered == 500
    assert world_state(c) == before
    assert c.clock().robots == 2
    assert d.alive()


def test_daemon_keeps_serving_after_a_client_vanishes_mid_request(
    populated: tuple[Daemon, FleetClient],
) -> None:
    d, c = populated
    with raw_session(d.endpoint) as s:
        s.get("fleet/sim/step", ignore_reply, payload=b'{"ticks": 300}', timeout=5)
    # the requester is gone; the step still completes and the daemon answers others
    assert wait_until(lambda: c.clock().tick >= 300, 10.0)
    assert d.alive()
    assert c.robots()


# -- one packet must not kill, reset or freeze the daemon -------------------------------------

DEEP_MSGPACK = b"\x81\xa1x" + b"\x91" * 1000 + b"\xc0"  # {"x": [[[...nil...]]]}, 1 000 deep
HOSTILE_BODIES = [
    ("msgpack nested 1 000 deep", DEEP_MSGPACK),
    ("msgpack nested 100 000 deep", b"\x81\xa1x" + b"\x91" * 100_000 + b"\xc0"),
    ("json nested 1 000 deep", b'{"x":' + b"[" * 1000 + b"]" * 1000 + b"}"),
    ("json nested 100 000 deep", b'{"x":' + b"[" * 100_000 + b"]" * 100_000 + b"}"),
    # in the fields the requests read (unknown fields are skipped unread, as for any message)
    ("invalid utf-8 in json", b'{"name": "\xff\xfe", "ticks": "\xff", "seed": "\xff"}'),
    ("invalid utf-8 in a json key", b'{"\xff": 1}'),
    ("5 MB of json", b'{"name": "' + b"a" * (5 << 20) + b'"}'),
    ("a huge array", msgspec.msgpack.encode({"name": "a", "x": list(range(100_000))})),
]


# a Twist skips fields it does not know without looking inside them: these are bad in its own
HOSTILE_TWISTS = [
    *HOSTILE_BODIES[:4],
    HOSTILE_BODIES[6],
    ("invalid utf-8 where a number goes", b'{"linear": {"x": "\xff\xfe"}}'),
    ("a huge array where a number goes", msgspec.msgpack.encode({"linear": {"x": list(range(100_000))}})),
]


@pytest.mark.parametrize(("case", "body"), HOSTILE_TWISTS, ids=[c for c, _ in HOSTILE_TWISTS])
def test_hostile_cmd_vel_is_dropped_and_the_daemon_lives(
    populated: tuple[Daemon, FleetClient], case: str, body: bytes
) -> None:
    d, c = populated
    before = world_state(c)
    dropped = c.clock().dropped_commands
    with raw_session(d.endpoint) as s:
        # BLOCK: a loaded machine must not drop the test's own (fragmented, 100 kB) puts
        block = zenoh.CongestionControl.BLOCK
        keys = ("fleet/tb3_0/cmd_vel", "fleet/ghost/cmd_vel")
        pubs = [s.declare_publisher(k, congestion_control=block) for k in keys]
        # a session a moment old may not know the daemon's subscriber yet, and drop a put
        assert wait_until(lambda: all(matching(p) for p in pubs), 5.0)
        for p in pubs:  # (the second for a robot that does not exist)
            p.put(body)
        assert wait_until(lambda: c.clock().dropped_commands >= dropped + 2, 5.0), case
    c.step(3)
    assert d.alive() and world_state(c) == before
    assert "Traceback" not in d.log()


QUERY_CASES = [
    (key, case, body)
    for key in ("fleet/spawn", "fleet/delete", "fleet/sim/step", "fleet/sim/reset", "fleet/robots")
    for case, body in HOSTILE_BODIES[::2] + HOSTILE_BODIES[1:5:2]
    if not (key == "fleet/robots" and "utf-8" in case)  # a list reads names, after and limit only
]

#: bodies that are bad in the fields a list request reads (protocol/listing.py), and the code
LIST_CASES = [
    ("invalid utf-8 in names", b'{"names": ["\xff\xfe"]}', "malformed"),
    ("invalid utf-8 in after", b'{"after": "\xff", "limit": 3}', "malformed"),
    ("names a string", b'{"names": "tb3_0"}', "malformed"),
    ("a limit not a number", b'{"limit": [1]}', "malformed"),
    ("a negative limit", b'{"limit": -5}', "invalid_value"),
    ("a limit past 64 bits", b'{"limit": 18446744073709551616}', "invalid_value"),
    ("100 001 names", msgspec.msgpack.encode({"names": [f"r{i}" for i in range(100_001)]}), "invalid_value"),
    ("a wildcard for a name", b'{"names": ["*"]}', "invalid_name"),
]


def _refused(populated: tuple[Daemon, FleetClient], key: str, body: bytes) -> dict[str, Any]:
    """The error reply to ``body`` on ``key``, once the daemon is seen alive, unchanged and
    without a traceback in its log."""
    d, c = populated
    before = world_state(c)
    with raw_session(d.endpoint) as s:
        ok, err = get(s, key, body, 10.0)
    assert ok is None and err is not None
    assert d.alive() and world_state(c) == before
    assert "Traceback" not in d.log()
    return decode_reply(err)


@pytest.mark.parametrize(("case", "body", "code"), LIST_CASES, ids=[c for c, _, _ in LIST_CASES])
def test_a_bad_list_request_is_refused_saying_why(
    populated: tuple[Daemon, FleetClient], case: str, body: bytes, code: str
) -> None:
    reply = _refused(populated, "fleet/robots", body)
    assert reply["code"] == code, (case, reply)


@pytest.mark.parametrize(("key", "case", "body"), QUERY_CASES, ids=[f"{k} {c}" for k, c, _ in QUERY_CASES])
def test_hostile_query_bodies_get_a_structured_error_not_an_internal_one(
    populated: tuple[Daemon, FleetClient], key: str, case: str, body: bytes
) -> None:
    reply = _refused(populated, key, body)
    assert reply["code"] in ("malformed", "too_large") and "internal" not in reply["message"], (case, reply)


def test_a_wildcard_get_reads_and_never_acts(daemon_factory: Any) -> None:
    """``get fleet/**`` (or ``fleet/sim/*``) with a body each action would accept: the
    read-only keys answer, no action runs."""
    d = daemon_factory("--world", "empty")
    c = d.client()
    c.spawn("a", 0.0, 0.0)
    c.drive("a", 0.2, 0.0)
    assert wait_until(lambda: c.clock().tick > 30, 5.0)
    body = b'{"name": "intruder", "ticks": 5, "seed": 3}'
    with raw_session(d.endpoint) as s:
        keys = set()
        for selector in ("fleet/**", "fleet/sim/*", "fleet/*", "**"):
            for r in s.get(selector, payload=body, timeout=3.0):
                if r.ok is not None:
                    keys.add(str(r.ok.key_expr))
    clock = c.clock()
    assert not clock.paused and clock.tick > 30  # neither paused nor reset
    assert [r.name for r in c.robots()] == ["a"]  # nobody spawned, nobody deleted
    assert {"fleet/robots", "fleet/world", "fleet/clock", "fleet/a/odom"} <= keys
    assert not keys & {"fleet/spawn", "fleet/delete", "fleet/sim/pause", "fleet/sim/reset", "fleet/sim/step"}


def test_a_huge_step_freezes_nothing_and_a_pause_cancels_it(daemon_factory: Any) -> None:
    d = daemon_factory("--lockstep", "--world", "empty")
    c = d.client()
    c.spawn("a", 0.0, 0.0)
    done: list[bytes] = []

    def on_reply(r: zenoh.Reply) -> None:
        done.append(r.ok.payload.to_bytes() if r.ok is not None else b"error")

    with raw_session(d.endpoint) as s:
        s.get("fleet/sim/step?format=json", on_reply, payload=b'{"ticks": 1000000}', timeout=60)
        assert wait_until(lambda: c.clock().tick > 0, 5.0)
        first = c.clock().tick
        c.spawn("b", 2.0, 0.0)  # served between two slices of the step
        assert wait_until(lambda: c.clock().tick > first, 5.0)  # and the step goes on
        c.drive("b", 0.1, 0.0)
        paused = c.pause()
        assert wait_until(lambda: bool(done), 5.0)
    reply = json.loads(done[0])
    assert reply["cancelled"] is True and 0 < reply["ticks_run"] < 1_000_000
    assert reply["tick"] == reply["ticks_run"] == paused.tick == c.clock().tick  # the step stopped there
    assert [r.name for r in c.robots()] == ["a", "b"]
    assert d.alive()


def test_packed_commands_that_do_not_add_up_are_refused(daemon_factory: Any) -> None:
    """JSON requests, as a person (or a client in another language) would send them: the
    arrays travel as base64."""
    import base64

    d = daemon_factory("--lockstep", "--world", "empty")
    c = d.client()
    c.spawn("a", 0.0, 0.0)
    eight = base64.b64encode(bytes(8)).decode()
    sixteen = base64.b64encode(bytes(16)).decode()
    short = {"ticks": 3, "commands": {"names": ["a"], "twist": eight}}
    both = {"ticks": 3, "cmd_vel": {"a": {}}, "commands": {"names": ["a"], "twist": sixteen}}
    not_base64 = {"ticks": 3, "commands": {"names": ["a"], "twist": "%%%"}}
    with raw_session(d.endpoint) as s:
        for body, words in (
            (short, "2 float64 for each of the 1 names, got 8 bytes"),
            (both, "not both"),
            (not_base64, "base64"),
        ):
            ok, err = get_json(s, "fleet/sim/step", body)
            assert ok is None and err is not None and words in err["message"], err
        ok, _ = get_json(s, "fleet/sim/step", {"ticks": 3, "commands": {"names": ["a"], "twist": sixteen}})
        assert ok is not None and ok["ticks_run"] == 3
