"""Each robot's goal, navigation state and planned path as the viewer keeps them, and the
``nav`` messages that bring them to pages.

Three sources, all of them zenoh callbacks: the fleet's summary ``P/navigation`` (2 Hz of sim
time: every navigating robot's goal and state, and goals that ended since the last one), the
paths ``P/<ns>/plan`` (put each time a robot plans, empty when its goal ends) and the results
``P/<ns>/navigate/result`` (once per goal, always put: the summary's row of an ended goal can
be missed, a result cannot). A viewer opened mid-goal asks for the current paths once
(:meth:`NavBoard.initial_plans`); a path heard live since is newer and wins.

Pages get deltas. Every change of a robot's row or path takes a new version from one counter;
a page's :class:`NavCursor` holds the versions it was sent, so a message carries only what
changed since (``null`` for what went away), and nothing at all while nothing changed. At 1 000
navigating robots that is the rows whose state changed and the paths that were planned again,
not the fleet twice a second. Rows and paths are encoded once per version, whatever the number
of pages. Distance left is not sent: the page measures it along the path it has, at its own
frame rate.

An ended goal (``reached``/``failed``) stays ENDED_KEEP_S wall seconds with that state, so
pages can flash the robot, then goes; its path goes at once.

Messages are data from the network, drawn but never trusted: rows whose goal is not a finite
point are dropped, strings are cut short, tolerances clamped, paths thinned
(:func:`~clients.viewer.decimate.thin_path`). The board holds no lock of its own:
:class:`~clients.viewer.state.FleetState` calls it under its lock, for present robots only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import msgspec
import numpy as np

from fleetcommon.arrays import F64
from protocol.navigation import NavigationPath, NavigationResult, RobotNavigation

ENDED_STATES = frozenset({"reached", "failed"})
ENDED_KEEP_S = 1.5  # wall seconds an ended goal stays on pages (they flash the robot)
MAX_TEXT = 64  # characters kept of a goal id, a state, a robot name or a reason
MAX_TOLERANCE_M = 100.0


def _text(s: str) -> str:
    return s[:MAX_TEXT]


def _finite(v: float) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)


@dataclass
class NavRow:
    """One robot's goal and what it is doing about it."""

    goal_id: str
    state: str
    x: float
    y: float
    yaw: float | None  # None: any heading will do
    tolerance: float
    other: str = ""
    reason: str = ""
    version: int = 0
    ended_at: float | None = None  # wall clock (time.monotonic) of the end, for the flash
    raw: msgspec.Raw = field(default_factory=msgspec.Raw)

    @property
    def ended(self) -> bool:
        return self.ended_at is not None

    def key(self) -> tuple[object, ...]:
        return (self.goal_id, self.state, self.x, self.y, self.yaw, self.tolerance, self.other, self.reason)

    def encode(self) -> None:
        yaw = None if self.yaw is None else round(self.yaw, 4)
        xy_tol = [round(self.x, 3), round(self.y, 3), yaw, round(self.tolerance, 3)]
        self.raw = msgspec.Raw(msgspec.json.encode([self.goal_id, self.state, *xy_tol, self.other, self.reason]))


@dataclass
class NavPath:
    """One robot's planned path, thinned, as pages get it (flat x0, y0, x1, y1, ... in mm)."""

    goal_id: str
    points: int
    version: int
    raw: msgspec.Raw


@dataclass(frozen=True)
class GoalView:
    """One goal under way as a still picture draws it (clients/viewer/snapshot.py)."""

    x: float
    y: float
    yaw: float | None  # None: any heading will do
    tolerance: float
    state: str
    path: list[tuple[float, float]]  # thinned, the robot first, the goal last; empty if none heard


@dataclass
class NavCursor:
    """What one page was sent: the board's counter then, and each robot's row and path version."""

    seq: int = -1
    goals: dict[str, int] = field(default_factory=dict)
    paths: dict[str, int] = field(default_factory=dict)


def row_of(r: RobotNavigation) -> NavRow | None:
    """The row a summary's entry makes, or None if it names no drawable goal."""
    g = r.goal
    if not (_finite(g.x) and _finite(g.y)):
        return None
    tol = r.tolerance if _finite(r.tolerance) else 0.0
    return NavRow(
        goal_id=_text(r.goal_id),
        state=_text(r.state),
        x=float(g.x),
        y=float(g.y),
        yaw=float(g.yaw) if r.has_yaw and _finite(g.yaw) else None,
        tolerance=min(MAX_TOLERANCE_M, max(0.0, float(tol))),
        other=_text(r.other),
        reason=_text(r.reason),
    )


