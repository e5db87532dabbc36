"""Navigation on a real daemon: goals over the fleet protocol, from the API, the ``fleet goto``
command line and raw zenoh, with what goes wrong (bad goals, storms, deletes, restarts).

Daemons run ``--lockstep``: the test steps time itself, so a goal takes the same ticks
whatever the machine's load, and "nothing moved" is exact."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest

from clients import FleetClient, wait_until
from protocol.codec import decode
from protocol.errors import FleetError
from protocol.navigation import NavigateRequest, NavigationResult, NavigationState
from tests.conftest import ROOT, Daemon, start_daemon
from tests.zraw import get, raw_session

#: free places of turtlebot3_world a burger fits (clearance > 0.4 m), and tb3_0's spawn
FREE = [(1.8, -0.5), (0.5, 1.8), (-0.5, -1.8), (1.5, 0.5)]
SPAWN = (-2.0, -0.5)
#: sim seconds a goal across turtlebot3_world may take at most (the burger does 0.22 m/s)
ACROSS_S = 90.0


def pose(c: FleetClient, name: str) -> tuple[float, float, float]:
    r = c.robot(name)
    assert r is not None
    return (r.pose.x, r.pose.y, r.pose.yaw)


def stepped_until_ended(c: FleetClient, robot: str, goal_id: str, seconds: float = ACROSS_S) -> NavigationResult:
    """Step the daemon a second at a time until the goal ended; its result."""
    for _ in range(int(seconds)):
        c.step(30)
        state = c.navigation_state(robot)
        if state.goal_id == goal_id and not state.active:
            assert state.result is not None
            return state.result
    raise AssertionError(f"goal {goal_id} of {robot} did not end in {seconds} sim s: {c.navigation_state(robot)}")


@pytest.fixture
def lockstep(daemon_factory: Callable[..., Daemon]) -> tuple[Daemon, FleetClient]:
    d = daemon_factory("--lockstep")
    c = d.client(timeout=10.0)  # (lockstep: nothing here waits on the clock; a shared machine stalls for seconds)
    c.spawn("tb3_0", *SPAWN)
    return d, c


def test_a_robot_goes_where_it_is_sent(lockstep: tuple[Daemon, FleetClient]) -> None:
    d, c = lockstep
    goal = c.navigate("tb3_0", 1.8, -0.5, yaw=math.pi / 2, tolerance=0.1, yaw_tolerance=0.1)
    assert goal.goal_id and goal.accepted is not None and goal.accepted.preempted == ""
    c.step(30)
    assert c.plans("tb3_0")["tb3_0"].goal_id == goal.goal_id  # its path, for whoever asks
    path = c.plans("tb3_0")["tb3_0"]
    assert len(path.points) >= 2
    result = stepped_until_ended(c, "tb3_0", goal.goal_id)
    assert (result.status, result.reason) == ("reached", ""), result
    x, y, yaw = pose(c, "tb3_0")
    assert math.hypot(x - 1.8, y + 0.5) <= 0.1 + 1e-9
    assert abs(math.remainder(yaw - math.pi / 2, math.tau)) <= 0.1 + 1e-9
    # the straight line is 3.8 m, less the tolerance; at 0.22 m/s at most
    assert 3.7 / 0.22 < result.navigation_time < ACROSS_S
    assert result.distance_travelled >= 3.7
    # the client's handle heard the same result, and feedback on the way
    assert goal.wait(timeout=5.0) == result
    assert "Traceback" not in d.log()


def test_feedback_says_how_far_and_how_long(lockstep: tuple[Daemon, FleetClient]) -> None:
    _, c = lockstep
    heard: list[Any] = []
    goal = c.navigate("tb3_0", 1.8, -0.5)
    sub = c.session.declare_subscriber(c.keys.navigate_feedback("tb3_0"), lambda s: heard.append(s))
    for _ in range(5):
        c.step(30)
    state = c.navigation_state("tb3_0")
    assert state.active and state.feedback is not None
    fb = state.feedback
    assert fb.goal_id == goal.goal_id and fb.state in ("driving", "planning", "waiting")
    assert (
        0.0 < fb.distance_remaining < 4.5
        and fb.estimated_time_remaining > 0.0
        and fb.navigation_time == pytest.approx(5.0, abs=0.25)
    )
    assert wait_until(lambda: len(heard) >= 1, 5.0)  # put while somebody listens
    sub.undeclare()
    goal.cancel()


def test_cancel_stops_the_robot_and_preempt_replaces_the_goal(lockstep: tuple[Daemon, FleetClient]) -> None:
    _, c = lockstep
    first = c.navigate("tb3_0", 1.8, -0.5)
    c.step(60)
    second = c.navigate("tb3_0", -0.5, -1.8)
    assert second.accepted is not None and second.accepted.preempted == first.goal_id
    old = first.wait(timeout=5.0)
    assert (old.status, old.reason) == ("failed", "preempted")
    c.step(60)
    cancelled = second.cancel()
    assert (cancelled.status, cancelled.reason) == ("failed", "cancelled")
    c.step(30)  # the wheels brake within a second
    before = pose(c, "tb3_0")
    c.step(30)
    assert pose(c, "tb3_0") == pytest.approx(before, abs=1e-3)  # it stays
    with pytest.raises(FleetError) as e:
        c.cancel_goal("tb3_0")  # nothing left to cancel
    assert e.value.code == "not_found"


def test_a_goal_runs_out_of_time(lockstep: tuple[Daemon, FleetClient]) -> None:
    _, c = lockstep
    goal = c.navigate("tb3_0", 1.8, -0.5, timeout=3.0)
    result = stepped_until_ended(c, "tb3_0", goal.goal_id, 10)
    assert (result.status, result.reason) == ("failed", "timeout")
    assert result.navigation_time == pytest.approx(3.0, abs=0.2)


BAD_GOALS: list[tuple[str, dict[str, Any], str]] = [
    ("in a pillar", {"x": 1.1, "y": 1.1}, "collision"),
    ("in the outer wall", {"x": 0.0, "y": 2.7}, "collision"),
    ("off the map", {"x": 30.0, "y": 0.0}, "out_of_bounds"),
    ("huge", {"x": 1e300, "y": 0.0}, "out_of_bounds"),
    ("huge int", {"x": 10**18, "y": 0}, "out_of_bounds"),
    ("nan", {"x": math.nan, "y": 0.0}, "non_finite"),
    ("inf y", {"x": 0.0, "y": math.inf}, "non_finite"),
    ("nan yaw", {"x": 1.8, "y": -0.5, "yaw": math.nan}, "non_finite"),
    ("zero tolerance", {"x": 1.8, "y": -0.5, "tolerance": 0.0}, "invalid_value"),
    ("negative tolerance", {"x": 1.8, "y": -0.5, "tolerance": -1.0}, "invalid_value"),
    ("yaw tolerance over pi", {"x": 1.8, "y": -0.5, "yaw_tolerance": 4.0}, "invalid_value"),
    ("negative timeout", {"x": 1.8, "y": -0.5, "timeout": -1.0}, "invalid_value"),
    ("bad goal id", {"x": 1.8, "y": -0.5, "goal_id": "a b/c"}, "invalid_value"),
]


@pytest.mark.parametrize(("case", "fields", "code"), BAD_GOALS, ids=[c for c, _, _ in BAD_GOALS])
def test_a_bad_goal_is_refused_and_nothing_moves(
    lockstep: tuple[Daemon, FleetClient], case: str, fields: dict[str, Any], code: str
) -> None:
    d, c = lockstep
    before = pose(c, "tb3_0")
    with raw_session(d.endpoint) as s:  # as any client would send it (MessagePack carries NaN)
        ok, err = get(s, c.keys.navigate("tb3_0"), msgspec.msgpack.encode(fields), 10.0)
    assert ok is None and err is not None, case
    reply = msgspec.msgpack.decode(err)
    assert reply["code"] == code, reply
    assert "internal" not in reply["message"]
    c.step(30)
    assert pose(c, "tb3_0") == before
    assert c.navigation_state("tb3_0") == NavigationState(robot="tb3_0")  # no goal was taken
    assert d.alive() and "Traceback" not in d.log()


def test_malformed_requests_and_unknown_robots(lockstep: tuple[Daemon, FleetClient]) -> None:
    d, c = lockstep
    before = pose(c, "tb3_0")
    with raw_session(d.endpoint) as s:
        for key, body in [
            (c.keys.navigate("tb3_0"), b"\xff\x00garbage"),
            (c.keys.navigate("tb3_0"), b'{"x": "one", "y": 0}'),
            (c.keys.navigate("tb3_0"), b'{"y": 0}'),
            (c.keys.navigate_cancel("tb3_0"), b"[1, 2"),
            (c.keys.navigate("tb3_0"), b'{"x": NaN, "y": 0}'),
            (c.keys.navigate("nobody"), b'{"x": 1.8, "y": -0.5}'),
            (c.keys.navigate_cancel("nobody"), b"{}"),
        ]:
            ok, err = get(s, key, body, 10.0)
            assert ok is None and err is not None, (key, body)
            assert json.loads(err)["code"] in ("malformed", "not_found") if err[:1] == b"{" else True
        # a wildcard get with a good body sends nobody anywhere
        for selector in (c.keys.navigate("*"), "fleet/**"):
            list(s.get(selector, payload=b'{"x": 1.8, "y": -0.5}', timeout=3.0))
    c.step(30)
    assert pose(c, "tb3_0") == before
    assert c.navigation_state("tb3_0").goal_id == ""
    with pytest.raises(FleetError) as e:
        c.navigate("nobody", 1.8, -0.5)
    assert e.value.code == "not_found"
    assert d.alive() and "Traceback" not in d.log()


def test_a_goal_storm_at_one_robot(lockstep: tuple[Daemon, FleetClient]) -> None:
    """1 000 goals sent as fast as a client can at one robot: each is answered, each one
    preempts the one before, the last is the robot's, and the daemon serves on."""
    d, c = lockstep
    heard: list[NavigationResult] = []
    sub = c.session.declare_subscriber(
        c.keys.navigate_result("tb3_0"), lambda s: heard.append(decode(s.payload.to_bytes(), NavigationResult))
    )
    goals = [("tb3_0", NavigateRequest(x=FREE[k % 4][0], y=FREE[k % 4][1])) for k in range(1000)]
    replies = c.send_goals(goals)
    assert len(replies) == 1000 and len({r.goal_id for r in replies}) == 1000
    assert all(r.preempted == replies[k].goal_id for k, r in enumerate(replies[1:]))
    assert wait_until(lambda: len(heard) == 999, 10.0), len(heard)
    assert all(r.reason == "preempted" for r in heard)
    state = c.navigation_state("tb3_0")
    assert state.active and state.goal_id == replies[-1].goal_id
    result = stepped_until_ended(c, "tb3_0", replies[-1].goal_id)
    assert result.status == "reached"
    x, y, _ = pose(c, "tb3_0")
    assert math.hypot(x - FREE[999 % 4][0], y - FREE[999 % 4][1]) <= 0.25 + 1e-9
    sub.undeclare()
    assert d.alive() and "Traceback" not in d.log()


