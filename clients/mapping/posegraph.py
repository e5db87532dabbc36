"""A pose graph over SE(2) and its least-squares solution: the back end of fleet-map's SLAM.

Scan matching (match.py) keeps each robot's trajectory locally consistent, but what it gets
wrong accumulates: a heading error made while the lidar saw nothing turns everything mapped
afterwards. A pose graph can bend it back, as Cartographer's global SLAM and slam_toolbox do:

- **Nodes** are keyframe poses (x, y, yaw) in the map frame.
- **Trajectory edges** tie each keyframe to the previous one of the same robot: the relative
  pose the front end measured, with an information matrix that says how much to trust it
  (tight where the scans were matched, loose where the robot drove blind on odometry).
  Each robot's first keyframe is held where its odometry started (a strong prior), which
  also fixes the map frame (the gauge).
- **Loop edges** say where a keyframe was seen from an older one (loops.py). They go through
  a robust kernel: a closure that the rest of the graph contradicts loses its weight instead of
  tearing the map apart. A new closure is far off by nature (it is there because the
  trajectory drifted), so the solution is first found with Huber's kernel, which is convex
  and never lets go of an edge, and then continued with Cauchy's, which all but drops the
  edges still far off at Huber's solution (graduated non-convexity, in two steps).

The solver is Gauss-Newton (with a backtracking step on the robust cost) on the poses
themselves. A trajectory is a chain, and a chain's normal equations are solved exactly by two
running sums along it (the derivation is in ``_Problem._tree``): a few vectorised passes over
the nodes, no matrix. The loop edges, a few dozen to a few hundred in a run, add a low-rank
term, which Woodbury's identity turns into one dense system of three unknowns a loop edge; with
more loop edges than that is worth, conjugate gradients preconditioned by the trajectories'
solver take over (the subgraph preconditioner of Dellaert et al., 2010). No sparse library is
needed, and everything is deterministic: the same graph gives the same poses bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64

Pose = tuple[float, float, float]

#: the robust kernels' scale, in standard deviations of the edge's own noise: Huber's (a loop
#: edge further off than this pulls with a constant force) and Cauchy's (a loop edge this far
#: off keeps half its weight, ten times as far 1 %)
HUBER_SCALE = 3.0
CAUCHY_SCALE = 3.0
#: Gauss-Newton stops when no pose moves more than this (metres, radians) in an iteration
STEP_TOLERANCE = 1e-5
#: up to this many loop edges the linear systems are solved directly (a dense system of three
#: unknowns a loop edge, by Woodbury's identity); beyond, by conjugate gradients to a relative
#: residual of CG_TOLERANCE, at most CG_ITERATIONS a system
DIRECT_LOOPS = 200
CG_TOLERANCE = 1e-9
CG_ITERATIONS = 300


def wrap(a: F64) -> F64:
    return np.arctan2(np.sin(a), np.cos(a))


def compose(a: Pose, b: Pose) -> Pose:
    """``a ⊕ b``: the pose ``b`` given in ``a``'s frame, in the frame ``a`` is given in."""
    c, s = math.cos(a[2]), math.sin(a[2])
    th = a[2] + b[2]
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.atan2(math.sin(th), math.cos(th))


def inverse(a: Pose) -> Pose:
    c, s = math.cos(a[2]), math.sin(a[2])
    return -c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]


def between(a: Pose, b: Pose) -> Pose:
    """``a⁻¹ ⊕ b``: where ``b`` is, seen from ``a``."""
    return compose(inverse(a), b)


def information(sigma_m: float, sigma_rad: float) -> F64:
    """An information matrix for independent errors of ``sigma_m`` along x and y and ``sigma_rad`` in yaw."""
    return np.diag([1.0 / sigma_m**2, 1.0 / sigma_m**2, 1.0 / sigma_rad**2])


@dataclass
class Stats:
    """What an optimisation took: Gauss-Newton steps, conjugate-gradient iterations in all, and
    the (robust) cost before and after."""

    iterations: int = 0
    cg_iterations: int = 0
    cost_before: float = 0.0
    cost_after: float = 0.0


