"""Property-based fuzzing of every key the daemon listens on, in both encodings.

Hypothesis draws a key (every queryable, a robot's ``cmd_vel`` and a ghost's, ``commands``) and a body:
random bytes, or a JSON / MessagePack document built from the protocol's own field names with
values of every type, nested, huge, non-finite or invalid UTF-8. After each one: the daemon is
alive; a query got an answer, and an error answer is structured (a known code, never
``internal``); a refused request left the world as it was. At the end, no traceback in the
log. ``FLEETSIM_FUZZ_EXAMPLES`` sets how many bodies are tried (the CI run: 300, about 20 s;
the soak script runs it longer).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from typing import Any

import msgspec
import pytest
import zenoh
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from clients import FleetClient
from protocol.errors import ErrorCode
from tests.conftest import Daemon, start_daemon
from tests.daemon.test_bad_input import decode_reply, world_state
from tests.zraw import get, raw_session

EXAMPLES = int(os.environ.get("FLEETSIM_FUZZ_EXAMPLES", "300"))
QUERY_KEYS = ["spawn", "delete", "robots", "world", "clock", "sim/pause", "sim/resume", "sim/reset", "sim/step"]
PUT_KEYS = ["tb3_0/cmd_vel", "ghost/cmd_vel", "commands"]
#: the protocol's field names, so that documents reach past "unknown field" into the decoders
FIELDS = ["name", "namespace", "model", "x", "y", "yaw", "ticks", "seed", "cmd_vel", "observe", "linear", "angular",
          "z", "format", "robots", "tb3_0", "names", "after", "limit", "twist", "commands"]  # fmt: skip
KNOWN_CODES = {c.value for c in ErrorCode} - {ErrorCode.INTERNAL.value}

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -0.0, 0.0, 0.22, 1_000_000, 10**6 + 1]),
    st.text(max_size=80),
    st.sampled_from(["burger", "waffle", "waffle_pi", "tb3_0", "**", "a/b", "spawn"]),
    st.integers(min_value=60, max_value=5000).map(lambda n: "x" * n),
)
documents = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=6),
        st.dictionaries(st.one_of(st.sampled_from(FIELDS), st.text(max_size=10)), inner, max_size=6),
    ),
    max_leaves=30,
)


def _deep(depth: int, json_: bool) -> bytes:
    if json_:
        return b'{"name":' + b"[" * depth + b"]" * depth + b"}"
    return b"\x81\xa4name" + b"\x91" * depth + b"\xc0"


def _encode(doc: Any, how: str) -> bytes:
    if how == "json":
        return json.dumps(doc, allow_nan=True).encode()
    return msgspec.msgpack.encode(doc)


bodies = st.one_of(
    st.binary(max_size=300),
    st.tuples(documents, st.sampled_from(["json", "msgpack"])).map(lambda d: _encode(*d)),
    st.tuples(st.integers(min_value=100, max_value=100_000), st.booleans()).map(lambda d: _deep(*d)),
    st.sampled_from([b'{"name": "\xff\xfe"}', b'{"\xff": 1}', b"", b"{", b"\xc1", b"\x81\xa4name\xdb\xff\xff\xff\xff"]),
)


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Daemon, FleetClient, zenoh.Session]]:
    d = start_daemon(tmp_path_factory.mktemp("fuzz"), "--lockstep")
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    with raw_session(d.endpoint) as s:
        yield d, c, s
    d.stop()
    assert "Traceback" not in d.log(), d.log()[-3000:]


def _state(c: FleetClient) -> tuple[Any, ...]:
    clock = c.clock()
    return tuple(world_state(c)), clock.tick, clock.paused


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
          HealthCheck.too_slow, HealthCheck.data_too_large])  # fmt: skip
@given(key=st.sampled_from(QUERY_KEYS), body=bodies, as_json=st.booleans())
def test_every_query_body_gets_an_answer_and_a_refusal_changes_nothing(
    fuzzed: tuple[Daemon, FleetClient, zenoh.Session], key: str, body: bytes, as_json: bool
) -> None:
    d, c, s = fuzzed
    before = _state(c)
    ok, err = get(s, f"fleet/{key}" + ("?format=json" if as_json else ""), body, 10.0)
    assert d.alive(), d.log()[-3000:]
    assert ok is not None or err is not None, f"no answer on {key} to {body[:80]!r}"
    if err is not None:
        reply = decode_reply(err)
        assert reply["code"] in KNOWN_CODES, reply
        assert _state(c) == before, (key, body[:80], reply)
        event(f"{key}: {reply['code']}")
        return
    assert ok is not None
    event(f"{key}: answered")
    if key == "spawn":  # a body that happened to be a valid spawn: take the robot away again
        c.delete(msgspec.json.decode(ok)["name"] if ok[:1] == b"{" else msgspec.msgpack.decode(ok)["name"])


@settings(max_examples=EXAMPLES // 2, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
          HealthCheck.too_slow, HealthCheck.data_too_large])  # fmt: skip
@given(key=st.sampled_from(PUT_KEYS), body=bodies)
def test_every_put_body_leaves_the_daemon_serving(
    fuzzed: tuple[Daemon, FleetClient, zenoh.Session], key: str, body: bytes
) -> None:
    d, c, s = fuzzed
    s.put(f"fleet/{key}", body)
    c.step(1)  # served after the put was taken in
    assert d.alive(), d.log()[-3000:]
    assert [r.name for r in c.robots()] == ["tb3_0"]
