"""Loop closure: the pose graph's solver on hand-made graphs, the closure search on scans of known scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clients.mapping.grid import Beams
from clients.mapping.loops import search
from clients.mapping.match import end_points
from clients.mapping.posegraph import Pose, PoseGraph, between, compose, information

LDS = Beams(0.0, 6.28 / 359, 360, 0.12, 3.5)
ODOMETRY = information(0.02, 0.01)


def _square(side: int = 4, step: float = 0.5) -> list[Pose]:
    """A square drive, ``side`` keyframes a side ``step`` apart, turning left at each corner."""
    poses = []
    p: Pose = (0.0, 0.0, 0.0)
    for _ in range(4):
        for _ in range(side):
            poses.append(p)
            p = compose(p, (step, 0.0, 0.0))
        p = compose(p, (0.0, 0.0, math.pi / 2))
    return poses


def _drifted(truth: list[Pose], drift_rad: float) -> PoseGraph:
    """The trajectory as odometry with a heading bias of ``drift_rad`` an edge measured it."""
    g = PoseGraph()
    g.add_root(truth[0], information(1e-3, 1e-3))
    for k in range(1, len(truth)):
        x, y, th = between(truth[k - 1], truth[k])
        g.add_node(k - 1, (x, y, th + drift_rad), ODOMETRY)
    return g


def _errors(g: PoseGraph, truth: list[Pose]) -> tuple[float, float]:
    """The largest position and heading errors of the graph's poses."""
    est, true = np.array(g.poses), np.array(truth)
    turn = np.arctan2(np.sin(est[:, 2] - true[:, 2]), np.cos(est[:, 2] - true[:, 2]))
    return float(np.hypot(*(est[:, :2] - true[:, :2]).T).max()), float(np.abs(turn).max())


def test_closing_a_square_loop_takes_out_the_drift() -> None:
    truth = _square()
    g = _drifted(truth, 0.006)  # 0.09 rad over the loop: 0.12 m off at worst
    assert _errors(g, truth)[0] > 0.1
    g.add_loop(0, len(truth) - 1, between(truth[0], truth[-1]), ODOMETRY)
    stats = g.optimise()
    position, heading = _errors(g, truth)
    assert position < 0.02 and heading < 0.01
    assert stats.cost_after < stats.cost_before
    assert g.loop_weights()[0] > 0.9  # the graph agrees with it: it keeps its weight


def test_a_wrong_loop_edge_loses_its_weight() -> None:
    """Two closures agree with the trajectory, a third (a false match, 0.5 m and 0.2 rad off) does
    not: the robust kernel all but drops it and the poses stay where they are."""
    truth = _square()
    g = _drifted(truth, 0.0)
    last = len(truth) - 1
    g.add_loop(0, last, between(truth[0], truth[last]), ODOMETRY)
    g.add_loop(1, last, between(truth[1], truth[last]), ODOMETRY)
    g.add_loop(2, 10, compose(between(truth[2], truth[10]), (0.5, 0.3, 0.2)), ODOMETRY)
    g.optimise()
    assert _errors(g, truth)[0] < 0.03  # a pull of 1 % of its weight is left: 1.6 cm
    good1, good2, wrong = g.loop_weights()
    assert good1 > 0.9 and good2 > 0.9 and wrong < 0.01


def _two_robots(loops: int, seed: int = 3) -> tuple[PoseGraph, dict[int, Pose]]:
    """Two robots' trajectories of 40 keyframes each, measured with noise and started off their
    true poses, and ``loops`` true loop edges between random keyframes."""
    rng = np.random.default_rng(seed)
    g = PoseGraph()
    last = [g.add_root((0.0, 0.0, 0.0), information(1e-3, 1e-3)), g.add_root((2.0, 1.0, 1.0), information(1e-3, 1e-3))]
    truth = {k: g.poses[k] for k in last}
    for k in range(80):
        r = k % 2
        z = (float(rng.uniform(0.1, 0.4)), float(rng.normal(0, 0.05)), float(rng.normal(0, 0.3)))
        measured = (z[0] + float(rng.normal(0, 0.005)), z[1], z[2] + float(rng.normal(0, 0.01)))
        node = g.add_node(last[r], measured, information(0.005, 0.01))
        truth[node] = compose(truth[last[r]], z)
        last[r] = node
    for _ in range(loops):
        i, j = (int(v) for v in rng.choice(len(truth), 2, replace=False))
        g.add_loop(i, j, between(truth[i], truth[j]), information(0.01, 0.005))
    return g, truth


def test_trajectories_alone_are_solved_exactly() -> None:
    """No loop edge: the trajectories' own solver is exact, and the measurements are met."""
    g, _ = _two_robots(loops=0)
    stats = g.optimise()
    assert stats.cg_iterations == 0 and stats.cost_after < 1e-12


def test_the_direct_and_the_iterative_solvers_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    """Thirty loop edges, solved by Woodbury's identity and, forced, by conjugate gradients: the
    same poses, and nearer the truth than the odometry."""
    import clients.mapping.posegraph as posegraph

    direct, truth = _two_robots(loops=30)
    before = _errors(direct, [truth[k] for k in range(len(truth))])[0]
    assert direct.optimise().cg_iterations == 0
    monkeypatch.setattr(posegraph, "DIRECT_LOOPS", 0)
    iterative, _ = _two_robots(loops=30)
    assert iterative.optimise().cg_iterations > 0
    assert np.allclose(direct.poses, iterative.poses, atol=1e-6)
    assert _errors(direct, [truth[k] for k in range(len(truth))])[0] < before / 3


