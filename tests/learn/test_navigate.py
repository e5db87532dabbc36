"""fleetsim/Navigate-v0 against Gymnasium's own checker, seeds, vector envs and bad actions."""

from __future__ import annotations

import math
import time
from typing import Any

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st

import learn  # noqa: F401  (registers the environments)
from learn.navigate import NavigateEnv
from learn.task import GOAL_RADIUS, KeepClear
from protocol.errors import FleetError
from tests.conftest import free_port


@pytest.mark.parametrize("kwargs", [{}, {"discrete": True}, {"model": "waffle", "beams": 36}])
def test_gymnasiums_checker_passes(kwargs: dict[str, Any]) -> None:
    env = gymnasium.make("fleetsim/Navigate-v0", **kwargs)
    check_env(env.unwrapped, skip_render_check=False)
    env.close()


def _rollout(env: NavigateEnv, seed: int, steps: int) -> tuple[list[np.ndarray], list[float]]:
    obs, _ = env.reset(seed=seed)
    observations, rewards = [obs], []
    rng = np.random.default_rng(7)
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        observations.append(obs)
        rewards.append(float(reward))
        if terminated or truncated:
            obs, _ = env.reset()
            observations.append(obs)
    return observations, rewards


def test_a_seed_replays_an_episode_exactly() -> None:
    a, b = NavigateEnv(), NavigateEnv()
    first = _rollout(a, 3, 60)
    again = _rollout(b, 3, 60)
    other = _rollout(b, 4, 60)
    assert all(np.array_equal(x, y) for x, y in zip(first[0], again[0], strict=True)) and first[1] == again[1]
    assert not np.array_equal(first[0][0], other[0][0])


def test_driving_at_the_goal_arrives_and_pays() -> None:
    """A simple controller (turn to the goal, drive) reaches a goal with a clear way to it."""
    env = NavigateEnv(lidar_noise=False)
    obs, info = env.reset(seed=1, options={"start": (-2.0, -0.5, 0.0), "goal": (-2.0, 0.7)})
    assert info["distance"] == pytest.approx(1.2)
    total, arrived = 0.0, False
    for _ in range(400):
        bearing = float(obs[-3])
        turn = float(np.clip(bearing, -1.0, 1.0))
        obs, reward, terminated, truncated, info = env.step(np.array([0.9 if abs(bearing) < 0.5 else 0.0, turn],
                                                                     np.float32))  # fmt: skip
        total += reward
        if terminated or truncated:
            arrived = info["arrived"]
            break
    assert arrived and info["distance"] < GOAL_RADIUS
    assert total > 10.0  # the progress made plus the arrival bonus


def test_driving_into_a_wall_ends_the_episode_with_a_penalty() -> None:
    env = NavigateEnv(world="turtlebot3_world", lidar_noise=False)
    env.reset(seed=2)
    for _ in range(300):
        _, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0], np.float32))  # straight on
        if terminated or truncated:
            break
    assert terminated and info["collided"] and reward < 0


def test_vector_envs_step_in_lockstep_in_one_process_or_several() -> None:
    actions = np.random.default_rng(0).uniform(-1, 1, (10, 2, 2)).astype(np.float32)
    seen = {}
    for mode in ("sync", "async"):  # async: a process for each env
        envs = gymnasium.make_vec("fleetsim/Navigate-v0", num_envs=2, vectorization_mode=mode)
        obs, _ = envs.reset(seed=5)
        assert obs.shape == (2, 28)
        trace = [obs]
        for a in actions:
            obs, rewards, *_ = envs.step(a)
            assert obs.shape == (2, 28) and rewards.shape == (2,)
            trace.append(obs)
        envs.close()
        seen[mode] = np.stack(trace)
    assert np.array_equal(seen["sync"], seen["async"])  # the same episodes either way


def test_actions_outside_the_space_are_clipped_and_nonsense_is_refused() -> None:
    env = NavigateEnv(world="empty", lidar_noise=False)
    env.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(np.array([0.0, -50.0], np.float32))  # clipped to the burger's -2.84 rad/s
    assert obs[-1] == pytest.approx(-2.84, abs=1e-3)
    for _ in range(3):
        obs, *_ = env.step(np.array([50.0, 0.0], np.float32))  # and 0.22 m/s
    assert obs[-2] == pytest.approx(0.22, abs=1e-3)
    for bad in ([math.nan, 0.0], [1.0], "fast"):
        with pytest.raises(ValueError, match="two finite numbers"):
            env.step(bad)
    d = NavigateEnv(world="empty", discrete=True)
    with pytest.raises(gymnasium.error.ResetNeeded):
        d.step(1)  # before any reset
    d.reset(seed=0)
    for not_a_choice in (7, 2.7, "1", None):
        with pytest.raises(ValueError, match="discrete action"):
            d.step(not_a_choice)
    d.step(np.int64(2))
    d.step(np.array(4))  # a whole number, however it comes


