"""The ROS domain a tool works in: ``--ros-domain-id``, else ``$ROS_DOMAIN_ID``, else 0.

rmw_zenoh makes the domain the first chunk of every key and token, so the daemon (``simd
--ros2``) and its clients (``fleet-record --source ros``) must read it the same way.
"""

from __future__ import annotations

from collections.abc import Mapping

#: the domain ids ROS 2 allows
MAX_DOMAIN_ID = 232


def domain_id(flag: int | None, env: Mapping[str, str]) -> int:
    """The domain from the flag, else the environment; ValueError with a one-line reason."""
    domain = flag
    if domain is None:
        raw = env.get("ROS_DOMAIN_ID", "").strip()
        try:
            domain = int(raw) if raw else 0
        except ValueError:
            raise ValueError(f"ROS_DOMAIN_ID must be a whole number, got {raw!r}") from None
    if not 0 <= domain <= MAX_DOMAIN_ID:
        raise ValueError(f"the ROS domain id must be in 0..{MAX_DOMAIN_ID}, got {domain}")
    return domain
