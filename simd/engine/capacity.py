"""What a tick costs here, and how many robots the daemon can keep at its target factor.

A simulator meets machines too small for its fleet; the user should learn the limit from the
daemon (``fleet clock``, the refusal of a spawn beyond ``--max-robots``, the warning when it
falls behind) before guessing it from a frozen viewer. What a tick costs is the CPU time the
whole daemon spends on it, not the simulation thread's time alone: the outbox encoding the
tick's messages and zenoh sending them take more than the physics, and compete with it.

That cost is close to a fixed part plus a part per robot. The fixed part is not only the loop
without robots: the first robot brings costs of its own that do not grow with the next ones
(a tick's messages are put at all, the navigator and the fleet topics run), and on a small
fleet they are most of the tick. Taking (tick − empty tick) / robots as the part per robot
counted them as per robot: four robots in ``./demo`` gave "about 81 robots keep real time" on
a machine that keeps a thousand. So the part per robot is the slope between two robot counts
the daemon has run, the smaller at most half the larger (a daemon's fleet grows through every
count as it is spawned); with no such pair, the old way, which errs on the side of fewer; and
below ``MIN_ROBOTS`` no estimate at all (capacity 0: not known), since the fixed costs of a
few robots swamp what each one adds. Moving averages, per robot count; an estimate for robots
like the ones it runs now, on this machine, under today's load: a measurement, not a promise.
"""

from __future__ import annotations

import math

from protocol.errors import ErrorCode, FleetError

#: Weight of the newest tick in the moving averages (about the last 50 ticks count).
ALPHA = 0.02
#: Ticks measured at a robot count before its average is used.
WARM_TICKS = 10
#: Fewer robots than this: no estimate (the fixed costs of having robots at all dominate).
MIN_ROBOTS = 20
#: Robot counts whose averages are kept (the newest; a fleet spawned one by one passes many).
KEPT_COUNTS = 64


class TickCost:
    """Moving averages of the CPU time of a tick (see the module docstring)."""

    def __init__(self) -> None:
        self.fixed_s: float | None = None  # a tick without robots
        self.last_s = 0.0  # the newest tick with robots
        self.mean_s = 0.0  # a tick with the robots there now (0: none measured)
        self._robots = 0
        self._by_count: dict[int, tuple[float, int]] = {}  # robots -> (mean seconds, ticks measured)

    def record(self, robots: int, seconds: float) -> None:
        """One tick of ``robots`` robots cost ``seconds`` of CPU time."""
        if robots == 0:
            self.fixed_s = seconds if self.fixed_s is None else self.fixed_s + ALPHA * (seconds - self.fixed_s)
            return
        mean, ticks = self._by_count.pop(robots, (seconds, 0))  # popped and put back: the newest last
        mean = seconds if ticks == 0 else mean + max(ALPHA, 1 / (ticks + 1)) * (seconds - mean)
        self._by_count[robots] = (mean, ticks + 1)
        while len(self._by_count) > KEPT_COUNTS:
            del self._by_count[next(iter(self._by_count))]
        if robots != self._robots:  # a spawn or delete: the mean restarts at the new count
            self._robots, self.mean_s = robots, seconds
        else:
            self.mean_s += ALPHA * (seconds - self.mean_s)
        self.last_s = seconds

    def per_robot(self) -> tuple[float, float] | None:
        """(fixed seconds, seconds per robot) of a tick of the robots there now, or None."""
        n = self._robots
        here = self._by_count.get(n)
        if n < MIN_ROBOTS or here is None or here[1] < WARM_TICKS:
            return None
        below = [m for m, (_, ticks) in self._by_count.items() if 0 < m <= n // 2 and ticks >= WARM_TICKS]
        if below:
            m = max(below)
            slope = (here[0] - self._by_count[m][0]) / (n - m)
            if slope > 0:
                return here[0] - slope * n, slope
        fixed = min(self.fixed_s or 0.0, here[0])  # no smaller fleet measured: errs on the side of fewer
        each = (here[0] - fixed) / n
        return (fixed, each) if each > 0 else None

    def capacity(self, period_s: float) -> int:
        """About how many robots like these fit in ticks of ``period_s`` wall seconds (0: not
        known, or fewer than ``MIN_ROBOTS`` run now)."""
        parts = self.per_robot()
        if parts is None:
            return 0
        fixed, each = parts
        return max(0, math.floor((period_s - fixed) / each))


def limit_refusal(limit: int, capacity: int) -> FleetError:
    """The refusal of a spawn beyond the robot limit, with the robots this machine keeps in
    real time when that is known."""
    said = f"the daemon's robot limit ({limit}) is reached"
    if capacity:
        said += f"; this machine keeps about {capacity} robots like these in real time (measured)"
    return FleetError(ErrorCode.ROBOT_LIMIT, said)