def test_optimising_repeats_to_the_bit() -> None:
    graphs = []
    for _ in range(2):
        truth = _square()
        g = _drifted(truth, 0.004)
        g.add_loop(0, len(truth) - 1, between(truth[0], truth[-1]), ODOMETRY)
        g.optimise()
        graphs.append(g.poses)
    assert graphs[0] == graphs[1]


def test_edges_need_real_nodes() -> None:
    g = PoseGraph()
    a = g.add_root((0.0, 0.0, 0.0), ODOMETRY)
    b = g.add_node(a, (1.0, 0.0, 0.0), ODOMETRY)
    with pytest.raises(ValueError, match="last node"):
        g.add_node(a, (1.0, 0.0, 0.0), ODOMETRY)  # a already has its next node
    with pytest.raises(ValueError, match="two different nodes"):
        g.add_loop(b, b, (0.0, 0.0, 0.0), ODOMETRY)


# -- the closure search -----------------------------------------------------------------------


def _scan(world_name: str, pose: Pose) -> np.ndarray:
    """A noiseless LDS-01 scan from ``pose`` in a built-in world, as end points in the robot's frame."""
    from protocol.control import SpawnRequest
    from protocol.frames import SCAN_OFFSET
    from simd.core.sim import SimConfig, Simulation
    from simd.core.worldfile import load_world

    sim = Simulation(load_world(world_name), SimConfig(noise=False, lidar_thread=False))
    sim.spawn(SpawnRequest(name="r", x=pose[0], y=pose[1], yaw=pose[2]))
    while not (snap := sim.step()).scan_namespaces:
        pass
    ranges = np.array(snap.scans[0])
    sim.close()
    ox, oy, _ = SCAN_OFFSET["burger"]
    return np.column_stack(end_points(ranges, LDS, (ox, oy)))


@pytest.mark.parametrize("error", [(0.02, -0.01, 0.01), (0.4, -0.3, 0.15), (-0.7, 0.5, -0.2)])
def test_a_scan_is_found_where_it_was_taken(error: Pose) -> None:
    """Two scans of turtlebot3_world 0.4 m and 0.3 rad apart; the second is looked for in the
    first from a guess up to 0.86 m and 0.2 rad off: it is found within a centimetre."""
    old, new = (-2.0, -0.5, 0.0), (-1.7, -0.8, 0.3)
    submap, scan = _scan("turtlebot3_world", old), _scan("turtlebot3_world", new)
    truth = between(old, new)
    guess = (truth[0] + error[0], truth[1] + error[1], truth[2] + error[2])
    closure = search(scan, submap, np.zeros_like(submap), guess)
    assert closure.accepted, closure.refused
    x, y, yaw = between(truth, closure.pose)
    assert math.hypot(x, y) < 0.01 and abs(yaw) < 0.005


def _corridor(x: float) -> np.ndarray:
    """End points of a scan at (x, 0) in an endless corridor between walls at y = ±1."""
    a = LDS.angles
    s = np.sin(a)
    with np.errstate(divide="ignore"):
        r = np.where(np.abs(s) > 1e-9, 1.0 / np.abs(s), np.inf)
    ok = r < LDS.range_max
    return np.column_stack([x + r[ok] * np.cos(a[ok]), r[ok] * s[ok]])


def test_a_corridor_is_no_closure() -> None:
    """Along a corridor every shift fits as well: refused, wherever the guess is."""
    submap = _corridor(0.0)
    scan = _corridor(0.0)  # taken 0.5 m further along: in its own frame, the same points
    for guess in [(0.5, 0.0, 0.0), (0.8, 0.1, 0.05)]:
        closure = search(scan, submap, np.zeros_like(submap), guess)
        assert not closure.accepted and ("ambiguous" in closure.refused or "one direction" in closure.refused)


def test_nothing_in_range_is_no_closure() -> None:
    submap = _scan("turtlebot3_world", (-2.0, -0.5, 0.0))
    closure = search(np.zeros((10, 2)), submap, np.zeros_like(submap), (0.0, 0.0, 0.0))
    assert not closure.accepted and "few points" in closure.refused


def _l_corner(offset: float, sensor: tuple[float, float]) -> np.ndarray:
    """The faces of an L of walls: along the x axis at y = -offset and along the y axis at
    x = -offset, out to 3 m, every 2 cm, relative to the ``sensor`` that sees them."""
    t = np.arange(-offset, 3.0, 0.02)
    faces = np.concatenate(
        [np.column_stack([t, np.full_like(t, -offset)]), np.column_stack([np.full_like(t, -offset), t])]
    )
    return np.asarray(faces - np.array(sensor))


def test_a_wall_seen_from_its_other_side_is_no_closure() -> None:
    """A robot outside a corner sees the outer faces of two walls another robot mapped from inside:
    a wall's thickness (0.15 m) away, the same L. Laid on the inner faces it fits well (the walls
    hold it both ways), and wrongly: refused. The same scan taken inside is found."""
    submap = _l_corner(0.0, (0.0, 0.0))  # in the corner's frame
    sensors = np.full_like(submap, 1.5)  # seen from (1.5, 1.5), inside the corner
    outside_at, inside_at = (-1.0, -1.0), (1.2, 0.8)
    closure = search(_l_corner(0.15, outside_at), submap, sensors, (*outside_at, 0.0))
    assert not closure.accepted and "far side" in closure.refused, closure
    closure = search(_l_corner(0.0, inside_at), submap, sensors, (inside_at[0] + 0.3, inside_at[1] - 0.2, 0.1))
    assert closure.accepted, closure.refused
    assert math.hypot(closure.pose[0] - inside_at[0], closure.pose[1] - inside_at[1]) < 0.01
