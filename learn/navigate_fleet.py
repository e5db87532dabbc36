"""``FleetNavigateEnv``: N TurtleBot3s in one world, each driving to its own goal (PettingZoo).

The multi-robot form of ``fleetsim/Navigate-v0`` (learn/navigate.py): the same observation,
action, reward and step (0.2 s, one lidar period) for every agent, on one simulation core in
this process. The robots see each other in their scans and can collide with each other; an
agent leaves the episode (and the world: its robot is removed) when it reaches its goal or
collides, and all leave at ``max_steps``.

Every step is one ``sim/step`` request for every agent, their observations packed as arrays in
its reply, served by the engine in this process (simd/engine/local.py) or, with ``endpoint=``,
by a simd in lockstep (learn/fleet.py): the same episodes either way, and ``publish=False``
when nobody watches the daemon, so that large fleets step fast.

The agents' state is kept in arrays, a row per agent, and every step is computed for the whole
fleet in a few numpy passes: a thousand agents step about as fast as the core moves them.

    from learn.navigate_fleet import FleetNavigateEnv
    env = FleetNavigateEnv(robots=4)
    observations, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        observations, rewards, terminations, truncations, infos = env.step(actions)
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from pettingzoo import ParallelEnv

from clients.api import observed_arrays
from fleetcommon.arrays import F32
from learn.fleet import open_fleet, remove_own
from learn.task import (
    ARRIVAL_REWARD,
    COLLISION_REWARD,
    GOAL_RADIUS,
    PROGRESS_REWARD,
    KeepClear,
    check_settings,
    collided_many,
    command_many,
    drivable,
    footprint_ranges,
    free_pose,
    observe_many,
    spaces_for,
)
from protocol.control import SpawnRequest

TICKS_A_STEP = 6
#: the most agents one env takes (a daemon's default robot limit is 5 000)
MAX_AGENTS = 1000
#: a placement that finds no free place in this many draws starts over; after this many such
#: dead ends the world is taken to be too small for the fleet
DRAWS_A_PLACE = 2000
PLACE_TRIES = 50


class _NoPlace(Exception):
    """The starts and goals drawn so far leave no place for the next."""


class FleetNavigateEnv(ParallelEnv[str, F32, Any]):  # type: ignore[misc]  # pettingzoo has no type information
    """See the module docstring."""

    metadata = {"name": "fleetsim_navigate_fleet_v0", "render_modes": ["rgb_array"], "render_fps": 5}  # noqa: RUF012

    def __init__(
        self,
        robots: int = 4,
        world: str = "turtlebot3_world",
        model: str = "burger",
        beams: int = 24,
        discrete: bool = False,
        max_steps: int = 500,
        lidar_noise: bool = True,
        render_mode: str | None = None,
        endpoint: str | None = None,
        prefix: str = "fleet",
        publish: bool = True,
    ) -> None:
        if not 1 <= robots <= MAX_AGENTS:
            raise ValueError(f"robots must be in 1..{MAX_AGENTS}, got {robots}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
        self.model = check_settings(model, beams, max_steps)
        self.beams = beams
        self.discrete = discrete
        self.max_steps = max_steps
        self.render_mode = render_mode
        self.possible_agents = [f"tb3_{i}" for i in range(robots)]
        self._own = frozenset(self.possible_agents)
        #: the fleet the robots drive in, and the world asked where they fit (the same, in process)
        self.fleet, self.places = open_fleet(
            world, self._own, lidar_noise=lidar_noise, lidar_thread=True, endpoint=endpoint, prefix=prefix
        )
        self.publish = publish
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self.agents: list[str] = []
        self._live = np.zeros(0, dtype=np.int64)  # the agents' rows, in their order
        self._agent_set: set[str] = set()
        found = spaces_for(self.model, beams, self.places.geometry, discrete)
        self._obs_space: spaces.Space[Any] = found.observation
        self._act_space = found.action
        self._low, self._high = found.low, found.high
        self._range_max = self.places.lidar.range_max
        self._footprint = footprint_ranges(self.model, self.places.lidar.samples)
        self.region = drivable(self.places.geometry, self.model)  # where starts and goals are drawn
        self._rng = np.random.default_rng()
        self._scans: F32 = np.zeros((0, self.places.lidar.samples), dtype=np.float32)  # of the last step, live rows
        # a row per possible agent
        self._pose = np.zeros((robots, 3))
        self._velocity = np.zeros((robots, 2))
        self._goal = np.zeros((robots, 2))
        self._distance = np.zeros(robots)
        self._command = np.zeros((robots, 2))  # held until an agent's next action
        self._goal_tuples: list[tuple[float, float]] = []
        self.steps = 0

    @property
    def goals(self) -> dict[str, tuple[float, float]]:
        """Each agent's goal (x, y)."""
        return {a: (float(g[0]), float(g[1])) for a, g in zip(self.possible_agents, self._goal.tolist(), strict=True)}

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self._act_space

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, F32], dict[str, dict[str, Any]]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        noise_seed = int(self._rng.integers(2**31))
        self.fleet.reset(noise_seed)
        self._remove_all()
        dead_ends = 0
        for _ in range(100):
            try:
                if self._place():
                    break
            except _NoPlace:  # the places drawn so far leave none for the next: draw them all anew
                dead_ends += 1
                if dead_ends == PLACE_TRIES:
                    self._remove_all()
                    raise RuntimeError(
                        f"no free place for {len(self.possible_agents)} robots and their goals in "
                        f"{self.places.geometry.name!r} (each a metre from the others) in {PLACE_TRIES} tries: "
                        "ask for fewer robots or a larger world"
                    ) from None
            self._remove_all()
        else:
            raise RuntimeError(
                f"no room for {len(self.possible_agents)} robots in {self.places.geometry.name!r}: every try "
                "left two robots touching; ask for fewer robots or a larger world"
            )
        self.agents = list(self.possible_agents)
        self._live = live = np.arange(len(self.agents))
        self._agent_set = set(self.agents)
        self._command[:] = 0.0
        self.steps = 0
        obs, distance = self._look(live)
        self._distance[live] = distance
        infos = self._infos(live, distance)
        return dict(zip(self.agents, obs, strict=True)), {a: infos[k] for k, a in enumerate(self.agents)}

    def _place(self) -> bool:
        """Every robot at a free start with its goal; False if one starts in contact."""
        taken = KeepClear()
        starts = []
        for a in self.possible_agents:
            x, y, yaw = self._free_pose(taken)
            starts.append(SpawnRequest(name=a, model=self.model.name, x=x, y=y, yaw=yaw))
            taken.add(x, y)
        self.fleet.spawn_many(starts)  # in this order: the fleet's rows, and with them the scan phases
        for i in range(len(self.possible_agents)):
            gx, gy, _ = self._free_pose(taken)
            self._goal[i] = (gx, gy)
            taken.add(gx, gy)
        self._goal_tuples = [(float(x), float(y)) for x, y in self._goal.tolist()]
        self._command[:] = 0.0
        self._scans = self._advance(np.arange(len(self.possible_agents)), self.possible_agents)[2]
        return not bool(np.any(collided_many(self._scans, self._footprint)))

    def _free_pose(self, taken: KeepClear) -> tuple[float, float, float]:
        try:
            return free_pose(self.places, self.model, self._rng, taken, self.region, tries=DRAWS_A_PLACE)
        except RuntimeError:
            raise _NoPlace from None

    def _remove_all(self) -> None:
        """Every robot of this env out of the world."""
        remove_own(self.fleet, self._own)

    def step(self, actions: dict[str, Any]) -> tuple[
        dict[str, F32], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]
    ]:  # fmt: skip
        if not actions.keys() <= self._agent_set:
            unknown = sorted(set(actions) - self._agent_set)
            raise ValueError(f"actions for agents not in the episode: {unknown} (live: {self.agents})")
        if not self.agents:  # everybody has left: nothing moves, nothing to report (PettingZoo's convention)
            return {}, {}, {}, {}, {}
        names = list(actions)
        try:
            commands = command_many([actions[a] for a in names], self.model, self.discrete)
        except ValueError as e:  # "action 3: ..." -> the agent's name
            where, _, why = str(e).partition(": ")
            raise ValueError(
                f"{names[int(where.split()[-1])]}: {why}" if where.startswith("action ") else str(e)
            ) from None
        if names == self.agents:  # the usual: every agent acts, in the agents' order
            self._command[self._live] = commands
        elif names:
            self._command[[self._index[a] for a in names]] = commands
        agents, live = self.agents, self._live
        pose, velocity, scans = self._advance(live, agents)
        self.steps += 1
        goal = self._goal[live]
        distance = np.hypot(goal[:, 0] - pose[:, 0], goal[:, 1] - pose[:, 1])
        arrived = distance < GOAL_RADIUS
        crashed = collided_many(scans, self._footprint)
        goals = self._goal_tuples
        together = zip(pose.tolist(), live.tolist(), distance.tolist(), arrived.tolist(), crashed.tolist(), strict=True)
        infos = [
            {"pose": (p[0], p[1], p[2]), "goal": goals[i], "distance": x, "arrived": a, "collided": c}
            for p, i, x, a, c in together
        ]
        obs = observe_many(pose, velocity, goal, scans, self.beams, self._range_max, self._low, self._high)
        reward = PROGRESS_REWARD * (self._distance[live] - distance)
        reward += np.where(arrived, ARRIVAL_REWARD, np.where(crashed, COLLISION_REWARD, 0.0))
        self._distance[live] = distance
        done = arrived | crashed
        out_of_time = ~done & (self.steps >= self.max_steps)
        done_l, late_l = done.tolist(), out_of_time.tolist()
        result = (
            dict(zip(agents, obs, strict=True)),
            dict(zip(agents, reward.tolist(), strict=True)),
            dict(zip(agents, done_l, strict=True)),
            dict(zip(agents, late_l, strict=True)),
            dict(zip(agents, infos, strict=True)),
        )
        leaving = [a for k, a in enumerate(agents) if done_l[k] or late_l[k]]
        if leaving:  # it leaves the episode, and the world
            self.fleet.delete_many(leaving)
            gone = set(leaving)
            self.agents = [a for a in agents if a not in gone]
            self._live = np.array([self._index[a] for a in self.agents], dtype=np.int64)
            self._agent_set = set(self.agents)
        return result

    def render(self) -> Any:
        from learn.picture import top_down

        if self.render_mode != "rgb_array":
            return None
        here = [(a, self.model, tuple(self._pose[self._index[a]].tolist())) for a in self.agents]
        return top_down(self.places.geometry, here, self.goals_of(self.agents))

    def goals_of(self, agents: list[str]) -> dict[str, tuple[float, float]]:
        goals = self.goals
        return {a: goals[a] for a in agents}

    def close(self) -> None:
        self.fleet.close()
        if self.places is not self.fleet:
            self.places.close()

    def _advance(
        self, live: npt.NDArray[np.int64], names: list[str]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], F32]:
        """Hold the agents' commands (rows ``live``, named ``names``) for one lidar period (one
        step of the fleet); their poses, velocities and scans after it, a row per agent (the
        poses and velocities kept too)."""
        reply = self.fleet.step(
            TICKS_A_STEP, commands=(names, self._command[live]), observe=names, packed=True, publish=self.publish
        )
        assert reply.packed is not None  # asked for
        seen = observed_arrays(reply.packed)
        if seen.names != names:  # one deleted during the step (before it, the step is refused)
            gone = sorted(set(names) - set(seen.names))
            raise RuntimeError(f"robots of this environment were deleted during the step, by somebody else: {gone}")
        pose, velocity = seen.odom[:, :3], seen.odom[:, [3, 5]]
        self._pose[live] = pose
        self._velocity[live] = velocity
        return pose, velocity, seen.ranges

    def _look(self, live: npt.NDArray[np.int64]) -> tuple[F32, npt.NDArray[np.float64]]:
        """The live agents' observations after the reset's step, and their distances to their goals."""
        pose, goal = self._pose[live], self._goal[live]
        obs = observe_many(pose, self._velocity[live], goal, self._scans, self.beams, self._range_max, self._low,
                           self._high)  # fmt: skip
        distance = np.hypot(goal[:, 0] - pose[:, 0], goal[:, 1] - pose[:, 1])
        return obs, distance

    def _infos(self, live: npt.NDArray[np.int64], distance: npt.NDArray[np.float64]) -> list[dict[str, Any]]:
        """The reset's infos (a step builds its own, around the wait for the scans)."""
        poses, goals, far = self._pose[live].tolist(), self._goal[live].tolist(), distance.tolist()
        together = zip(poses, goals, far, strict=True)
        return [{"pose": tuple(p), "goal": tuple(g), "distance": x} for p, g, x in together]
