"""Which daemon owns a robot's name when several daemons share one fleet.

Rendezvous (highest random weight) hashing: every daemon scores every live daemon id against
the robot's name with the same stable hash and the highest score wins. Every daemon computes
the same winner with no coordination, the robots spread evenly over the daemons, and when a
daemon joins or leaves only the names it wins or loses change owner (a 1/N share), unlike a
hash modulo N. Chosen over regions of the world because it needs no configuration and holds
for any world and any fleet; a robot stays on the daemon that spawned it (docs/scale-out.md).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable


def score(daemon_id: str, name: str) -> bytes:
    """The stable weight of ``daemon_id`` for ``name`` (the same in every process and run)."""
    return hashlib.blake2b(f"{daemon_id}\0{name}".encode(), digest_size=8).digest()


def owner(name: str, daemons: Iterable[str]) -> str:
    """The daemon among ``daemons`` that places the robot called ``name``."""
    return max(daemons, key=lambda d: (score(d, name), d))