def test_a_robot_deleted_mid_goal(lockstep: tuple[Daemon, FleetClient]) -> None:
    _, c = lockstep
    goal = c.navigate("tb3_0", 1.8, -0.5)
    c.step(30)
    c.delete("tb3_0")
    result = goal.wait(timeout=10.0)
    assert (result.status, result.reason) == ("failed", "robot_gone")
    with pytest.raises(FleetError):
        c.navigation_state("tb3_0")


def test_a_reset_ends_the_goals(lockstep: tuple[Daemon, FleetClient]) -> None:
    _, c = lockstep
    goal = c.navigate("tb3_0", 1.8, -0.5)
    c.step(60)
    c.reset()
    result = goal.wait(timeout=10.0)
    assert (result.status, result.reason) == ("failed", "cancelled")
    c.step(30)
    assert pose(c, "tb3_0")[:2] == pytest.approx(SPAWN, abs=1e-6)  # back where it was spawned, and stays


def test_no_nav_refuses_goals(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--lockstep", "--no-nav")
    c = d.client()
    c.spawn("tb3_0", *SPAWN)
    with pytest.raises(FleetError) as e:
        c.navigate("tb3_0", 1.8, -0.5)
    assert e.value.code == "not_allowed" and "--no-nav" in e.value.message


def test_a_daemon_restarted_without_state_ends_the_goal(daemon_factory: Callable[..., Daemon], tmp_path: Path) -> None:
    d = daemon_factory("--lockstep")
    c = d.client()
    c.spawn("tb3_0", *SPAWN)
    goal = c.navigate("tb3_0", 1.8, -0.5)
    c.step(30)
    d.proc.kill()
    d.proc.wait()
    again = start_daemon(tmp_path, "--lockstep", port=d.port)
    try:
        result = goal.wait(timeout=20.0)  # the client asks, finds no such robot any more
        assert (result.status, result.reason) == ("failed", "robot_gone")
        assert "gone" in result.message
    finally:
        again.stop()


def test_a_daemon_restarted_with_state_drives_on(daemon_factory: Callable[..., Daemon], tmp_path: Path) -> None:
    state = tmp_path / "fleet.json"
    d = daemon_factory("--lockstep", "--state", str(state))
    c = d.client()
    c.spawn("tb3_0", *SPAWN)
    goal = c.navigate("tb3_0", 1.8, -0.5, goal_id="to-the-east")
    c.step(150)
    assert wait_until(lambda: json.loads(state.read_text()).get("goals"), 10.0)
    d.proc.kill()  # no chance to save on the way out
    d.proc.wait()
    again = start_daemon(tmp_path, "--lockstep", "--state", str(state), port=d.port)
    try:
        assert "resumed 1 goals" in again.log()
        c2 = again.client()
        st = c2.navigation_state("tb3_0")
        assert st.active and st.goal_id == "to-the-east"
        result = stepped_until_ended(c2, "tb3_0", "to-the-east")
        assert result.status == "reached"
        assert goal.wait(timeout=10.0).status == "reached"  # the client of before heard it too
        assert not json.loads(state.read_text())["goals"] or wait_until(
            lambda: not json.loads(state.read_text())["goals"], 10.0
        )
    finally:
        again.stop()


def test_goals_repeat_bit_for_bit_for_a_seed(daemon_factory: Callable[..., Daemon]) -> None:
    """Two daemons, the same seed, the same goals at the same ticks: the same poses, exactly."""
    runs = []
    for _ in range(2):
        d = daemon_factory("--lockstep", "--seed", "7")
        c = d.client()
        for k, (x, y) in enumerate([SPAWN, (-0.5, -1.8), (0.5, 1.8)]):
            c.spawn(f"r{k}", x, y)
        c.send_goals([("r0", NavigateRequest(x=0.5, y=1.8)), ("r1", NavigateRequest(x=-2.0, y=-0.5)),
                      ("r2", NavigateRequest(x=-0.5, y=-1.8))])  # fmt: skip
        trace: list[list[tuple[float, ...]]] = []
        for _ in range(20):
            reply = c.step(30, observe=["r0", "r1", "r2"])
            trace.append(
                [(o.odom.pose.pose.position.x, o.odom.pose.pose.position.y) for o in reply.observations.values()]
            )
        trace.append([pose(c, n) for n in ("r0", "r1", "r2")])
        runs.append(trace)
        d.stop()
    assert runs[0] == runs[1]
    assert runs[0][0] != runs[0][-2]  # and they did move


def test_two_robots_swap_ends_of_a_corridor(daemon_factory: Callable[..., Daemon], tmp_path: Path) -> None:
    """A corridor one robot wide (0.45 m between walls; the burger is 0.178 m across its
    wheels' box): both robots arrive, neither touches the other."""
    world = tmp_path / "corridor.yaml"
    world.write_text(
        "name: corridor\n"
        "bounds: {x_min: -3.5, x_max: 3.5, y_min: -2.0, y_max: 2.0}\n"
        "obstacles:\n"
        "  - {type: box, x_min: -1.5, x_max: 1.5, y_min: 0.225, y_max: 2.0}\n"
        "  - {type: box, x_min: -1.5, x_max: 1.5, y_min: -2.0, y_max: -0.225}\n"
    )
    d = daemon_factory("--lockstep", "--world", str(world))
    c = d.client()
    c.spawn("a", -2.5, 0.0)
    c.spawn("b", 2.5, 0.0, yaw=math.pi)
    ga = c.navigate("a", 2.5, 0.0, tolerance=0.1)
    gb = c.navigate("b", -2.5, 0.0, tolerance=0.1)
    closest = math.inf
    for _ in range(240):
        c.step(15)
        (ax, ay, _), (bx, by, _) = pose(c, "a"), pose(c, "b")
        closest = min(closest, math.hypot(ax - bx, ay - by))
        if ga.done and gb.done:
            break
    assert ga.wait(timeout=5.0).status == "reached" and gb.wait(timeout=5.0).status == "reached"
    assert closest > 0.3  # never closer than two burgers' half-widths
    assert math.hypot(pose(c, "a")[0] - 2.5, pose(c, "a")[1]) <= 0.1 + 1e-9


# -- fleet goto ------------------------------------------------------------------------------------


def fleet(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "clients.fleet.cli", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)  # fmt: skip


class Stepper:
    """Steps a lockstep daemon from a thread while a command waits on it."""

    def __init__(self, c: FleetClient) -> None:
        self.c = c
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                self.c.step(15)
            except FleetError:
                time.sleep(0.05)

    def __enter__(self) -> Stepper:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(10.0)


def test_goto_waits_until_reached(lockstep: tuple[Daemon, FleetClient]) -> None:
    d, c = lockstep
    with Stepper(d.client(timeout=10.0)):
        p = fleet("goto", "tb3_0", "1.8", "-0.5", "--yaw", "1.57", "--tolerance", "0.1", "--wait", "-e", d.endpoint)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "reached" in p.stdout
    x, y, _ = pose(c, "tb3_0")
    assert math.hypot(x - 1.8, y + 0.5) <= 0.1 + 1e-9


def test_goto_refused_and_failed_say_why_in_one_line(lockstep: tuple[Daemon, FleetClient]) -> None:
    d, c = lockstep
    p = fleet("goto", "tb3_0", "1.1", "1.1", "-e", d.endpoint)
    assert p.returncode == 1
    assert len(p.stderr.strip().splitlines()) == 1 and "wall or obstacle" in p.stderr, p.stderr
    p = fleet("goto", "tb3_0", "nan", "0", "-e", d.endpoint)
    assert p.returncode in (1, 2) and "finite" in p.stderr, p.stderr
    p = fleet("goto", "tb3_0", "east", "0", "-e", d.endpoint)
    assert p.returncode == 2 and "numbers" in p.stderr, p.stderr
    p = fleet("goto", "ghost", "1.8", "-0.5", "-e", d.endpoint)
    assert p.returncode == 1 and "ghost" in p.stderr, p.stderr
    with Stepper(d.client(timeout=10.0)):  # a goal with a time limit that runs out: exit 4
        p = fleet("goto", "tb3_0", "1.8", "-0.5", "--wait", "--timeout", "2", "-e", d.endpoint)
    assert p.returncode == 4, p.stdout + p.stderr
    assert "timeout" in p.stderr.strip().splitlines()[-1]
    assert pose(c, "tb3_0") != (*SPAWN, 0.0)


def test_goto_cancel(lockstep: tuple[Daemon, FleetClient]) -> None:
    d, c = lockstep
    p = fleet("goto", "tb3_0", "1.8", "-0.5", "-e", d.endpoint)
    assert p.returncode == 0, p.stderr
    c.step(30)
    p = fleet("goto", "--cancel", "tb3_0", "-e", d.endpoint)
    assert p.returncode == 0, p.stderr
    assert "cancelled" in p.stdout
    state = c.navigation_state("tb3_0")
    assert not state.active and state.result is not None and state.result.reason == "cancelled"
    p = fleet("goto", "--cancel", "tb3_0", "-e", d.endpoint)  # nothing left: says so
    assert p.returncode == 1 and "no goal" in p.stderr


def test_goto_goals_from_a_file(lockstep: tuple[Daemon, FleetClient], tmp_path: Path) -> None:
    d, c = lockstep
    c.spawn("tb3_1", -0.5, -1.8)
    goals = tmp_path / "goals.yaml"
    goals.write_text("- {robot: tb3_0, x: 0.5, y: 1.8}\n- {robot: tb3_1, x: 1.8, y: -0.5, tolerance: 0.2}\n")
    before = goals.read_bytes()
    with Stepper(d.client(timeout=10.0)):
        p = fleet("goto", "--file", str(goals), "--wait", "-e", d.endpoint, timeout=120.0)
    assert p.returncode == 0, p.stdout + p.stderr
    assert p.stdout.count("reached") >= 2
    assert goals.read_bytes() == before
    bad = tmp_path / "bad.yaml"
    for text, says in [
        ("- {robot: tb3_0, x: 0.5}\n", "y"),
        ("- {robot: tb3_0, x: 0.5, y: 1.8, speed: 3}\n", "speed"),
        ("- {robot: tb3_0, x: [0.5, y: 1.8\n", "line"),
        ("robot: tb3_0\n", "list"),
    ]:
        bad.write_text(text)
        p = fleet("goto", "--file", str(bad), "-e", d.endpoint)
        assert p.returncode == 2, (text, p.stderr)
        last = p.stderr.strip().splitlines()[-1]  # after the usage, as every fleet command says it
        assert last.startswith("fleet goto: error: ") and str(bad) in last and says in last, (text, p.stderr)
        assert bad.read_text() == text
    p = fleet("goto", "--file", str(tmp_path / "missing.yaml"), "-e", d.endpoint)
    assert p.returncode == 2 and "missing.yaml" in p.stderr


def test_goto_without_a_daemon(tmp_path: Path) -> None:
    p = fleet("goto", "tb3_0", "1", "1", "-e", "tcp/127.0.0.1:9", "--timeout", "1")
    assert p.returncode == 3, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


def test_a_waffle_on_a_map_server_map_goes_round_a_wall(daemon_factory: Callable[..., Daemon], tmp_path: Path) -> None:
    """A map as fleet-map or map_server writes it (PGM + YAML), a waffle (0.58 m cells): the
    wall between start and goal leaves a gap at its top end, and the robot takes it."""
    from fleetcommon.mapfile import OCCUPIED, OccupancyMap, write_map

    cells = np.zeros((80, 120), dtype=np.int8)  # 6 m x 4 m at 5 cm, row 0 at the bottom
    cells[:2, :] = cells[-2:, :] = cells[:, :2] = cells[:, -2:] = OCCUPIED
    cells[:58, 59:62] = OCCUPIED  # a wall up the middle from the bottom, 2.9 m of the 4
    _, yaml_path = write_map(tmp_path / "room", OccupancyMap(cells, 0.05, (0.0, 0.0, 0.0)))
    d = daemon_factory("--lockstep", "--world", str(yaml_path))
    c = d.client()
    c.spawn("w", 1.0, 1.0, model="waffle")
    goal = c.navigate("w", 5.0, 1.0, tolerance=0.15)
    highest = 0.0
    for _ in range(120):
        c.step(30)
        highest = max(highest, pose(c, "w")[1])
        state = c.navigation_state("w")
        if not state.active:
            break
    result = goal.wait(timeout=5.0)
    assert result.status == "reached", result
    assert highest > 2.9  # round the wall's end, not through it
    x, y, _ = pose(c, "w")
    assert math.hypot(x - 5.0, y - 1.0) <= 0.15 + 1e-9