@dataclass
class PoseGraph:
    """Keyframe poses, one chain of trajectory edges per robot, and loop edges between any two."""

    poses: list[Pose] = field(default_factory=list)
    #: per node, the previous node of its trajectory (-1 for a trajectory's first node)
    parent: list[int] = field(default_factory=list)
    #: per node, the trajectory edge from its parent (or the prior of a first node): the
    #: measured pose (relative to the parent, or absolute) and its information
    measured: list[Pose] = field(default_factory=list)
    info: list[F64] = field(default_factory=list)
    #: loop edges: from node i, node j was seen at pose z (in i's frame), with information
    loops: list[tuple[int, int, Pose, F64]] = field(default_factory=list)
    _continued: set[int] = field(default_factory=set)  # nodes that have a next node

    def add_root(self, pose: Pose, info: F64) -> int:
        """A trajectory's first node, held at ``pose`` with ``info``."""
        self.poses.append(pose)
        self.parent.append(-1)
        self.measured.append(pose)
        self.info.append(np.asarray(info, dtype=np.float64))
        return len(self.poses) - 1

    def add_node(self, parent: int, z: Pose, info: F64, pose: Pose | None = None) -> int:
        """A node seen at ``z`` from its trajectory's previous node ``parent``; it starts at
        ``parent ⊕ z`` unless ``pose`` is given."""
        if not 0 <= parent < len(self.poses) or parent in self._continued:
            raise ValueError(f"node {parent} is not the last node of a trajectory")
        self._continued.add(parent)
        self.poses.append(pose if pose is not None else compose(self.poses[parent], z))
        self.parent.append(parent)
        self.measured.append(z)
        self.info.append(np.asarray(info, dtype=np.float64))
        return len(self.poses) - 1

    def add_loop(self, i: int, j: int, z: Pose, info: F64) -> None:
        """Node ``j`` seen at ``z`` from node ``i``: a robust edge."""
        n = len(self.poses)
        if not (0 <= i < n and 0 <= j < n) or i == j:
            raise ValueError(f"a loop edge needs two different nodes, got {i} and {j}")
        self.loops.append((i, j, z, np.asarray(info, dtype=np.float64)))

    # -- the least-squares problem -----------------------------------------------------------

    def _edges(self) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], F64, F64, npt.NDArray[np.bool_]]:
        """All relative edges (trajectory first, then loops): from, to, measurement, information, robust."""
        kids = [k for k, p in enumerate(self.parent) if p >= 0]
        i = [self.parent[k] for k in kids] + [e[0] for e in self.loops]
        j = kids + [e[1] for e in self.loops]
        z = [self.measured[k] for k in kids] + [e[2] for e in self.loops]
        w = [self.info[k] for k in kids] + [e[3] for e in self.loops]
        robust = np.zeros(len(i), dtype=bool)
        robust[len(kids) :] = True
        return (np.array(i, dtype=np.intp), np.array(j, dtype=np.intp), np.array(z, dtype=np.float64).reshape(-1, 3),
                np.array(w, dtype=np.float64).reshape(-1, 3, 3), robust)  # fmt: skip

    def optimise(self, iterations: int = 10) -> Stats:
        """Move the poses to the least robust-squares solution: Gauss-Newton from where they are,
        up to ``iterations`` steps with Huber's kernel on the loop edges and as many with
        Cauchy's. Returns what it took."""
        stats = Stats()
        if not self.poses:
            return stats
        problem = _Problem(self)
        x = np.array(self.poses, dtype=np.float64)
        stats.cost_before = problem.cost(x, "huber")
        for kernel in ("huber", "cauchy") if problem.robust.any() else ("huber",):
            cost = problem.cost(x, kernel)
            for _ in range(iterations):
                stats.iterations += 1
                step, used = problem.step(x, kernel)
                stats.cg_iterations += used
                t = 1.0
                for _ in range(6):  # backtrack while the (robust) cost does not fall
                    trial = x + t * step
                    trial[:, 2] = wrap(trial[:, 2])
                    trial_cost = problem.cost(trial, kernel)
                    if trial_cost < cost:
                        break
                    t *= 0.5
                else:
                    break
                x, cost = trial, trial_cost
                if float(np.abs(t * step).max()) < STEP_TOLERANCE:
                    break
            stats.cost_after = cost
        self.poses = [(float(p[0]), float(p[1]), float(p[2])) for p in x]
        return stats

    def loop_weights(self) -> F64:
        """Each loop edge's weight under Cauchy's kernel at the current poses: near 1 where the
        graph agrees with it, near 0 where it is contradicted."""
        problem = _Problem(self)
        s = problem.mahalanobis(np.array(self.poses, dtype=np.float64))
        return np.asarray(_weight(s, "cauchy"))[problem.robust]


