"""``FleetNavigateEnv``: N TurtleBot3s in one world, each driving to its own goal (PettingZoo).

The multi-robot form of ``fleetsim/Navigate-v0`` (learn/navigate.py): the same observation,
action, reward and step (0.2 s, one lidar period) for every agent, on one simulation core in
this process. The robots see each other in their scans and can collide with each other; an
agent leaves the episode (and the world: its robot is removed) when it reaches its goal or
collides, and all leave at ``max_steps``.

    from learn.navigate_fleet import FleetNavigateEnv
    env = FleetNavigateEnv(robots=4)
    observations, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        observations, rewards, terminations, truncations, infos = env.step(actions)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from learn.task import (
    ARRIVAL_REWARD,
    COLLISION_REWARD,
    DISCRETE_TURNS,
    F32,
    GOAL_RADIUS,
    PROGRESS_REWARD,
    check_settings,
    collided,
    command,
    footprint_ranges,
    free_pose,
    observation_bounds,
    observe,
    state_of,
)
from protocol.control import SpawnRequest
from simd.core.mapworld import load_world_or_map
from simd.core.sim import SimConfig, Simulation

TICKS_A_STEP = 6


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
    ) -> None:
        if not 1 <= robots <= 64:
            raise ValueError(f"robots must be in 1..64, got {robots}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
        self.model = check_settings(model, beams, max_steps)
        self.beams = beams
        self.discrete = discrete
        self.max_steps = max_steps
        self.render_mode = render_mode
        self.sim = Simulation(load_world_or_map(world), SimConfig(noise=lidar_noise, lidar_thread=False, cmd_timeout=0))
        self.possible_agents = [f"tb3_{i}" for i in range(robots)]
        self.agents: list[str] = []
        x0, x1, y0, y1 = self.sim.world.bounds
        self._low, self._high = observation_bounds(self.model, beams, math.hypot(x1 - x0, y1 - y0))
        self._obs_space = spaces.Box(self._low, self._high, dtype=np.float32)
        self._act_space: spaces.Space[Any] = (
            spaces.Discrete(len(DISCRETE_TURNS)) if discrete else spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        )
        self._footprint = footprint_ranges(self.model, self.sim.config.lidar.samples)
        self._rng = np.random.default_rng()
        self.goals: dict[str, tuple[float, float]] = {}
        self._scans: dict[str, F32] = {}
        self._distance: dict[str, float] = {}
        self.steps = 0

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self._act_space

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, F32], dict[str, dict[str, Any]]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self.sim.reset(int(self._rng.integers(2**31)))
        for s in self.sim.states():
            self.sim.delete(s.name)
        for _ in range(100):
            if self._place():
                break
            for s in self.sim.states():
                self.sim.delete(s.name)
        else:
            raise RuntimeError(f"no room for {len(self.possible_agents)} robots in {self.sim.world.name!r}")
        self.agents = list(self.possible_agents)
        self.steps = 0
        seen = {a: self._look(a) for a in self.agents}
        self._distance = {a: d for a, (_, d, _) in seen.items()}
        return {a: o for a, (o, _, _) in seen.items()}, {a: i for a, (_, _, i) in seen.items()}

    def _place(self) -> bool:
        """Every robot at a free start with its goal; False if one starts in contact."""
        taken: list[tuple[float, float]] = []
        for a in self.possible_agents:
            x, y, yaw = free_pose(self.sim, self.model, self._rng, tuple(taken))
            self.sim.spawn(SpawnRequest(name=a, model=self.model.name, x=x, y=y, yaw=yaw))
            taken.append((x, y))
        for a in self.possible_agents:
            gx, gy, _ = free_pose(self.sim, self.model, self._rng, tuple(taken))
            self.goals[a] = (gx, gy)
            taken.append((gx, gy))
        self._advance({})
        return not any(collided(self._scans[a], self._footprint) for a in self.possible_agents)

    def step(self, actions: dict[str, Any]) -> tuple[
        dict[str, F32], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]
    ]:  # fmt: skip
        unknown = set(actions) - set(self.agents)
        if unknown:
            raise ValueError(f"actions for agents not in the episode: {sorted(unknown)} (live: {self.agents})")
        commands = {a: command(actions[a], self.model, self.discrete) for a in actions}
        self._advance(commands)
        self.steps += 1
        obs, rewards, terms, truncs, infos = {}, {}, {}, {}, {}
        for a in self.agents:
            obs[a], d, info = self._look(a)
            reward = PROGRESS_REWARD * (self._distance[a] - d)
            self._distance[a] = d
            arrived = d < GOAL_RADIUS
            crashed = collided(self._scans[a], self._footprint)
            reward += ARRIVAL_REWARD if arrived else COLLISION_REWARD if crashed else 0.0
            rewards[a] = float(reward)
            terms[a] = arrived or crashed
            truncs[a] = not terms[a] and self.steps >= self.max_steps
            infos[a] = info | {"arrived": arrived, "collided": crashed}
        for a in list(self.agents):
            if terms[a] or truncs[a]:  # it leaves the episode, and the world
                self.sim.delete(a)
                self.agents.remove(a)
        return obs, rewards, terms, truncs, infos

    def render(self) -> Any:
        from learn.picture import top_down

        if self.render_mode != "rgb_array":
            return None
        return top_down(self.sim, {a: self.goals[a] for a in self.agents})

    def close(self) -> None:
        self.sim.close()

    def _advance(self, commands: dict[str, tuple[float, float]]) -> None:
        for _ in range(TICKS_A_STEP):
            self.sim.command_many(commands)
            snap = self.sim.step()
            for i, ns in enumerate(snap.scan_namespaces):
                self._scans[ns] = np.array(snap.scans[i])

    def _look(self, agent: str) -> tuple[F32, float, dict[str, Any]]:
        """The agent's observation, distance to its goal and info, from one look at its state."""
        pose, velocity = state_of(self.sim, agent)
        goal = self.goals[agent]
        d = math.hypot(goal[0] - pose[0], goal[1] - pose[1])
        obs = observe(pose, velocity, goal, self._scans[agent], self.beams, self.sim.config.lidar.range_max,
                      self._low, self._high)  # fmt: skip
        return obs, d, {"pose": pose, "goal": goal, "distance": d}