class NavBoard:
    """The goals and paths of the robots that navigate (see the module docstring)."""

    def __init__(self) -> None:
        self._seq = 0
        self.goals: dict[str, NavRow] = {}
        self.paths: dict[str, NavPath] = {}
        self._heard: set[str] = set()  # robots whose paths were heard live (a get reply is older)
        self._ending = 0  # rows kept for their flash

    @property
    def seq(self) -> int:
        return self._seq

    def _bump(self) -> int:
        self._seq += 1
        return self._seq

    # -- in ----------------------------------------------------------------------------------------

    def summary_row(self, ns: str, entry: RobotNavigation, now: float) -> None:
        """One robot's row of ``P/navigation``."""
        row = row_of(entry)
        if row is None:
            return
        old = self.goals.get(ns)
        if entry.reason or row.state in ENDED_STATES:
            if old is not None and old.goal_id == row.goal_id and not old.ended:
                self._end(ns, old, row.state if row.state in ENDED_STATES else "failed", row.reason, now)
            return  # the end of a goal this viewer never saw: nothing to draw
        if old is not None and old.goal_id == row.goal_id and old.ended:
            return  # its result came first (another key): an end is final
        if old is not None and old.key() == row.key():
            return
        if old is not None and old.goal_id != row.goal_id:
            self._drop_path(ns, lambda goal_id: goal_id != row.goal_id)  # a path of the goal it replaced
        self._set(ns, row)

    def result(self, ns: str, result: NavigationResult, now: float) -> None:
        """A goal ended (``P/<ns>/navigate/result``)."""
        goal_id = _text(result.goal_id)
        if result.reason == "preempted":  # a newer goal replaced it: that one is drawn next
            self._drop_path(ns, lambda g: g == goal_id)
            return
        old = self.goals.get(ns)
        status = result.status if result.status in ENDED_STATES else "failed"
        if old is None:
            g = result.goal
            if not (_finite(g.x) and _finite(g.y)):
                return
            old = NavRow(goal_id, status, float(g.x), float(g.y), None, 0.0)
            self._set(ns, old)
        elif old.goal_id != goal_id or old.ended:
            return  # the goal this one replaced, or told twice
        self._end(ns, old, status, _text(result.reason), now)

    def plan(self, ns: str, path: NavigationPath, thinned: F64) -> None:
        """A path the robot planned (``thinned`` by the caller, off the lock), or none."""
        self._heard.add(ns)
        goal_id = _text(path.goal_id)
        if len(thinned) == 0:
            self._drop_path(ns, lambda g: g == goal_id)
            return
        row = self.goals.get(ns)
        if row is not None and row.goal_id == goal_id and row.ended:
            return  # late: the goal is over
        self._put_path(ns, goal_id, thinned)

    def initial_plans(self, paths: dict[str, tuple[NavigationPath, F64]]) -> None:
        """The paths a get returned, for robots that have none heard live."""
        for ns, (path, thinned) in paths.items():
            if ns not in self._heard and ns not in self.paths and len(thinned):
                row = self.goals.get(ns)
                if row is None or not row.ended:
                    self._put_path(ns, _text(path.goal_id), thinned)

    def forget(self, ns: str) -> None:
        """The robot is gone."""
        row = self.goals.pop(ns, None)
        if row is not None and row.ended:
            self._ending -= 1
        had_path = self.paths.pop(ns, None) is not None
        if row is not None or had_path:
            self._bump()
        self._heard.discard(ns)

    def prune(self, now: float) -> None:
        """Drop the ended goals whose flash is over."""
        if not self._ending:
            return
        for ns, row in list(self.goals.items()):
            if row.ended_at is not None and now - row.ended_at >= ENDED_KEEP_S:
                del self.goals[ns]
                self._ending -= 1
                self._bump()

    # -- the changes ------------------------------------------------------------------------------

    def _set(self, ns: str, row: NavRow) -> None:
        old = self.goals.get(ns)
        if old is not None and old.ended:
            self._ending -= 1
        row.version = self._bump()
        row.encode()
        self.goals[ns] = row

    def _end(self, ns: str, row: NavRow, status: str, reason: str, now: float) -> None:
        row.state, row.reason, row.other = status, reason or status, ""
        row.ended_at = now
        row.version = self._bump()
        row.encode()
        self._ending += 1
        self._drop_path(ns, lambda g: g == row.goal_id)

    def _put_path(self, ns: str, goal_id: str, thinned: F64) -> None:
        flat = np.round(thinned.reshape(-1), 3).tolist()
        self.paths[ns] = NavPath(goal_id, len(thinned), self._bump(), msgspec.Raw(msgspec.json.encode(flat)))

    def _drop_path(self, ns: str, which: Callable[[str], bool]) -> None:
        """Drop the robot's path if ``which`` says so of its goal id."""
        p = self.paths.get(ns)
        if p is not None and which(p.goal_id):
            del self.paths[ns]
            self._bump()

    # -- out ----------------------------------------------------------------------------------------

    def under_way(self) -> dict[str, GoalView]:
        """The goals that have not ended, with their paths (what a snapshot draws)."""
        out = {}
        for ns, row in self.goals.items():
            if row.ended:
                continue
            p = self.paths.get(ns)
            flat = msgspec.json.decode(p.raw) if p is not None and p.goal_id == row.goal_id else []
            path = [(float(flat[i]), float(flat[i + 1])) for i in range(0, len(flat) - 1, 2)]
            out[ns] = GoalView(row.x, row.y, row.yaw, row.tolerance, row.state, path)
        return out

    def updates(self, cursor: NavCursor) -> bytes | None:
        """A ``nav`` message with what changed since ``cursor`` (which it advances), or None."""
        if cursor.seq == self._seq:
            return None
        goals = _delta({ns: (r.version, r.raw) for ns, r in self.goals.items()}, cursor.goals)
        paths = _delta({ns: (p.version, p.raw) for ns, p in self.paths.items()}, cursor.paths)
        cursor.seq = self._seq
        if not goals and not paths:
            return None
        return msgspec.json.encode({"type": "nav", "goals": goals, "paths": paths})

    def counts(self) -> dict[str, int]:
        """Robots per navigation state (ended goals still flashing included)."""
        out: dict[str, int] = {}
        for r in self.goals.values():
            out[r.state] = out.get(r.state, 0) + 1
        return out


def _delta(now: dict[str, tuple[int, msgspec.Raw]], sent: dict[str, int]) -> dict[str, msgspec.Raw | None]:
    """What changed from ``sent`` (updated in place) to ``now``: new versions, and None for gone."""
    out: dict[str, msgspec.Raw | None] = {}
    for ns, (version, raw) in now.items():
        if sent.get(ns) != version:
            out[ns] = raw
            sent[ns] = version
    for ns in [ns for ns in sent if ns not in now]:
        out[ns] = None
        del sent[ns]
    return out