def _weight(s: F64, kernel: str) -> F64:
    """The iteratively-reweighted least-squares weight of squared Mahalanobis residuals ``s``."""
    if kernel == "huber":
        return np.minimum(1.0, HUBER_SCALE / np.sqrt(np.maximum(s, 1e-300)))
    return np.asarray(1.0 / (1.0 + s / CAUCHY_SCALE**2))


def _rho(s: F64, kernel: str) -> F64:
    """The robust cost of squared Mahalanobis residuals ``s``."""
    if kernel == "huber":
        k = HUBER_SCALE
        return np.where(s <= k * k, s, 2.0 * k * np.sqrt(s) - k * k)
    c2 = CAUCHY_SCALE**2
    return np.asarray(c2 * np.log1p(s / c2))


class _Problem:
    """The graph's edges as arrays, and the chains its trajectories form (for the preconditioner)."""

    def __init__(self, g: PoseGraph) -> None:
        self.n = len(g.poses)
        self.i, self.j, self.z, self.info, self.robust = g._edges()
        parent = np.array(g.parent, dtype=np.intp)
        self.roots = np.flatnonzero(parent < 0)
        self.root_z = np.array([g.measured[k] for k in self.roots], dtype=np.float64).reshape(-1, 3)
        self.root_info = np.array([g.info[k] for k in self.roots], dtype=np.float64).reshape(-1, 3, 3)
        # trajectory of each node (its first node), and the nodes chain by chain
        traj = np.arange(self.n)
        for k in range(self.n):
            if parent[k] >= 0:
                traj[k] = traj[parent[k]]
        self.order = np.lexsort((np.arange(self.n), traj))
        self.chain = traj[self.order]  # trajectory of each position of the order
        self.parent = parent
        self.kids = np.flatnonzero(parent >= 0)  # the trajectory edges come first, in this order
        self.edge_of = np.full(self.n, -1, dtype=np.intp)
        self.edge_of[self.kids] = np.arange(len(self.kids))

    def mahalanobis(self, x: F64) -> F64:
        e, _, _ = _linearise(x, self.i, self.j, self.z)
        return np.asarray(np.einsum("mi,mij,mj->m", e, self.info, e))

    def cost(self, x: F64, kernel: str) -> float:
        s = self.mahalanobis(x)
        total = float(np.where(self.robust, _rho(s, kernel), s).sum())
        er = self._root_residual(x)
        return total + float(np.einsum("mi,mij,mj->", er, self.root_info, er))

    def _root_residual(self, x: F64) -> F64:
        er = x[self.roots] - self.root_z
        er[:, 2] = wrap(er[:, 2])
        return er

    def _scatter(self, ai: F64, bj: F64) -> F64:
        """Per node, the sum of ``ai`` over the edges from it and ``bj`` over the edges to it."""
        out = np.empty((self.n, 3))
        for c in range(3):
            out[:, c] = np.bincount(self.i, ai[:, c], self.n) + np.bincount(self.j, bj[:, c], self.n)
        return out

    def step(self, x: F64, kernel: str) -> tuple[F64, int]:
        """The Gauss-Newton step at ``x`` (iteratively reweighted for the robust edges), and the
        conjugate-gradient iterations it took (0 when solved directly)."""
        e, a, b = _linearise(x, self.i, self.j, self.z)
        s = np.einsum("mi,mij,mj->m", e, self.info, e)
        w = self.info * np.where(self.robust, _weight(s, kernel), 1.0)[:, None, None]
        we = np.einsum("mij,mj->mi", w, e)
        g = self._scatter(np.einsum("mji,mj->mi", a, we), np.einsum("mji,mj->mi", b, we))
        g[self.roots] += np.einsum("mij,mj->mi", self.root_info, self._root_residual(x))

        tree = self._tree(x, b)
        rhs = -g
        loops = np.flatnonzero(self.robust)
        if len(loops) == 0:
            return tree(rhs[:, :, None])[:, :, 0], 0
        if len(loops) <= DIRECT_LOOPS:
            return self._woodbury(tree, rhs, loops, a, b, w), 0
        return self._conjugate_gradients(tree, rhs, a, b, w)

    def _woodbury(self, tree: Callable[[F64], F64], rhs: F64, loops: npt.NDArray[np.intp], a: F64, b: F64,
                  w: F64) -> F64:  # fmt: skip
        """H⁻¹ rhs exactly, for H = T + U Uᵀ: T the trajectories' normal matrix (solved by
        ``tree``), U Uᵀ the loop edges' (each Jᵀ W J = (Jᵀ W½)(Jᵀ W½)ᵀ, three columns of U
        nonzero at its two nodes). Woodbury's identity leaves one dense system of three
        unknowns a loop edge: H⁻¹ = T⁻¹ - T⁻¹U (I + Uᵀ T⁻¹ U)⁻¹ Uᵀ T⁻¹."""
        m = len(loops)
        ie, je = self.i[loops], self.j[loops]
        root = np.linalg.cholesky(w[loops])  # W = R Rᵀ
        ua = np.einsum("eji,ejk->eik", a[loops], root)  # the rows of U at each edge's first node
        ub = np.einsum("eji,ejk->eik", b[loops], root)  # and at its second
        u = np.zeros((self.n, 3, 3 * m))
        cols = np.arange(3 * m).reshape(m, 3)
        u[ie[:, None, None], np.arange(3)[None, :, None], cols[:, None, :]] = ua
        u[je[:, None, None], np.arange(3)[None, :, None], cols[:, None, :]] = ub
        z = tree(u)  # T⁻¹ U
        capacitance = np.eye(3 * m) + (np.einsum("eji,ejk->eik", ua, z[ie]) +
                                       np.einsum("eji,ejk->eik", ub, z[je])).reshape(3 * m, 3 * m)  # fmt: skip
        y = tree(rhs[:, :, None])[:, :, 0]
        uty = (np.einsum("eji,ej->ei", ua, y[ie]) + np.einsum("eji,ej->ei", ub, y[je])).reshape(3 * m)
        return np.asarray(y - np.einsum("njk,k->nj", z, np.linalg.solve(capacitance, uty)))

    def _conjugate_gradients(self, tree: Callable[[F64], F64], rhs: F64, a: F64, b: F64,
                             w: F64) -> tuple[F64, int]:  # fmt: skip
        """H⁻¹ rhs by conjugate gradients preconditioned by ``tree``, and the iterations it took:
        for graphs with more loop edges than a dense system of theirs is worth."""

        def hessian_times(v: F64) -> F64:
            u = np.einsum("mij,mj->mi", a, v[self.i]) + np.einsum("mij,mj->mi", b, v[self.j])
            wu = np.einsum("mij,mj->mi", w, u)
            out = self._scatter(np.einsum("mji,mj->mi", a, wu), np.einsum("mji,mj->mi", b, wu))
            out[self.roots] += np.einsum("mij,mj->mi", self.root_info, v[self.roots])
            return out

        def precondition(r: F64) -> F64:
            return tree(r[:, :, None])[:, :, 0]

        sol = np.zeros_like(rhs)
        r = rhs.copy()
        zr = precondition(r)
        p = zr.copy()
        rz = float((r * zr).sum())
        limit = CG_TOLERANCE * float(np.sqrt((rhs * rhs).sum()))
        used = 0
        for used in range(1, CG_ITERATIONS + 1):  # noqa: B007 (the count is returned)
            hp = hessian_times(p)
            php = float((p * hp).sum())
            if php <= 0.0:
                break
            alpha = rz / php
            sol += alpha * p
            r -= alpha * hp
            if float(np.sqrt((r * r).sum())) <= limit:
                break
            zr = precondition(r)
            rz_next = float((r * zr).sum())
            p = zr + (rz_next / rz) * p
            rz = rz_next
        return sol, used

    def _tree(self, x: F64, b: F64) -> Callable[[F64], F64]:
        """The exact solver of the trajectories' own normal equations (the roots' priors and the
        trajectory edges), for any number of right-hand sides at once.

        Write u_k = A_k δ_parent + B_k δ_k for each trajectory edge (u = δ for a root): the
        trajectories' normal matrix is Lᵀ Ω L for that bidiagonal map L and the edges'
        informations Ω. For this residual -B_k⁻¹ A_k = [[I, perp(t_k - t_parent)], [0, 1]]:
        turning the parent by dθ swings the child by dθ times the lever arm between them,
        and nothing else. Solving with L and Lᵀ is then a running sum along each chain
        (forward for L, backward for Lᵀ) of the headings and of the translations plus lever
        arm times heading; in between, each node's 3x3 block (Bᵀ Ω B)⁻¹."""
        order, chain = self.order, self.chain
        info = self.info[self.edge_of[self.kids]]
        bk = b[self.edge_of[self.kids]]
        blocks = np.empty((self.n, 3, 3))
        blocks[self.kids] = np.linalg.inv(np.einsum("mji,mjk,mkl->mil", bk, info, bk))
        blocks[self.roots] = np.linalg.inv(self.root_info)
        lever = np.zeros((self.n, 2))  # perp(t_k - t_parent), zero for the roots
        d = x[self.kids, :2] - x[self.parent[self.kids], :2]
        lever[self.kids] = np.column_stack([-d[:, 1], d[:, 0]])
        lever_o = lever[order]
        blocks_o = blocks[order]
        first = np.ones(self.n, dtype=bool)
        first[1:] = chain[1:] != chain[:-1]

        def solve(r: F64) -> F64:  # r: n x 3 x k, k right-hand sides
            ro = r[order]
            k = r.shape[2]
            # backward: q_k = r_k + M_childᵀ q_child
            qt = _segment_sum(ro[::-1, :2], chain[::-1])[::-1]
            child_term = np.zeros((self.n, k))
            child_term[:-1] = np.where(first[1:, None], 0.0, (lever_o[1:, :, None] * qt[1:]).sum(axis=1))
            qth = _segment_sum((ro[:, 2] + child_term)[::-1], chain[::-1])[::-1]
            c = np.einsum("mij,mjk->mik", blocks_o, np.concatenate([qt, qth[:, None, :]], axis=1))
            # forward: y_k = c_k + M_k y_parent
            yth = _segment_sum(c[:, 2], chain)
            parent_th = np.zeros((self.n, k))
            parent_th[1:] = np.where(first[1:, None], 0.0, yth[:-1])
            yt = _segment_sum(c[:, :2] + lever_o[:, :, None] * parent_th[:, None, :], chain)
            out = np.empty_like(r)
            out[order] = np.concatenate([yt, yth[:, None, :]], axis=1)
            return out

        return solve