def test_bad_settings_say_what_to_fix() -> None:
    with pytest.raises(ValueError, match="model must be one of"):
        NavigateEnv(model="roomba")
    with pytest.raises(ValueError, match="beams must divide 360"):
        NavigateEnv(beams=7)
    with pytest.raises(ValueError, match="render_mode"):
        NavigateEnv(render_mode="vr")
    env = NavigateEnv()
    with pytest.raises(ValueError, match="'start' and 'goal'"):
        env.reset(options={"begin": (0, 0, 0)})
    with pytest.raises(ValueError, match=r"options\['goal'\] is \(x, y\)"):
        env.reset(options={"goal": (1.0, math.inf)})
    with pytest.raises(ValueError, match="would overlap"):  # the simulator's own words
        env.reset(options={"start": (1.1, 1.1, 0.0)})  # inside a pillar


def test_rgb_array_is_a_top_down_picture() -> None:
    env = NavigateEnv(render_mode="rgb_array")
    env.reset(seed=0)
    image = env.render()
    assert image is not None and image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    assert len(np.unique(image.reshape(-1, 3), axis=0)) >= 4  # floor, walls, robot, goal at least


# -- the fleet (PettingZoo) ------------------------------------------------------------------


def test_pettingzoos_parallel_api_and_seed_tests_pass() -> None:
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    from learn.navigate_fleet import FleetNavigateEnv

    parallel_api_test(FleetNavigateEnv(robots=3), num_cycles=200)
    parallel_seed_test(lambda: FleetNavigateEnv(robots=3))


def test_robots_see_each_other_and_leave_the_world_when_done() -> None:
    from learn.navigate_fleet import FleetNavigateEnv

    env = FleetNavigateEnv(robots=4, lidar_noise=False)
    observations, _ = env.reset(seed=11)
    assert sorted(observations) == ["tb3_0", "tb3_1", "tb3_2", "tb3_3"] and len(env.places) == 4
    steps = 0
    while env.agents and steps < 500:
        # full speed at their goals: they meet, bump or arrive; each leaves when it is done
        actions = {a: np.array([1.0, float(np.clip(observations[a][-3], -1, 1))], np.float32) for a in env.agents}
        observations, _, terms, truncs, _ = env.step(actions)
        for a in terms:
            if terms[a] or truncs[a]:
                assert a not in env.agents and a not in {r.name for r in env.places.robots()}
        steps += 1
    assert not env.agents and len(env.places) == 0
    with pytest.raises(ValueError, match="not in the episode"):
        env.step({"tb3_0": np.zeros(2, np.float32)})
    assert env.step({}) == ({}, {}, {}, {}, {})  # nobody left: nothing to report


# -- remote: a running simd in lockstep --------------------------------------------------------


def test_a_remote_daemon_gives_the_same_episode_as_the_core_in_process(daemon_factory: Any) -> None:
    d = daemon_factory("--lockstep")  # lidar noise on, as the env's default
    remote = NavigateEnv(endpoint=d.endpoint)
    local = NavigateEnv()
    rng = np.random.default_rng(3)
    actions = [rng.uniform(-1, 1, 2).astype(np.float32) for _ in range(40)]
    for env in (remote, local):
        env.reset(seed=9)
    here: list[tuple[Any, float, Any, bool]] = []
    there: list[tuple[Any, float, Any, bool]] = []
    for a in actions:
        for env, out in ((local, here), (remote, there)):
            obs, reward, terminated, _, info = env.step(a)
            out.append((obs, reward, info["pose"][:2], terminated))
        if here[-1][3]:
            break
    assert len(here) == len(there) > 1
    for (o1, r1, p1, t1), (o2, r2, p2, t2) in zip(here, there, strict=True):
        assert p1 == p2 and t1 == t2  # the same positions, bit for bit
        assert np.array_equal(o1, o2) and r1 == r2  # the same requests, served by the same engine
    c = d.client()
    assert [r.name for r in c.robots()] == ["agent"]  # the episode is there to watch
    remote.close()
    local.close()


def test_a_remote_fleet_gives_the_same_episodes_as_the_core_in_process(daemon_factory: Any) -> None:
    from learn.navigate_fleet import FleetNavigateEnv

    d = daemon_factory("--lockstep")
    c = d.client()
    remote = FleetNavigateEnv(robots=3, endpoint=d.endpoint, publish=False)
    local = FleetNavigateEnv(robots=3)
    for episode in range(2):  # the second reset clears the first episode's robots off the daemon
        got = [env.reset(seed=5 + episode) for env in (local, remote)]
        assert all(np.array_equal(got[0][0][a], got[1][0][a]) for a in local.possible_agents)
        rng = np.random.default_rng(episode)
        steps = 0
        while local.agents and steps < 60:
            assert remote.agents == local.agents
            actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in local.agents}
            (o1, r1, t1, _, i1), (o2, r2, t2, _, i2) = (env.step(actions) for env in (local, remote))
            for a in o1:
                assert i1[a] == i2[a]  # bit for bit
                assert np.array_equal(o1[a], o2[a]) and r1[a] == r2[a]
                assert t1[a] == t2[a]
            steps += 1
        assert steps > 5
    left = {r.name for r in c.robots()}
    assert left == set(remote.agents)  # the agents that left the episode left the daemon too
    clock = c.clock()
    remote.close()
    local.close()
    assert clock.paused and clock.tick > 0


