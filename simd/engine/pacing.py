"""Keeping time: when the next tick is due, the real-time factor achieved, and whether the
loop is falling behind its target.

Ticks are due on a grid of wall-clock deadlines that starts one period after time starts
running (the daemon starts, a resume, a reset), so the sim clock never leads the wall clock
(times the target factor) since that moment: a resume after a long pause is not a burst of
the ticks the pause "owed". Ticks late by up to ``CATCH_UP_TICKS`` periods are caught up (the
OS wakes us a little late all the time, a garbage collection or a tick with every robot's
scan takes two or three periods, and the grid must not drift for them: a machine that keeps
real time on average holds it); later than that the grid moves instead (the schedule slips),
so a loop that cannot keep up runs its ticks back to back, evenly, slower than real time,
and never bursts to catch up on more than those few ticks. What it lost is counted
(:attr:`Pacer.behind_s`) and the clock reply says so.

:class:`LagWatch` turns the measured factor into one warning when the loop starts falling
behind and one line when it recovers, with hysteresis (it enters below ``ENTER_BELOW`` of the
target and leaves above ``LEAVE_ABOVE``) and a floor between warnings, so a daemon that
hovers at the edge does not fill its log.
"""

from __future__ import annotations

import collections
import logging
from collections.abc import Callable
from dataclasses import dataclass, field

from simd.engine.capacity import TickCost

log = logging.getLogger(__name__)

#: The factor is measured over about this much wall time, from points at least
#: ``RTF_SPACING_S`` apart (an unpaced daemon ticks thousands of times a second).
RTF_WINDOW_S = 2.0
RTF_SPACING_S = RTF_WINDOW_S / 500
#: Falling behind: the achieved factor below this share of the target, measured over at
#: least ``JUDGE_AFTER_S`` of running; recovered: above ``LEAVE_ABOVE`` of it.
ENTER_BELOW = 0.9
LEAVE_ABOVE = 0.97
JUDGE_AFTER_S = 1.0
#: At most one "falling behind" warning this often; episodes between are counted in the next.
WARN_EVERY_S = 60.0
#: Lateness (in periods) that is caught up rather than slipped: with one period, 1 000
#: navigating robots, whose ticks take about three quarters of a period on average, ran at
#: 0.955 of real time; the engine caught up five before the grid and held 1.00.
CATCH_UP_TICKS = 5


@dataclass
class RtfMeter:
    """Sim seconds per wall second over about the last ``RTF_WINDOW_S`` of wall time."""

    window: collections.deque[tuple[float, float]] = field(default_factory=collections.deque)

    def restart(self, wall: float, sim_time: float) -> None:
        """Time starts running from here: the next tick already gives a measurement."""
        self.window.clear()
        self.window.append((wall, sim_time))

    def record(self, wall: float, sim_time: float) -> None:
        w = self.window
        if len(w) >= 2 and wall - w[-2][0] < RTF_SPACING_S:
            w[-1] = (wall, sim_time)  # close to the point before it: the newest point moves
        else:
            w.append((wall, sim_time))
        while len(w) > 2 and wall - w[1][0] >= RTF_WINDOW_S:
            w.popleft()

    def span(self) -> float:
        """The wall time the measurement covers."""
        return self.window[-1][0] - self.window[0][0] if self.window else 0.0

    def measure(self) -> float | None:
        """The measured factor, or None before two points (right after a resume)."""
        if len(self.window) < 2:
            return None
        (w0, s0), (w1, s1) = self.window[0], self.window[-1]
        return (s1 - s0) / (w1 - w0) if w1 > w0 else None


class Pacer:
    """The wall-clock deadline of the next tick for a target factor (see the module
    docstring); ``rtf`` 0 runs unpaced, every tick due at once."""

    def __init__(self, dt: float, rtf: float) -> None:
        self.period = dt / rtf if rtf > 0 else 0.0
        self.rtf = rtf
        self.next = 0.0
        self._slipped = 0.0  # wall seconds the grid moved since time last started

    def start(self, now: float) -> None:
        """Time starts running now: the first tick is due one period from now."""
        self.next = now + self.period
        self._slipped = 0.0

    def wait(self, now: float) -> float:
        """Wall seconds until the next tick is due (0: due now)."""
        return max(0.0, self.next - now)

    def due(self, now: float) -> bool:
        return now >= self.next

    def ticked(self, now: float) -> None:
        """A tick has run (``now`` is when it ended): the next one is due a period after the
        last deadline, or now if that is more than ``CATCH_UP_TICKS`` periods gone (the grid
        slips, no burst)."""
        self.next += self.period
        late = now - self.next
        if self.period > 0 and late > CATCH_UP_TICKS * self.period:
            self._slipped += late
            self.next = now

    @property
    def slipped_s(self) -> float:
        """Wall seconds the grid moved since time last started."""
        return self._slipped

    def behind_s(self, now: float) -> float:
        """Sim seconds the clock is behind where the target factor would have it since time
        last started (the lost wall time times the factor; a tick's phase is not lost)."""
        if self.period <= 0:
            return 0.0
        return (self._slipped + max(0.0, now - self.next - self.period)) * self.rtf