def _segment_sum(v: F64, seg: npt.NDArray[np.intp]) -> F64:
    """Running sums of ``v`` restarting wherever ``seg`` changes (segments are contiguous)."""
    total = np.cumsum(v, axis=0)
    start = np.ones(len(seg), dtype=bool)
    start[1:] = seg[1:] != seg[:-1]
    idx = np.maximum.accumulate(np.where(start, np.arange(len(seg)), 0))  # each position's segment start
    before = np.zeros_like(total)
    before[1:] = total[:-1]
    return np.asarray(total - before[idx])


def _linearise(x: F64, i: npt.NDArray[np.intp], j: npt.NDArray[np.intp], z: F64) -> tuple[F64, F64, F64]:
    """Residuals e = (R_z^T (R_i^T (t_j - t_i) - t_z), θ_j - θ_i - θ_z) and their Jacobians."""
    ci, si = np.cos(x[i, 2]), np.sin(x[i, 2])
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    dx, dy = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1]
    lx, ly = ci * dx + si * dy, -si * dx + ci * dy  # t_j - t_i in i's frame
    ex, ey = lx - z[:, 0], ly - z[:, 1]
    e = np.column_stack([cz * ex + sz * ey, -sz * ex + cz * ey, wrap(x[j, 2] - x[i, 2] - z[:, 2])])
    m = len(i)
    rot = np.empty((m, 2, 2))  # R_z^T R_i^T = R(-(θ_i + θ_z))
    c, s = np.cos(x[i, 2] + z[:, 2]), np.sin(x[i, 2] + z[:, 2])
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1] = c, s, -s, c
    # d(R_i^T (t_j - t_i)) / dθ_i = (ly, -lx)
    dth = np.column_stack([cz * ly - sz * lx, -sz * ly - cz * lx])
    a = np.zeros((m, 3, 3))
    b = np.zeros((m, 3, 3))
    a[:, :2, :2] = -rot
    a[:, :2, 2] = dth
    a[:, 2, 2] = -1.0
    b[:, :2, :2] = rot
    b[:, 2, 2] = 1.0
    return e, a, b
