"""What a tick costs here, and how many robots the daemon can keep at its target factor.

A simulator meets machines too small for its fleet; the user should learn the limit from the
daemon (``fleet clock``, the refusal of a spawn beyond ``--max-robots``, the warning when it
falls behind) before guessing it from a frozen viewer. What a tick costs is the CPU time the
whole daemon spends on it, not the simulation thread's time alone: the outbox encoding the
tick's messages and zenoh sending them take more than the physics, and compete with it. That
is close to a fixed part (the loop, the clock, zenoh's own upkeep) plus a part per robot
(physics, lidar, encoding and sending its messages), so the daemon keeps both as moving
averages: the fixed part from the ticks it runs without robots (a daemon starts empty), the
part per robot from every other tick, net of the fixed part. The estimate is for robots like
the ones it runs now, on this machine, under today's load (counting zenoh's threads, which
may run on another core, errs on the side of fewer robots): a measurement, not a promise.
"""

from __future__ import annotations

import math

from protocol.errors import ErrorCode, FleetError

#: Weight of the newest tick in the moving averages (about the last 50 ticks count).
ALPHA = 0.02
#: Ticks measured with robots before the estimate is given.
WARM_TICKS = 10


class TickCost:
    """Moving averages of the CPU time of a tick (see the module docstring)."""

    def __init__(self) -> None:
        self.fixed_s: float | None = None  # a tick without robots
        self.per_robot_s: float | None = None
        self.last_s = 0.0  # the newest tick with robots
        self.mean_s = 0.0  # a tick with the robots there now (0: none measured)
        self._robots = 0
        self._measured = 0  # ticks with robots

    def record(self, robots: int, seconds: float) -> None:
        """One tick of ``robots`` robots cost ``seconds`` of CPU time."""
        if robots == 0:
            self.fixed_s = seconds if self.fixed_s is None else self.fixed_s + ALPHA * (seconds - self.fixed_s)
            return
        fixed = min(self.fixed_s or 0.0, seconds)
        each = (seconds - fixed) / robots
        self.per_robot_s = each if self.per_robot_s is None else self.per_robot_s + ALPHA * (each - self.per_robot_s)
        if robots != self._robots:  # a spawn or delete: the mean restarts at the new count
            self._robots, self.mean_s = robots, seconds
        else:
            self.mean_s += ALPHA * (seconds - self.mean_s)
        self.last_s = seconds
        self._measured += 1

    def capacity(self, period_s: float) -> int:
        """About how many robots like these fit in ticks of ``period_s`` wall seconds (0: not
        known yet)."""
        if self.per_robot_s is None or self.per_robot_s <= 0 or self._measured < WARM_TICKS:
            return 0
        spare = period_s - (self.fixed_s or 0.0)
        return max(0, math.floor(spare / self.per_robot_s))


def limit_refusal(limit: int, capacity: int) -> FleetError:
    """The refusal of a spawn beyond the robot limit, with the robots this machine keeps in
    real time when that is known."""
    said = f"the daemon's robot limit ({limit}) is reached"
    if capacity:
        said += f"; this machine keeps about {capacity} robots like these in real time (measured)"
    return FleetError(ErrorCode.ROBOT_LIMIT, said)
