"""A fleet in this process: the engine's requests served on the caller's thread.

A learning environment steps a world thousands of times a second and wants no daemon, no
network and no thread of its own; it also wants to run the same episodes on a daemon, to be
watched. :class:`LocalFleet` is the part of ``clients.api.FleetClient`` such a program uses
(spawn, delete, list, reset, clock, and a step with packed observations), answered by an
:class:`~simd.engine.engine.Engine` in lockstep that no thread runs: each call is one typed
request (protocol/control.py) served at once by the engine's own handlers
(``Engine.serve_here``), so a step here and a step of ``simd --lockstep`` are the same code,
tick for tick and byte for byte. Refusals raise the same :class:`FleetError`.

What differs, on purpose: answers are the engine's values (``RobotState`` for a robot, where
the client decodes a ``RobotRecord``), since turning them into wire messages is the adapters'
business; and a step's observations come only packed (``packed=True``), the arrays a learner
reads, as the same ``StepReply`` the client returns (its arrays are views, not copies).

It also answers what only a local world can: whether a robot would fit at a pose
(:meth:`fits`, :meth:`touches`), which an environment asks while it draws starts and goals,
whichever fleet it drives.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import msgspec
import numpy as np
import numpy.typing as npt

from protocol.control import (
    Clock,
    ClockRequest,
    DeleteRequest,
    ListRequest,
    PackedCommands,
    PackedObservations,
    Request,
    ResetRequest,
    SpawnRequest,
    StepReply,
    StepRequest,
)
from protocol.errors import FleetError
from protocol.messages import Twist, Vector3
from simd.core.lidar import LidarSpec
from simd.core.mapworld import load_world_or_map
from simd.core.models import RobotModel
from simd.core.sim import SimConfig, Simulation
from simd.core.snapshot import RobotState
from simd.core.worldfile import WorldGeometry
from simd.engine.engine import Engine
from simd.engine.ports import ObservedArrays, Result, RobotList, StepResult


class LocalFleet:
    """A world and its robots in this process, asked as a daemon is asked (module docstring).

    ``world`` is a shipped world's name, a world or map file, or a loaded geometry.
    ``lidar_thread`` casts the scans beside the next tick's physics (the same scans, bit for
    bit). Commands hold until a step gives others (no watchdog: the caller steps the time)."""

    def __init__(
        self, world: str | WorldGeometry, *, lidar_noise: bool = True, lidar_thread: bool = True, seed: int = 0
    ) -> None:
        geometry = load_world_or_map(world) if isinstance(world, str) else world
        config = SimConfig(seed=seed, noise=lidar_noise, lidar_thread=lidar_thread, cmd_timeout=0)
        self._sim = Simulation(geometry, config)
        # no tick costs measured: nobody reads them here, and the process's CPU clock costs
        # a system call a tick (more, while the lidar thread runs)
        self._engine = Engine(self._sim, lockstep=True, cpu_clock=None)

    # -- what the world is --------------------------------------------------------------------

    @property
    def geometry(self) -> WorldGeometry:
        return self._sim.world

    @property
    def lidar(self) -> LidarSpec:
        return self._sim.config.lidar

    def __len__(self) -> int:
        return len(self._sim)

    def fits(self, model: str, x: float, y: float, yaw: float) -> bool:
        """Whether a robot of ``model`` could be spawned at this pose now: inside the world, on
        no wall and no robot (the spawn's own checks, as a ``SpawnRequest`` is judged)."""
        try:
            self._sim.validate_spawn(SpawnRequest(name="probe", model=model, x=x, y=y, yaw=yaw))
        except FleetError:
            return False
        return True

    def touches(self, model: RobotModel, x: float, y: float, yaw: float, static_only: bool = False) -> bool:
        """Whether the footprint at this pose overlaps a wall or obstacle, or (unless
        ``static_only``) a robot; the world's bounds are not asked."""
        hit = self._sim.physics.blocker(model, x, y, yaw)
        return hit == -1 if static_only else hit is not None

    # -- the requests -------------------------------------------------------------------------

    def _ask(self, request: Request) -> Result:
        answer = self._engine.serve_here(request)
        if isinstance(answer, FleetError):
            raise answer
        return answer

    def spawn(
        self,
        name: str,
        x: float = 0.0,
        y: float = 0.0,
        yaw: float = 0.0,
        *,
        model: str = "burger",
        namespace: str | None = None,
    ) -> RobotState:
        """Spawn a robot (FleetClient.spawn); its state. Raises FleetError if refused."""
        req = SpawnRequest(name=name, namespace=namespace, model=model, x=float(x), y=float(y), yaw=float(yaw))
        return self._robot(req)

    def spawn_many(self, robots: Iterable[SpawnRequest]) -> list[RobotState]:
        """Spawn these robots in this order; as FleetClient.spawn_many, every one is tried and
        the first refusal (naming its robot) raised afterwards, the others spawned."""
        requests = list(robots)
        for r in requests:
            if not isinstance(r, SpawnRequest):
                raise TypeError(f"spawn_many takes SpawnRequest(name=..., x=..., y=...) items, got {r!r}")
        return self._each(requests)

    def delete(self, name: str) -> RobotState:
        """Delete a robot by name or namespace; its last state."""
        return self._robot(DeleteRequest(name=name))

    def delete_many(self, names: Iterable[str]) -> list[RobotState]:
        """Delete these robots in this order, as FleetClient.delete_many: every one tried, the
        first refusal (naming its robot) raised afterwards, the others deleted; all at once
        (``Engine.delete_many_here``)."""
        listed = list(names)
        for n in listed:
            if not isinstance(n, str):
                raise TypeError(f"delete_many takes robot names, got {n!r}")
        gone, refusal = self._engine.delete_many_here(listed)
        if refusal is not None:
            raise refusal
        return gone

    def _robot(self, request: Request) -> RobotState:
        state = self._ask(request)
        assert isinstance(state, RobotState)
        return state

    def _each(self, requests: Sequence[SpawnRequest | DeleteRequest]) -> list[RobotState]:
        """Every request served in order; the first refusal raised at the end, naming its robot."""
        out: list[RobotState] = []
        refusal: FleetError | None = None
        for r in requests:
            try:
                out.append(self._robot(r))
            except FleetError as e:
                if refusal is None:
                    refusal = FleetError(e.code, f"{r.name}: {e.message}", e.field)
        if refusal is not None:
            raise refusal
        return out

    def robots(self) -> list[RobotState]:
        """Every robot, in spawn order."""
        listed = self._ask(ListRequest())
        assert isinstance(listed, RobotList)
        return listed.robots

    def clock(self) -> Clock:
        return self._clock(ClockRequest())

    def reset(self, seed: int | None = None) -> Clock:
        """Time to zero, every robot back to its spawn pose, the lidar noise reseeded."""
        return self._clock(ResetRequest(seed=seed))

    def _clock(self, request: Request) -> Clock:
        clock = self._ask(request)
        assert isinstance(clock, Clock)
        return clock

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
    ) -> StepReply:
        """Advance ``ticks`` ticks with these commands held, as FleetClient.step; the
        observations of ``observe`` come packed (``reply.packed``, read with
        ``clients.api.observed_arrays``). ``timeout`` and ``publish`` change nothing here
        (the step runs to its end on this thread; nobody is published to)."""
        watched = list(observe)
        if watched and not packed:
            raise ValueError("a local fleet gives its observations packed: step(..., packed=True)")
        if commands is not None and not cmd_vel:  # a learner's every step: the arrays as they are
            names, values = commands
            twist = np.array(values, _F8)
            if twist.shape != (len(names), 2):
                raise ValueError(f"commands: values must have shape ({len(names)}, 2), got {twist.shape}")
            req = StepRequest(ticks=ticks, observe=watched, publish=False, packed=packed)
            result = self._engine.step_here(req, list(names), twist)
        else:  # cmd_vel (or both, which the engine refuses): the request as a client sends it
            cmds = {ns: Twist(linear=Vector3(x=v), angular=Vector3(z=w)) for ns, (v, w) in (cmd_vel or {}).items()}
            arrays = None
            if commands is not None:
                names, values = commands
                arrays = PackedCommands(names=list(names), twist=np.asarray(values, dtype="<f8").tobytes())
            req = StepRequest(ticks=ticks, cmd_vel=cmds, commands=arrays, observe=watched, publish=False, packed=packed)
            answer = self._ask(req)
            assert isinstance(answer, StepResult)
            result = answer
        seen = None if result.packed is None else packed_observations(result.packed)
        return StepReply(
            **msgspec.structs.asdict(result.clock), ticks_run=result.ticks_run, cancelled=result.cancelled, packed=seen
        )

    def close(self) -> None:
        self._sim.close()

    def __enter__(self) -> LocalFleet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def packed_observations(seen: ObservedArrays) -> PackedObservations:
    """The engine's packed observations as the protocol's message, viewing its arrays (read
    only, as a decoded reply's are)."""
    return PackedObservations(
        names=seen.names,
        samples=seen.ranges.shape[1],
        odom=_bytes_of(seen.odom, _F8),
        scan_time=_bytes_of(seen.scan_time, _F8),
        ranges=_bytes_of(seen.ranges, _F4),
    )


_F8, _F4 = np.dtype("<f8"), np.dtype("<f4")


def _bytes_of(array: npt.NDArray[Any], dtype: np.dtype[Any]) -> memoryview:
    return np.ascontiguousarray(array, dtype).data.toreadonly().cast("B")
