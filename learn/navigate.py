"""``fleetsim/Navigate-v0``: one TurtleBot3 drives to a goal in a world, seeing with its lidar.

The task of ROBOTIS' turtlebot3_machine_learning stages and of most TurtleBot3 navigation
papers, on fleetsim's simulation core in this process: no daemon, no network, a reset that
takes milliseconds instead of a Gazebo restart.

- **Time**: one step is one lidar period, 0.2 s of sim time (six 30 Hz ticks with the command
  held), so every observation holds a fresh scan, as on the robot (LDS-01 at 5 Hz).
- **Observation** (``Box``, float32): the scan reduced to ``beams`` sectors, each the nearest
  return in it divided by the range limit (no return 1, closer than the minimum range 0); then
  the goal's distance (m) and bearing from the robot's heading (rad, -π..π); then the robot's
  linear and angular velocity.
- **Action**: ``Box`` of (linear, angular) velocity as fractions -1..1 of the model's limits
  (0.22 m/s and 2.84 rad/s for the burger; values outside are clipped, as the robot's firmware
  clamps), or with ``discrete=True`` one of five turn rates at a fixed forward speed, as the
  ROBOTIS DQN stage.
- **Reward**: 10 per metre of progress towards the goal, +10 on arrival (within 0.2 m), -10
  for a collision (a return closer than 2 cm outside the footprint, or below the lidar's
  minimum range).
- **End**: ``terminated`` on arrival or collision; ``truncated`` after ``max_steps`` steps.
- **Episodes**: start and goal drawn uniformly over the free space the robot can drive to
  from the world's spawn (learn/reach.py: not the floor outside turtlebot3_world's wall; the
  footprint clear of everything, with room to see; at least a metre apart) from the env's
  generator; ``reset(seed=s)`` reseeds it and the lidar noise, so a seed replays an episode
  exactly. ``reset(options={"start": (x, y, yaw), "goal": (x, y)})`` fixes either.
- **Where it runs**: the engine in this process (simd/engine/local.py), asked the fleet
  protocol's requests: one ``sim/step`` a step, the observation packed in its reply. With
  ``endpoint=`` the same requests go to a simd in lockstep over Zenoh (learn/fleet.py), to be
  watched in the viewer or ROS tools: the same episodes; ``publish=False`` steps it without
  publishing any topic, when nobody watches.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium
import numpy as np
import numpy.typing as npt

from clients.api import observed_arrays
from fleetcommon.arrays import F32
from learn.fleet import open_fleet, remove_own
from learn.task import (
    ARRIVAL_REWARD,
    COLLISION_REWARD,
    GOAL_RADIUS,
    PROGRESS_REWARD,
    check_settings,
    collided,
    command,
    drivable,
    footprint_ranges,
    free_pose,
    observe_many,
    spaces_for,
)
from protocol.errors import FleetError

TICKS_A_STEP = 6  # one lidar period at 30 Hz: every step sees a new scan
MIN_START_GOAL_M = 1.0
ROBOT = "agent"


class NavigateEnv(gymnasium.Env[F32, Any]):
    """See the module docstring."""

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 5}  # noqa: RUF012 (gymnasium's own name)

    def __init__(
        self,
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
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.model = check_settings(model, beams, max_steps)
        self.beams = beams
        self.max_steps = max_steps
        self.render_mode = render_mode
        #: the fleet the robot drives in, and the world asked where it fits (the same, in process)
        self.fleet, self.places = open_fleet(
            world, {ROBOT}, lidar_noise=lidar_noise, lidar_thread=False, endpoint=endpoint, prefix=prefix
        )
        self.publish = publish
        spec = self.places.lidar
        self.range_max = spec.range_max
        self._footprint = footprint_ranges(self.model, spec.samples)
        self.region = drivable(self.places.geometry, self.model)  # where starts and goals are drawn
        self._state: tuple[tuple[float, float, float], tuple[float, float]] = ((0.0, 0.0, 0.0), (0.0, 0.0))
        found = spaces_for(self.model, beams, self.places.geometry, discrete)
        self.observation_space, self.action_space = found.observation, found.action
        self._low, self._high = found.low, found.high
        self._discrete = discrete
        self.goal = (0.0, 0.0)
        self.steps = 0
        self._distance = 0.0
        self._scan = np.zeros(spec.samples, dtype=np.float32)
        self._odom = np.zeros((1, 6))
        self._window: Any = None
        self._in_episode = False  # the robot is in the world

    # -- the gymnasium API ------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[F32, dict[str, Any]]:
        super().reset(seed=seed)
        rng = self.np_random
        noise_seed = int(rng.integers(2**31))  # the lidar noise follows the env's generator
        self.fleet.reset(noise_seed)
        remove_own(self.fleet, {ROBOT})
        self._in_episode = False
        chosen_start, chosen_goal = _chosen(options)
        if chosen_goal is not None:
            gx, gy = chosen_goal
            x0, x1, y0, y1 = self.places.geometry.bounds
            if not (x0 <= gx <= x1 and y0 <= gy <= y1) or self.places.touches(
                self.model, gx, gy, 0.0, static_only=True
            ):
                raise ValueError(
                    f"options['goal'] {chosen_goal}: a {self.model.name} could not stand there "
                    f"(outside the world's bounds or in an obstacle)"
                )
        for _ in range(1000):
            start = chosen_start or self._free_pose(rng)
            goal = chosen_goal or self._free_pose(rng)[:2]
            if chosen_start is None and chosen_goal is None and math.dist(start[:2], goal) < MIN_START_GOAL_M:
                continue
            try:
                self._spawn(start)
            except FleetError as e:
                raise ValueError(f"options['start'] {start}: {e.message}") from None
            self.goal = goal
            self._advance(0.0, 0.0)
            if not self._collided() or chosen_start is not None:
                break
            self._delete()
        else:
            raise RuntimeError(f"no free start in {self.places.geometry.name!r} after 1000 draws")
        self.steps = 0
        self._distance = self._goal_distance()
        if self.render_mode == "human":
            self.render()
        return self._observation(), self._info()

    def step(self, action: Any) -> tuple[F32, float, bool, bool, dict[str, Any]]:
        v, w = self._command(action)
        self._advance(v, w)
        self.steps += 1
        distance = self._goal_distance()
        reward = PROGRESS_REWARD * (self._distance - distance)
        self._distance = distance
        arrived = distance < GOAL_RADIUS
        collided = self._collided()
        if arrived:
            reward += ARRIVAL_REWARD
        elif collided:
            reward += COLLISION_REWARD
        terminated = arrived or collided
        truncated = not terminated and self.steps >= self.max_steps
        info = self._info() | {"arrived": arrived, "collided": collided}
        if self.render_mode == "human":
            self.render()
        return self._observation(), float(reward), terminated, truncated, info

    def render(self) -> npt.NDArray[np.uint8] | None:
        from learn.picture import top_down

        here = [(ROBOT, self.model, self._pose())] if self._in_episode else []
        image = top_down(self.places.geometry, here, self.goal, ROBOT, self._scan)
        if self.render_mode == "rgb_array":
            return image
        if self.render_mode == "human":
            try:
                import matplotlib.pyplot as plt
            except ImportError:
                raise ImportError(
                    "render_mode='human' draws with matplotlib: pip install matplotlib (or the bench extra), "
                    "or use render_mode='rgb_array'"
                ) from None

            if self._window is None:
                plt.ion()
                self._window = plt.imshow(image)
                plt.axis("off")
            else:
                self._window.set_data(image)
            plt.pause(1.0 / self.metadata["render_fps"])
        return None

    def close(self) -> None:
        self.fleet.close()
        if self.places is not self.fleet:
            self.places.close()

    # -- the pieces -------------------------------------------------------------------------

    def _command(self, action: Any) -> tuple[float, float]:
        return command(action, self.model, self._discrete)

    def _spawn(self, start: tuple[float, float, float]) -> None:
        self.fleet.spawn(ROBOT, start[0], start[1], start[2], model=self.model.name)
        self._in_episode = True

    def _delete(self) -> None:
        self.fleet.delete_many([ROBOT])
        self._in_episode = False

    def _advance(self, v: float, w: float) -> None:
        """Hold (v, w) for one lidar period; keep the robot's scan, pose and velocity of it."""
        if not self._in_episode:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        reply = self.fleet.step(
            TICKS_A_STEP, commands=([ROBOT], [(v, w)]), observe=[ROBOT], packed=True, publish=self.publish
        )
        assert reply.packed is not None  # asked for
        seen = observed_arrays(reply.packed)
        self._scan = seen.ranges[0]  # a lidar period always holds one scan
        self._odom = seen.odom  # (1, 6): the observation's pose and velocities, as arrays
        x, y, yaw, vx, _, wz = seen.odom[0].tolist()
        self._state = ((x, y, yaw), (vx, wz))

    def _free_pose(self, rng: np.random.Generator) -> tuple[float, float, float]:
        return free_pose(self.places, self.model, rng, region=self.region)

    def _pose(self) -> tuple[float, float, float]:
        return self._state[0]

    def _goal_distance(self) -> float:
        x, y, _ = self._pose()
        return math.hypot(self.goal[0] - x, self.goal[1] - y)

    def _collided(self) -> bool:
        return collided(self._scan, self._footprint)

    def _observation(self) -> F32:
        # the step's arrays as they came (x, y, yaw; linear x, angular z), the values of _state
        odom = self._odom
        one = observe_many(odom[:, :3], odom[:, 3::2], np.array([self.goal]), self._scan[None, :], self.beams,
                           self.range_max, self._low, self._high)  # fmt: skip
        row: F32 = one[0]
        return row

    def _info(self) -> dict[str, Any]:
        x, y, yaw = self._pose()
        return {"pose": (x, y, yaw), "goal": self.goal, "distance": self._goal_distance(), "steps": self.steps}


def _chosen(options: dict[str, Any] | None) -> tuple[tuple[float, float, float] | None, tuple[float, float] | None]:
    """``reset(options={"start": (x, y, yaw), "goal": (x, y)})``: a fixed start and/or goal, as
    the ROBOTIS stages' fixed goals or an evaluation set; either may be left to chance."""
    opts = dict(options or {})
    unknown = set(opts) - {"start", "goal"}
    if unknown:
        raise ValueError(f"reset options are 'start' and 'goal', got {sorted(unknown)}")
    start = goal = None
    if opts.get("start") is not None:
        v = tuple(float(c) for c in opts["start"])
        if len(v) != 3 or not all(math.isfinite(c) for c in v):
            raise ValueError(f"options['start'] is (x, y, yaw), got {opts['start']!r}")
        start = (v[0], v[1], v[2])
    if opts.get("goal") is not None:
        g = tuple(float(c) for c in opts["goal"])
        if len(g) != 2 or not all(math.isfinite(c) for c in g):
            raise ValueError(f"options['goal'] is (x, y), got {opts['goal']!r}")
        goal = (g[0], g[1])
    return start, goal
