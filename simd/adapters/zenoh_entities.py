"""Zenoh helpers that every adapter uses: knowing who listens, and letting go of entities."""

from __future__ import annotations

from typing import Any

import zenoh


def undeclare_all(entities: list[Any]) -> None:
    """Undeclare zenoh entities, going on past any that the session already dropped."""
    for ent in entities:
        try:
            ent.undeclare()
        except zenoh.ZError:
            pass
    entities.clear()


class Interest:
    """Whether some subscriber matches a publisher, kept current by zenoh's matching listener.

    Asking zenoh every tick costs little CPU but hands the GIL back and forth between the
    adapter's thread and the simulation's at every call; the listener's callback runs only
    when somebody arrives or leaves, and a tick just reads a bool.
    """

    def __init__(self, pub: zenoh.Publisher) -> None:
        self._listener = pub.declare_matching_listener(self._changed)  # first, so no change is missed
        self.matching = bool(pub.matching_status.matching)  # type: ignore[attr-defined]  # the stub says bool

    def _changed(self, status: zenoh.MatchingStatus) -> None:
        self.matching = bool(status.matching)

    def __bool__(self) -> bool:
        return self.matching

    def undeclare(self) -> None:
        self._listener.undeclare()
