"""The environments' remote mode: a running simd in lockstep, stepped over Zenoh.

With ``endpoint=`` an environment drives a daemon instead of the core in its own process, so
that training can be watched in ``fleet-view`` or ROS tools. The environment owns the daemon's
clock: each reset resets the daemon's world (which reseeds its noise). Both modes give the same
episodes for the same seed; the checks here refuse a daemon that could not.
"""

from __future__ import annotations

from clients.api import FleetClient
from protocol.errors import FleetError

#: How long connecting, and then any one request, may take before the env gives up: seconds,
#: not the client's default, so that a wrong endpoint is reported while the user still waits.
REMOTE_TIMEOUT_S = 3.0


def connect(endpoint: str, prefix: str, world: str) -> FleetClient:
    """A client of the daemon at ``endpoint``, once it is known to be a lockstep (or paused)
    simd running ``world``. ConnectionError when nothing answers, ValueError when it could not
    give the in-process episodes."""
    try:
        client = FleetClient(endpoint, prefix=prefix, timeout=REMOTE_TIMEOUT_S)
    except FleetError as e:
        raise ConnectionError(f"no fleetsim daemon at {endpoint}: {e.message}") from None
    try:
        clock = client.clock()
        there = client.world().name
    except FleetError as e:
        client.close()
        raise ConnectionError(f"no fleetsim daemon at {endpoint} (prefix {prefix!r}): {e.message}") from None
    if not clock.paused:
        client.close()
        raise ValueError(f"the daemon at {endpoint} must run in lockstep (simd --lockstep) or be paused")
    if there != world:
        client.close()
        raise ValueError(f"the daemon at {endpoint} runs world {there!r}, this env {world!r}: make them the same")
    return client