class LagWatch:
    """Whether the loop is falling behind, and the log lines that say so (module docstring)."""

    def __init__(self) -> None:
        self.behind = False
        self._warned_at = -float("inf")
        self._warned = False  # the current episode was logged (so its end is logged too)
        self._unlogged = 0  # episodes since the last warning that were not logged

    def judge(
        self, now: float, measured: float | None, span: float, target: float, why: Callable[[], str] = str
    ) -> None:
        """Look at the factor achieved (over ``span`` wall seconds) against the target; ``why``
        says what the warning adds (asked only for a warning: this runs every tick)."""
        if target <= 0 or measured is None or span < JUDGE_AFTER_S:
            return
        if not self.behind and measured < ENTER_BELOW * target:
            self.behind = True
            if now - self._warned_at >= WARN_EVERY_S:
                more = f" ({self._unlogged} more episodes since the last warning)" if self._unlogged else ""
                log.warning("falling behind: running at %.2fx of the target %gx%s%s", measured, target, why(), more)
                self._warned_at, self._warned, self._unlogged = now, True, 0
            else:
                self._warned = False
                self._unlogged += 1
        elif self.behind and measured > LEAVE_ABOVE * target:
            self._end(f"caught up: running at {measured:.2f}x of the target {target:g}x again")

    def stopped(self, why: str) -> None:
        """Time stopped (a pause) or started again (a resume, a reset): an episode ends."""
        if self.behind:
            self._end(f"no longer falling behind: {why}")

    def _end(self, line: str) -> None:
        if self._warned:
            log.warning("%s", line)
        self.behind = self._warned = False


class Timekeeper:
    """The loop's time and load in one place: when ticks are due (:class:`Pacer`), the factor
    achieved (:class:`RtfMeter`), whether it falls behind (:class:`LagWatch`), and what a tick
    costs (:class:`~simd.engine.capacity.TickCost`, from the whole process's CPU time between
    two ticks while time runs on)."""

    def __init__(self, dt: float, rtf: float, cpu_clock: Callable[[], float] | None) -> None:
        """``cpu_clock``: the whole process's CPU time (None: no tick costs measured, for an
        engine in a learner's process that nobody asks its capacity)."""
        self.dt = dt
        self.rtf = rtf
        self.pacer = Pacer(dt, rtf)
        self.meter = RtfMeter()
        self.lag = LagWatch()
        self.cost = TickCost()
        self._cpu = cpu_clock
        self._cpu_mark: float | None = None  # at the end of the last tick while time runs on

    def start(self, now: float, sim_time: float) -> None:
        """Time starts running now (the start, a resume, a reset): the first tick is due a
        period from now, and the factor is measured from here."""
        self.pacer.start(now)
        self.meter.restart(now, sim_time)
        self._cpu_mark = None

    def idle(self) -> None:
        """The loop waits (paused, between steps): the next tick's cost counts from the tick."""
        self._cpu_mark = None

    def tick_cost(self, robots: int) -> None:
        """What the daemon spent since the last tick, all its threads (the outbox encoding and
        zenoh sending this tick's messages take more than the physics): the tick's cost, while
        time runs on (the first tick after time stood still would count the idle wait)."""
        if self._cpu is None:
            return
        now = self._cpu()
        if self._cpu_mark is not None:
            self.cost.record(robots, now - self._cpu_mark)
        self._cpu_mark = now

    def ticked(self, now: float, why: Callable[[], str]) -> None:
        """A paced tick ended at ``now``: the next deadline, and whether the loop falls behind."""
        self.pacer.ticked(now)
        self.lag.judge(now, self.meter.measure(), self.meter.span(), self.rtf, why)

    def capacity(self) -> int:
        """About how many robots like these keep real time here (0: not known yet)."""
        return self.cost.capacity(self.dt)

    def load(self, robots: int) -> str:
        """What the warning of a loop falling behind says of its load."""
        cost = self.cost.mean_s
        if not robots or not cost:
            return ""
        said = f"; {robots} robots, a tick takes {cost * 1e3:.1f} ms of the {self.pacer.period * 1e3:.1f} ms it may"
        cap = self.capacity()
        return said + (f" (about {cap} robots like these keep real time here)" if cap else "")
