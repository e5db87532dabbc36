"""Keeping the cyclic garbage collector off the daemon's long-lived objects.

Every robot brings a few dozen objects that live as long as it does: its pymunk body and
shapes (with their cffi handles and finalizers), its row, its records, its publishers. CPython's
collector walks all of them in every full collection, with every thread stopped: at 8 000
robots ~240 000 objects and 150 ms of CPU each time, and the ticks, the commands and the
replies made enough surviving objects for a full collection every one or two seconds while
running. On a machine shared with other work each one stopped the daemon for 170-700 ms, and
that, more than anything else, was the tail of every request's latency (bench.overload, with
a ``gc.callbacks`` probe).

So the daemon moves what has lived for a while out of the collector's sight (``gc.freeze``,
which only links lists: cheap at any heap size) about once a second; collections then walk only
what is newer. Freezing is the whole process's business, so only the daemon does it (a learning
environment's engine runs in the user's process and does not). Frozen objects are still freed
as soon as nothing refers to them; only garbage in reference cycles waits (a deleted robot's
body and shapes refer to each other). So once the robots spawned and deleted since the last full
collection make a quarter of the fleet (CPython's own rule for its oldest generation, with the
robots as the measure of the long-lived heap: counting the frozen objects walks them all, ~50 ms
at 8 000 robots), everything is thawed and collected once, then frozen again; and at least every
``COLLECT_EVERY_S`` for whatever else. With a fleet of steady size that is rare, and with robots
deleted and spawned all the time a full collection now and then instead of every second.

The youngest generation is sized to the fleet as well. A tick makes a few container objects a
robot (tuples, lists, the replies' and publications' arguments) that die within the tick, and
CPython collects its youngest generation every 700 objects made: a tick of 20 000 robots ran
~80 young collections, each walking every young object still alive, ~0.6 ms each, with the
GIL held. Under ``bench.overload`` at 20 000 robots that was 4.3 s of CPU in 49 s, and a
quarter of the whole list's latency. With room for ``YOUNG_PER_ROBOT`` objects a robot, what a
tick makes dies before the collector looks at it (one young collection in 30 s of running).
"""

from __future__ import annotations

import gc
import logging
import math
import time
from collections.abc import Callable

log = logging.getLogger(__name__)

#: How often what has survived since is frozen.
FREEZE_EVERY_S = 1.0
#: Robots spawned and deleted since the last full collection, as a share of the fleet then,
#: that make the next one due.
GROWTH = 0.25
#: Robots counted as the fleet at least (a small fleet's collections are short anyway).
MIN_FLEET = 64
#: The longest time between two full collections.
COLLECT_EVERY_S = 600.0
#: Room in the youngest generation, in objects a robot (never less than CPython's own 700).
YOUNG_PER_ROBOT = 4


class HeapKeeper:
    """Freezes the heap now and then, and collects it whole when the fleet has changed enough (the
    module docstring). :meth:`keep` is called from the engine's loop; it does nothing until due."""

    def __init__(
        self,
        every_s: float = FREEZE_EVERY_S,
        growth: float = GROWTH,
        collect_every_s: float = COLLECT_EVERY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.every_s = every_s
        self.growth = growth
        self.collect_every_s = collect_every_s
        self._clock = clock
        self._next = -math.inf
        self._collected: tuple[float, int, int] | None = None  # (when, robots, changes) at the last full collection
        self.full_collections = 0
        self._thresholds = gc.get_threshold()  # CPython's, given back at close

    def keep(self, robots: int, changes: int) -> None:
        """``robots``: the fleet's size; ``changes``: a count that grows by at least one with
        every robot spawned or deleted (the robot table's generation)."""
        now = self._clock()
        if now < self._next:
            return
        self._next = now + self.every_s
        self._size_young(robots)
        last = self._collected
        if (last is None or now - last[0] >= self.collect_every_s
                or changes - last[2] > self.growth * max(last[1], MIN_FLEET)):  # fmt: skip
            self.collect()
            self._collected = (now, robots, changes)
        else:
            gc.freeze()

    def _size_young(self, robots: int) -> None:
        """Room for what a tick of ``robots`` makes in the youngest generation (the module
        docstring)."""
        young, *older = self._thresholds
        wanted = max(young, YOUNG_PER_ROBOT * robots)
        if gc.get_threshold()[0] != wanted:
            gc.set_threshold(wanted, *older)

    def collect(self) -> None:
        """Thaw everything, collect it whole, freeze what is left."""
        t0 = time.perf_counter()
        gc.unfreeze()
        found = gc.collect()
        gc.freeze()
        self.full_collections += 1
        log.debug("full collection: %d unreachable, %.0f ms", found, (time.perf_counter() - t0) * 1e3)

    def close(self) -> None:
        """Give the frozen objects back to the collector, and its thresholds (the engine stops)."""
        gc.unfreeze()
        gc.set_threshold(*self._thresholds)
