"""Who serves the fleet: each daemon's liveliness token ``P/daemons/<id>`` and its answer on
``P/daemons``.

A daemon announces itself so that clients, routers and other daemons can see which daemons
serve a key space, and for how long (the token goes when the daemon does, however it dies).
Until daemons can share one fleet (issue "scale-out": spawns placed on one daemon, one list,
robots that see each other across daemons), two daemons on one key space would both answer
every spawn and each list only their own robots; a daemon therefore refuses to start where
another already serves its prefix, and says how to run beside it.
"""

from __future__ import annotations

import os
import socket
import time
from typing import Any

import zenoh

from protocol.control import DaemonInfo
from protocol.keys import Keys
from simd.adapters.fleet.requests import Pending, reply_format

#: how long a starting daemon looks for others (they answer in milliseconds on one network)
LOOK_S = 1.0


def serving(session: zenoh.Session, keys: Keys, timeout: float = LOOK_S) -> list[str]:
    """The ids of the daemons that serve ``keys``' prefix on this network now."""
    found = []
    head = keys.daemon("")
    for reply in session.liveliness().get(keys.daemon("*"), timeout=timeout):
        if reply.ok is not None:
            found.append(str(reply.ok.key_expr)[len(head) :])
    return sorted(found)


class Presence:
    """The daemon's token and its answer on ``P/daemons``, for as long as it runs."""

    def __init__(self, session: zenoh.Session, keys: Keys, daemon_id: str, world: str) -> None:
        self.info = DaemonInfo(
            id=daemon_id,
            world=world,
            host=socket.gethostname(),
            pid=os.getpid(),
            zid=str(session.zid()),
            started=time.time(),
        )
        self._token = session.liveliness().declare_token(keys.daemon(daemon_id))
        self._queryable: Any = session.declare_queryable(keys.daemons, self._on_query)
        self._key = keys.daemons

    def _on_query(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        fmt = reply_format(query, payload)
        Pending(query, self._key, fmt).ok(self.info)

    def close(self) -> None:
        self._queryable.undeclare()
        self._token.undeclare()
