"""Zenoh helpers that every adapter uses: knowing who listens, letting go of entities, and
whether this eclipse-zenoh has what they use."""

from __future__ import annotations

import re
import threading
from typing import Any

import zenoh

#: what simd uses of eclipse-zenoh that its first 1.x releases lack (1.4.0's wheel has none of
#: them; zenoh-python's advanced pub/sub, #537, and matching listeners, #557, came in 1.5.0)
REQUIRED_FEATURES = (
    ("zenoh.ext", "declare_advanced_publisher"),  # transient-local topics, as rmw_zenoh declares them
    ("zenoh.ext", "CacheConfig"),
    ("zenoh.ext", "MissDetectionConfig"),
    ("zenoh.Publisher", "declare_matching_listener"),  # messages built only for topics somebody reads (Interest)
)
#: the first release that also works: with 1.5.0 and 1.5.1, samples go missing through a router
#: (tests/ros2/test_record_ros.py recorded 9 of 60 odometries; after a daemon of a shared fleet
#: died, the /clock of the one that took over never reached a ROS subscriber in client mode,
#: tests/scaleout/test_ros2_shared.py); 1.6.1 passes both (there is no 1.6.0 for Python)
MINIMUM_ZENOH = "1.6.1"


def _release(text: str) -> tuple[int, ...]:
    """``1.6.1`` -> (1, 6, 1): the leading digits of each part (``1.7.0rc1`` -> (1, 7, 0))."""
    return tuple(int(m.group()) if (m := re.match(r"\d+", part)) else 0 for part in text.split(".")[:3])


def installed_zenoh() -> str | None:
    """The installed eclipse-zenoh's version, or None when the package metadata is missing."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("eclipse-zenoh")
    except PackageNotFoundError:
        return None


def missing_features() -> list[str]:
    """The names simd uses that this eclipse-zenoh lacks (empty: it has them all)."""
    import zenoh.ext

    owners = {"zenoh.ext": zenoh.ext, "zenoh.Publisher": zenoh.Publisher}
    return [f"{owner}.{name}" for owner, name in REQUIRED_FEATURES if not hasattr(owners[owner], name)]


def zenoh_too_old() -> str | None:
    """Why this eclipse-zenoh cannot run simd, in one line, or None if it can: checked before
    anything starts, so an old install is one line and not an AttributeError mid-spawn or
    samples that silently go missing."""
    missing = missing_features()
    installed = installed_zenoh()
    old = installed is not None and _release(installed) < _release(MINIMUM_ZENOH)
    if not missing and not old:
        return None
    why = f"without {', '.join(missing)}" if missing else "which loses samples through a router"
    return (f"simd needs eclipse-zenoh >= {MINIMUM_ZENOH} ({installed or 'unknown'} is installed, {why}): "
            f"pip install 'eclipse-zenoh>={MINIMUM_ZENOH},<2'")  # fmt: skip


def undeclare_all(entities: list[Any]) -> None:
    """Undeclare zenoh entities, going on past any that the session already dropped."""
    for ent in entities:
        try:
            ent.undeclare()
        except zenoh.ZError:
            pass
    entities.clear()


class Tally:
    """How many of a group of :class:`Interest` s match right now: one read tells a tick
    whether any robot's topic has a subscriber at all."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.count = 0

    def add(self, delta: int) -> None:
        with self._lock:
            self.count += delta

    def __bool__(self) -> bool:
        return self.count > 0


class Interest:
    """Whether some subscriber matches a publisher, kept current by zenoh's matching listener.

    Asking zenoh every tick costs little CPU but hands the GIL back and forth between the
    adapter's thread and the simulation's at every call; the listener's callback runs only
    when somebody arrives or leaves, and a tick just reads a bool. A :class:`Tally` given
    counts it while it matches.
    """

    def __init__(self, pub: zenoh.Publisher, tally: Tally | None = None) -> None:
        self._lock = threading.Lock()
        self._pub = pub
        self._tally = tally
        self.matching = False
        # on zenoh's own thread (it only sets a bool): a Python callback would get a thread of its
        # own, and the ROS adapter has four listeners per robot
        handler = zenoh.handlers.Callback(self._changed, None, indirect=False)
        self._listener = pub.declare_matching_listener(handler)  # first, so no change is missed
        self.refresh()

    def refresh(self) -> None:
        """Ask zenoh now. The listener's news of a subscriber comes a moment after zenoh knows
        of it (under load, after a request that follows the subscriber on the same link): a
        lockstep client that subscribes and then steps must get that step's ticks."""
        self._set(bool(self._pub.matching_status.matching))  # type: ignore[attr-defined]  # the stub says bool

    def _changed(self, status: zenoh.MatchingStatus) -> None:
        self._set(bool(status.matching))

    def _set(self, matching: bool) -> None:
        with self._lock:
            if matching == self.matching:
                return
            self.matching = matching
            if self._tally is not None:
                self._tally.add(1 if matching else -1)

    def __bool__(self) -> bool:
        return self.matching

    def undeclare(self) -> None:
        self._listener.undeclare()
        self._set(False)
