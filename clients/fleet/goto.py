"""``fleet goto``: send robots to places, follow them there, cancel them (the command's talk
with the daemon; the grammar is in fleet_args.py).

    fleet goto tb3_0 2.0 0.5                    # sent: the goal's id
    fleet goto tb3_0 2.0 0.5 --yaw 1.57 --wait  # live progress, exit 0 when reached
    fleet goto --cancel tb3_0
    fleet goto --file goals.yaml --wait         # - {robot: tb3_0, x: 2.0, y: 0.5}

With ``--wait`` the exit status says how the goal ended: 0 reached, 4 failed (the reason on
stderr in one line: ``fleet: tb3_0: failed: blocked: no way forward for 120 s``).
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
from pathlib import Path

import msgspec
import msgspec.yaml
import yaml

from clients.api import FleetClient
from clients.fleet.spawn_plan import UsageError
from clients.navigation import Goal
from fleetcommon.files import split_location, yaml_syntax_problem
from protocol.errors import FleetError
from protocol.navigation import NavigateRequest, NavigationFeedback, NavigationResult

EXIT_OK = 0
EXIT_REFUSED = 1
EXIT_FAILED = 4
#: the daemon's usual time to answer (``--timeout`` is the goal's time limit for goto)
ANSWER_S = 3.0


class GoalLine(msgspec.Struct, forbid_unknown_fields=True, frozen=True, kw_only=True):
    """One entry of a goals file."""

    robot: str
    x: float
    y: float
    yaw: float | None = None
    tolerance: float = 0.25
    yaw_tolerance: float = 0.25
    timeout: float = 0.0


def prepare(args: argparse.Namespace) -> list[tuple[str, NavigateRequest]] | None:
    """Check the command line; the goals to send (None for --cancel)."""
    args.goal_timeout = args.timeout
    args.timeout = ANSWER_S if args.timeout is None else min(ANSWER_S, args.timeout) if args.timeout > 0 else ANSWER_S
    if args.goal_timeout is not None and not (math.isfinite(args.goal_timeout) and args.goal_timeout > 0):
        raise UsageError(f"--timeout must be a positive number of seconds, got {args.goal_timeout:g}")
    if args.cancel:
        if args.words or args.file:
            raise UsageError("--cancel NS takes no other robot, place or file")
        return None
    if args.file:
        if args.words:
            raise UsageError("give a goals file or NS X Y, not both")
        return [
            (g.robot, _request(g.x, g.y, g.yaw, g.tolerance, g.yaw_tolerance, g.timeout)) for g in read_goals(args.file)
        ]
    if len(args.words) != 3:
        raise UsageError("expected NS X Y (the robot, then where to in metres), or --cancel NS, or --file GOALS")
    ns, xs, ys = args.words
    try:
        x, y = float(xs), float(ys)
    except ValueError:
        raise UsageError(f"X and Y must be numbers, got {xs!r} {ys!r}") from None
    return [(ns, _request(x, y, args.yaw, args.tolerance, args.yaw_tolerance, args.goal_timeout or 0.0))]


def _request(x: float, y: float, yaw: float | None, tol: float, yaw_tol: float, timeout: float) -> NavigateRequest:
    return NavigateRequest(x=x, y=y, yaw=yaw, tolerance=tol, yaw_tolerance=yaw_tol, timeout=timeout)


def read_goals(path: str) -> list[GoalLine]:
    """A goals file, strictly: one clear line on the first problem (file, location, reason)."""
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise UsageError(f"{path}: cannot read it: {e.strerror or e}") from None
    try:
        goals = msgspec.yaml.decode(text.encode(), type=list[GoalLine])
    except msgspec.ValidationError as e:
        reason, where = split_location(str(e))
        if not where or where == "$":
            reason = f"a goals file is a list of goals, as '- {{robot: tb3_0, x: 1.0, y: 2.0}}' ({reason})"
        raise UsageError(f"{path}: {where or '$'}: {reason}") from None
    except (msgspec.DecodeError, yaml.YAMLError) as e:
        reason, where = yaml_syntax_problem(e) if isinstance(e, msgspec.DecodeError) else (str(e), "")
        raise UsageError(f"{path}: {where}: {reason}" if where else f"{path}: {reason}") from None
    if not goals:
        raise UsageError(f"{path}: no goals in it")
    twice = {g.robot for g in goals if sum(h.robot == g.robot for h in goals) > 1}
    if twice:
        raise UsageError(
            f"{path}: robot {sorted(twice)[0]!r} has more than one goal (a second would replace the first)"
        )
    return goals


def run(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    if args.cancel:
        result = client.cancel_goal(args.cancel)
        print(
            f"{result.robot}: goal {result.goal_id} cancelled at ({result.pose.x:.2f}, {result.pose.y:.2f})", flush=True
        )
        return EXIT_OK
    assert isinstance(plan, list)
    if len(plan) == 1:
        robot, req = plan[0]
        goal = client.navigate(robot, req.x, req.y, req.yaw, tolerance=req.tolerance,
                               yaw_tolerance=req.yaw_tolerance, timeout=req.timeout)  # fmt: skip
        return _follow([goal], args)
    goals: list[Goal] = []
    refused = 0
    for robot, req in plan:
        try:
            goals.append(client.navigate(robot, req.x, req.y, req.yaw, tolerance=req.tolerance,
                                         yaw_tolerance=req.yaw_tolerance, timeout=req.timeout))  # fmt: skip
        except FleetError as e:
            print(f"fleet: {robot}: {e.code.value}: {e.message}", file=sys.stderr, flush=True)
            refused += 1
    code = _follow(goals, args)
    return EXIT_REFUSED if refused else code


def _follow(goals: list[Goal], args: argparse.Namespace) -> int:
    for g in goals:
        a = g.accepted
        assert a is not None
        print(
            f"{g.robot}: goal {g.goal_id} to ({a.goal.x:g}, {a.goal.y:g})"
            + (f", replacing {a.preempted}" if a.preempted else ""),
            flush=True,
        )
    if not args.wait:
        for g in goals:
            g.close()
        return EXIT_OK
    live = _Progress(sys.stdout.isatty())
    failed = 0
    lock = threading.Lock()
    results: list[NavigationResult] = []

    def wait(g: Goal) -> None:
        r = g.wait(on_feedback=live.show)
        with lock:
            results.append(r)
            live.clear()
            _ended(r)

    threads = [threading.Thread(target=wait, args=(g,), daemon=True) for g in goals]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    failed = sum(r.status != "reached" for r in results)
    return EXIT_FAILED if failed else EXIT_OK


def _ended(r: NavigationResult) -> None:
    if r.status == "reached":
        at = f"({r.pose.x:.2f}, {r.pose.y:.2f}, yaw {r.pose.yaw:.2f})"
        print(f"{r.robot}: reached {at} in {r.navigation_time:.1f} s, {r.distance_travelled:.2f} m driven", flush=True)
    else:
        print(f"fleet: {r.robot}: failed: {r.reason}: {r.message}", file=sys.stderr, flush=True)


class _Progress:
    """The latest feedback of each robot: one line rewritten in place on a terminal, a line per
    change of state otherwise (a log stays readable)."""

    def __init__(self, tty: bool) -> None:
        self.tty = tty
        self._lock = threading.Lock()
        self._last: dict[str, str] = {}

    def show(self, fb: NavigationFeedback) -> None:
        left = f"{fb.distance_remaining:.2f} m left, ~{fb.estimated_time_remaining:.0f} s"
        text = f"{fb.robot}: {fb.state}" + (f" for {fb.other}" if fb.other else "")
        text += f", {left}, {fb.navigation_time:.0f} s so far"
        with self._lock:
            if self.tty:
                sys.stdout.write("\r\033[K" + text)
                sys.stdout.flush()
            elif self._last.get(fb.robot) != fb.state:
                print(text, flush=True)
            self._last[fb.robot] = fb.state

    def clear(self) -> None:
        if self.tty:
            sys.stdout.write("\r\033[K")
            sys.stdout.flush()
