"""Robot name and namespace rules (ROS 2 single-token names).

Zenoh itself accepts spaces, unicode and dots in key chunks, so names are checked here,
once, before they ever become part of a key expression.
"""

from __future__ import annotations

import re

from protocol.errors import ErrorCode, FleetError

NAME_PATTERN = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
MAX_NAME_LENGTH = 64

#: Words that are control keys under the prefix (or could be confused with them); never a namespace.
RESERVED_WORDS = frozenset(
    {
        "spawn",
        "delete",
        "robots",
        "world",
        "clock",
        "sim",
        "odom",
        "scan",
        "cmd_vel",
        "alive",
        "odometry",  # the fleet topics P/odometry and P/scans
        "scans",
        "daemons",  # P/daemons and the daemons' liveliness tokens P/daemons/<id>
        "navigation",  # the fleet's navigation topic P/navigation
    }
)


def check_name(value: str, field: str = "name") -> str:
    """Return ``value`` if it is a valid robot name or namespace, else raise :class:`FleetError`."""
    if not isinstance(value, str):
        raise FleetError(ErrorCode.INVALID_NAME, f"{field} must be a string", field)
    if value == "":
        raise FleetError(ErrorCode.INVALID_NAME, f"{field} is empty", field)
    if len(value) > MAX_NAME_LENGTH:
        raise FleetError(
            ErrorCode.INVALID_NAME,
            f"{field} is {len(value)} characters long; the limit is {MAX_NAME_LENGTH}",
            field,
        )
    if NAME_PATTERN.fullmatch(value) is None:
        bad = next((c for c in value if not (c.isascii() and (c.isalnum() or c == "_"))), None)
        why = f"contains {bad!r}" if bad is not None else "must start with a letter"
        raise FleetError(
            ErrorCode.INVALID_NAME,
            f"{field} {value!r} {why}: use letters, digits and '_', starting with a letter",
            field,
        )
    if value in RESERVED_WORDS:
        raise FleetError(
            ErrorCode.RESERVED_NAME,
            f"{field} {value!r} is a reserved word ({', '.join(sorted(RESERVED_WORDS))})",
            field,
        )
    return value


def check_prefix(prefix: str) -> str:
    """A key prefix is one or more '/'-separated chunks of ``[A-Za-z0-9_-]``."""
    chunks = prefix.split("/")
    if not prefix or any(re.fullmatch(r"[A-Za-z0-9_\-]+", c) is None for c in chunks):
        raise ValueError(f"prefix {prefix!r} must be '/'-separated chunks of letters, digits, '_' or '-'")
    return prefix
