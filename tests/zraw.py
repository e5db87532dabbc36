"""Raw zenoh sessions for tests: talk to the daemon the way zenoh's CLI or another language would."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import zenoh


def client_config(endpoint: str) -> zenoh.Config:
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    return c


@contextmanager
def raw_session(endpoint: str) -> Iterator[zenoh.Session]:
    s = zenoh.open(client_config(endpoint))
    try:
        yield s
    finally:
        s.close()


def get(
    session: zenoh.Session, selector: str, payload: bytes | None = None, timeout: float = 3.0
) -> tuple[bytes | None, bytes | None]:
    """(ok payload, error payload) of the first reply; (None, None) if nobody answered."""
    for r in session.get(selector, payload=payload, timeout=timeout):
        if r.ok is not None:
            return r.ok.payload.to_bytes(), None
        assert r.err is not None
        return None, r.err.payload.to_bytes()
    return None, None


def get_json(session: zenoh.Session, selector: str, body: Any = None) -> tuple[Any, Any]:
    """A JSON request as a person would send it with zenoh-cli; JSON replies decoded."""
    payload = json.dumps(body).encode() if body is not None else None
    ok, err = get(session, selector, payload)
    return (json.loads(ok) if ok is not None else None), (json.loads(err) if err is not None else None)


def matching(pub: zenoh.Publisher) -> bool:
    """Whether some subscriber matches ``pub`` (zenoh's stub types the status as a bool)."""
    return bool(pub.matching_status.matching)  # type: ignore[attr-defined]


def ignore_reply(reply: zenoh.Reply) -> None:
    """A query's reply handler for a requester that does not wait for the answer."""


class Collector:
    """Counts and keeps samples of a key expression (callback subscriber)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.samples: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, s: zenoh.Sample) -> None:
        with self.lock:
            self.samples.append((str(s.key_expr), s.payload.to_bytes()))

    def __len__(self) -> int:
        with self.lock:
            return len(self.samples)

    def key_set(self) -> set[str]:
        with self.lock:
            return {k for k, _ in self.samples}

    def clear(self) -> None:
        with self.lock:
            self.samples.clear()
