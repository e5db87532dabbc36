"""What an environment drives: a fleet in this process or a daemon's, asked the same way.

Both environments (learn/navigate.py, learn/navigate_fleet.py) spawn their robots, step them
with their observations packed in the step's reply, delete them and reset the world through
the requests of the fleet protocol, answered either by the engine in this process
(:class:`~simd.engine.local.LocalFleet`) or by a lockstep simd over Zenoh
(:class:`~learn.remote.RemoteFleet`, a ``FleetClient``). One code path for both: what makes
the episodes equal is that they are the same requests, served by the same engine.

Starts and goals are drawn where a robot fits, which only a world in this process can say
quickly: a remote environment keeps an empty local fleet of the same world for that (its
``places``); a local one asks the fleet it drives.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Protocol

import numpy.typing as npt

from learn.remote import RemoteFleet
from protocol.control import SpawnRequest, StepReply
from simd.engine.local import LocalFleet


class Named(Protocol):
    @property
    def name(self) -> str: ...


class Fleet(Protocol):
    """The requests an environment makes (``FleetClient``'s names and arguments)."""

    def spawn(
        self, name: str, x: float = 0.0, y: float = 0.0, yaw: float = 0.0, *, model: str = "burger",
        namespace: str | None = None,
    ) -> Named: ...  # fmt: skip

    def spawn_many(self, robots: Iterable[SpawnRequest]) -> Sequence[Named]: ...

    def delete_many(self, names: Iterable[str]) -> Sequence[Named]: ...

    def robots(self) -> Sequence[Named]: ...

    def reset(self, seed: int | None = None) -> object: ...

    def step(
        self,
        ticks: int = 1,
        cmd_vel: dict[str, tuple[float, float]] | None = None,
        timeout: float | None = None,
        *,
        observe: Iterable[str] = (),
        publish: bool = True,
        packed: bool = False,
        commands: tuple[list[str], npt.ArrayLike] | None = None,
    ) -> StepReply: ...

    def close(self) -> None: ...


def open_fleet(
    world: str, own: Iterable[str], *, lidar_noise: bool, lidar_thread: bool, endpoint: str | None, prefix: str
) -> tuple[Fleet, LocalFleet]:
    """The fleet an environment drives (in this process, or the daemon at ``endpoint``, which
    must run the same world in lockstep), and the local world it asks where robots fit."""
    places = LocalFleet(world, lidar_noise=lidar_noise, lidar_thread=lidar_thread)
    if endpoint is None:
        return places, places
    try:
        return RemoteFleet(endpoint, prefix, places.geometry.name, frozenset(own)), places
    except BaseException:
        places.close()
        raise


def remove_own(fleet: Fleet, own: frozenset[str] | set[str]) -> None:
    """The environment's robots out of the fleet's world, in the order they are listed (the
    order a local fleet removes them in); a remote one may hold those of an environment that
    crashed."""
    fleet.delete_many([r.name for r in fleet.robots() if r.name in own])