def test_a_remote_daemon_must_be_in_lockstep_and_in_the_same_world(daemon_factory: Any) -> None:
    from learn.navigate_fleet import FleetNavigateEnv

    running = daemon_factory()
    with pytest.raises(ValueError, match="--lockstep"):
        NavigateEnv(endpoint=running.endpoint)
    other = daemon_factory("--lockstep", "--world", "empty")
    with pytest.raises(ValueError, match="runs world 'empty'"):
        NavigateEnv(endpoint=other.endpoint)
    with pytest.raises(ValueError, match="runs world 'empty'"):
        FleetNavigateEnv(endpoint=other.endpoint)


def test_an_unreachable_endpoint_is_reported_within_seconds() -> None:
    from learn.navigate_fleet import FleetNavigateEnv

    for make in (NavigateEnv, FleetNavigateEnv):
        t = time.monotonic()
        with pytest.raises(ConnectionError, match=r"no fleetsim daemon at tcp/127\.0\.0\.1:"):
            make(endpoint=f"tcp/127.0.0.1:{free_port()}")
        assert time.monotonic() - t < 6.0


def test_a_world_too_small_for_the_fleet_says_so() -> None:
    from learn.navigate_fleet import FleetNavigateEnv

    env = FleetNavigateEnv(robots=40)  # 80 places a metre apart do not fit in turtlebot3_world
    with pytest.raises(RuntimeError, match=r"no free place for 40 robots .* ask for fewer robots or a larger world"):
        env.reset(seed=0)
    env.close()
    with pytest.raises(ValueError, match=r"robots must be in 1\.\.1000"):
        FleetNavigateEnv(robots=0)


def test_one_env_drives_a_daemon_and_takes_its_robots_when_it_closes(daemon_factory: Any) -> None:
    from learn.navigate_fleet import FleetNavigateEnv

    d = daemon_factory("--lockstep")
    c = d.client()
    first = NavigateEnv(endpoint=d.endpoint)
    first.reset(seed=1)
    with pytest.raises(ValueError, match="another environment drives the daemon"):
        NavigateEnv(endpoint=d.endpoint)  # two would reset each other's worlds (a vector env: a daemon each)
    first.close()
    assert c.robots() == []  # its robot went with it
    fleet = FleetNavigateEnv(robots=2, endpoint=d.endpoint)  # and the daemon is free again
    fleet.reset(seed=2)
    assert sorted(r.name for r in c.robots()) == ["tb3_0", "tb3_1"]
    c.spawn("intruder", 0.5, -1.8)
    with pytest.raises(ValueError, match=r"robots this environment does not own \(intruder\)"):
        fleet.reset(seed=3)
    fleet.close()
    assert [r.name for r in c.robots()] == ["intruder"]  # somebody else's robot stays


def test_a_malformed_endpoint_or_goal_is_a_clear_error() -> None:
    with pytest.raises(ConnectionError, match="cannot connect to 'bogus': Endpoints must be of the form"):
        NavigateEnv(endpoint="bogus")
    env = NavigateEnv()
    for goal in ((100.0, 100.0), (0.0, 0.0)):  # outside the world; in turtlebot3_world's middle pillar
        with pytest.raises(ValueError, match="could not stand there"):
            env.reset(seed=0, options={"goal": goal})
    env.close()


def test_a_fleet_that_fits_is_placed_whatever_the_seed() -> None:
    from learn.navigate_fleet import FleetNavigateEnv

    env = FleetNavigateEnv(robots=7, lidar_noise=False)  # 14 places a metre apart in the hexagon: tight
    for seed in range(12):
        observations, _ = env.reset(seed=seed)
        assert len(observations) == 7
    env.close()


@settings(max_examples=200, deadline=None)
@given(
    points=st.lists(st.tuples(st.floats(-5, 5), st.floats(-5, 5)), max_size=40),
    x=st.floats(-6, 6),
    y=st.floats(-6, 6),
)
def test_the_keep_clear_cells_answer_as_checking_every_point_does(
    points: list[tuple[float, float]], x: float, y: float
) -> None:
    """Places are kept a metre from other robots' starts and goals; the cells that make this
    fast for a thousand robots must find exactly what a check of every point finds."""
    assert KeepClear(points).near(x, y) == any(math.dist((x, y), p) < 1.0 for p in points)


def test_a_robot_deleted_behind_the_fleet_envs_back_is_a_clear_error() -> None:
    from learn.navigate_fleet import FleetNavigateEnv

    env = FleetNavigateEnv(robots=2, lidar_noise=False)
    env.reset(seed=3)
    env.fleet.delete_many(["tb3_1"])  # somebody else's doing (on a daemon: fleet delete tb3_1)
    with pytest.raises(FleetError, match="no robot with namespace 'tb3_1'"):  # refused, nothing moved
        env.step({a: np.zeros(2, np.float32) for a in env.agents})
    env.close()
