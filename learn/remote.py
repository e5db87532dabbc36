"""The environments' remote mode: a running simd in lockstep, stepped over Zenoh.

With ``endpoint=`` an environment drives a daemon instead of a fleet in its own process
(simd/engine/local.py), so that training can be watched in ``fleet-view`` or ROS tools. Both
are asked the same requests (learn/fleet.py); the environment owns the daemon's clock (each
reset resets the daemon's world, which reseeds its noise) and its robots, so that both modes
give the same episodes for the same seed. The checks here refuse a daemon that could not: one
in the wrong mode or world, one another environment drives already (two envs on one daemon
would reset each other's worlds: a vector env needs a daemon per env), or one with robots the
environment does not own (obstacles the in-process world would not have).

The environment that drives a daemon says so with the liveliness token ``P/@learner`` (a
verbatim chunk, which no robot key or wildcard matches); it goes with the environment's
session, so a crashed training run frees the daemon at once, and the robots it left (named as
this environment names its own) are taken back by the next one.
"""

from __future__ import annotations

from typing import Any

from clients.api import FleetClient
from protocol.control import Clock
from protocol.errors import FleetError

#: How long connecting, and then any one request, may take before the env gives up: seconds,
#: not the client's default, so that a wrong endpoint is reported while the user still waits.
REMOTE_TIMEOUT_S = 3.0


class RemoteFleet(FleetClient):
    """A client of a lockstep simd that one environment drives, and the robots it may call
    its own (``own``): a reset refuses anybody else's, closing takes its own away."""

    def __init__(self, endpoint: str, prefix: str, world: str, own: frozenset[str]) -> None:
        self.own = own
        self.endpoint = endpoint
        try:
            super().__init__(endpoint, prefix=prefix, timeout=REMOTE_TIMEOUT_S)
        except FleetError as e:
            why = e.message.split(": ", 1)[-1]
            if e.field == "connect":  # zenoh refuses a malformed endpoint before it tries it
                raise ConnectionError(f"cannot connect to {endpoint!r}: {why}") from None
            raise ConnectionError(f"no fleetsim daemon at {endpoint}: {why}") from None
        try:
            self._check(world)
            learner = f"{prefix}/@learner"
            if any(r.ok is not None for r in self.session.liveliness().get(learner, timeout=1.0)):
                raise ValueError(
                    f"another environment drives the daemon at {endpoint} already: one env a daemon "
                    "(a vector env needs a daemon for each env, or the in-process envs)"
                )
            self._token: Any = self.session.liveliness().declare_token(learner)
        except BaseException:
            super().close()
            raise

    def _check(self, world: str) -> None:
        """ConnectionError when nothing answers, ValueError when the daemon could not give the
        in-process episodes (not in lockstep, another world)."""
        try:
            clock = super().clock()
            there = self.world().name
        except FleetError as e:
            raise ConnectionError(f"no fleetsim daemon at {self.endpoint} (prefix {self.keys.prefix!r}): "
                                  f"{e.message}") from None  # fmt: skip
        if not clock.paused:
            raise ValueError(f"the daemon at {self.endpoint} must run in lockstep (simd --lockstep) or be paused")
        if there != world:
            raise ValueError(
                f"the daemon at {self.endpoint} runs world {there!r}, this env {world!r}: make them the same"
            )

    def reset(self, seed: int | None = None) -> Clock:
        """The daemon's world reset and reseeded, once it is known to hold none of anybody
        else's robots (ValueError naming them)."""
        foreign = sorted(r.name for r in self.robots() if r.name not in self.own)
        if foreign:
            raise ValueError(
                f"the daemon at {self.endpoint} has robots this environment does not own "
                f"({', '.join(foreign[:5])}{', ...' if len(foreign) > 5 else ''}): they would be obstacles "
                "the in-process world does not have; delete them (fleet delete NAME) or use a daemon of its own"
            )
        return super().reset(seed)

    def close(self) -> None:
        """Take this env's robots away and free the daemon for the next environment."""
        try:
            self.delete_many([r.name for r in self.robots() if r.name in self.own])
        except FleetError:
            pass  # the daemon went away first: nothing left to take
        finally:
            self._token.undeclare()
            super().close()
