"""The environments' remote mode: a running simd in lockstep, stepped over Zenoh.

With ``endpoint=`` an environment drives a daemon instead of the core in its own process, so
that training can be watched in ``fleet-view`` or ROS tools. The environment owns the daemon's
clock (each reset resets the daemon's world, which reseeds its noise) and its robots, so that
both modes give the same episodes for the same seed. The checks here refuse a daemon that could
not: one in the wrong mode or world, one another environment drives already (two envs on one
daemon would reset each other's worlds: a vector env needs a daemon per env), or one with
robots the environment does not own (obstacles the in-process world would not have).

The environment that drives a daemon says so with the liveliness token ``P/@learner`` (a
verbatim chunk, which no robot key or wildcard matches); it goes with the environment's
session, so a crashed training run frees the daemon at once, and the robots it left (named as
this environment names its own) are taken back by the next one.
"""

from __future__ import annotations

from typing import Any

from clients.api import FleetClient
from fleetcommon.zenoh_config import zenoh_error_text
from protocol.errors import FleetError

#: How long connecting, and then any one request, may take before the env gives up: seconds,
#: not the client's default, so that a wrong endpoint is reported while the user still waits.
REMOTE_TIMEOUT_S = 3.0


class Daemon:
    """A lockstep simd that one environment drives, and the robots it may call its own."""

    def __init__(self, endpoint: str, prefix: str, world: str, own: frozenset[str]) -> None:
        self.own = own
        self.client = connect(endpoint, prefix, world)
        try:
            learner = f"{prefix}/@learner"
            if any(r.ok is not None for r in self.client.session.liveliness().get(learner, timeout=1.0)):
                raise ValueError(
                    f"another environment drives the daemon at {endpoint} already: one env a daemon "
                    "(a vector env needs a daemon for each env, or the in-process envs)"
                )
            self._token: Any = self.client.session.liveliness().declare_token(learner)
        except BaseException:
            self.client.close()
            raise
        self.endpoint = endpoint

    def reset(self, noise_seed: int) -> None:
        """The daemon's world reset and reseeded, with none of this env's robots left in it,
        and none of anybody else's (ValueError naming them)."""
        foreign = sorted(r.name for r in self.client.robots() if r.name not in self.own)
        if foreign:
            raise ValueError(
                f"the daemon at {self.endpoint} has robots this environment does not own "
                f"({', '.join(foreign[:5])}{', ...' if len(foreign) > 5 else ''}): they would be obstacles "
                "the in-process world does not have; delete them (fleet delete NAME) or use a daemon of its own"
            )
        self.client.reset(noise_seed)
        self.remove_own()

    def remove_own(self) -> None:
        """This env's robots out of the daemon's world, in the order they are listed (the
        order the in-process world removes them in)."""
        self.client.delete_many([r.name for r in self.client.robots() if r.name in self.own])

    def close(self) -> None:
        """Take this env's robots away and free the daemon for the next environment."""
        try:
            self.remove_own()
        except FleetError:
            pass  # the daemon went away first: nothing left to take
        finally:
            self._token.undeclare()
            self.client.close()


def connect(endpoint: str, prefix: str, world: str) -> FleetClient:
    """A client of the daemon at ``endpoint``, once it is known to be a lockstep (or paused)
    simd running ``world``. ConnectionError when nothing answers or the endpoint is malformed,
    ValueError when the daemon could not give the in-process episodes."""
    try:
        client = FleetClient(endpoint, prefix=prefix, timeout=REMOTE_TIMEOUT_S)
    except FleetError as e:
        raise ConnectionError(f"no fleetsim daemon at {endpoint}: {e.message.split(': ', 1)[-1]}") from None
    except Exception as e:  # zenoh refuses a malformed endpoint before it tries it
        raise ConnectionError(f"cannot connect to {endpoint!r}: {zenoh_error_text(e)}") from None
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
