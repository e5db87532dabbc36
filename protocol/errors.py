"""Structured errors shared by the daemon and every client.

Every refusal travels as an :class:`ErrorReply`: a stable machine-readable ``code`` that
programs switch on, and a ``message`` written for a person. Codes never change meaning;
new ones may be added.
"""

from __future__ import annotations

import enum

import msgspec


class ErrorCode(str, enum.Enum):
    """Stable error codes. The string values are the wire form."""

    MALFORMED = "malformed"  # payload is not valid MessagePack/JSON for the request type
    INVALID_NAME = "invalid_name"  # name/namespace breaks the ROS 2 token rules
    RESERVED_NAME = "reserved_name"  # name/namespace is one of the control words
    ALREADY_EXISTS = "already_exists"  # name or namespace already used by a live robot
    UNKNOWN_MODEL = "unknown_model"  # model is not burger, waffle or waffle_pi
    NON_FINITE = "non_finite"  # NaN or infinity where a number is required
    OUT_OF_BOUNDS = "out_of_bounds"  # pose (footprint) leaves the world bounds
    COLLISION = "collision"  # footprint overlaps a wall, obstacle or robot
    ROBOT_LIMIT = "robot_limit"  # the daemon's --max-robots is reached
    NOT_FOUND = "not_found"  # no robot by that name or namespace
    INVALID_VALUE = "invalid_value"  # a field is out of its allowed range
    NOT_ALLOWED = "not_allowed"  # request not valid in the current mode (e.g. step while running)
    BUSY = "busy"  # the daemon's request queue is full; retry later
    TOO_LARGE = "too_large"  # the payload exceeds the key's size limit
    INTERNAL = "internal"  # the daemon's own bug (never bad input): please report it
    TIMEOUT = "timeout"  # client side: no reply within the deadline
    UNAVAILABLE = "unavailable"  # client side: no daemon answered


class ErrorReply(msgspec.Struct, kw_only=True):
    """What an error reply carries on the wire."""

    code: ErrorCode
    message: str
    field: str | None = None


class FleetError(Exception):
    """An error with a stable code; raised by the core, mapped to ``reply_err`` by the network layer."""

    def __init__(self, code: ErrorCode, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        self.field = field

    def to_reply(self) -> ErrorReply:
        return ErrorReply(code=self.code, message=self.message, field=self.field)

    @classmethod
    def from_reply(cls, reply: ErrorReply) -> FleetError:
        return cls(reply.code, reply.message, reply.field)

    def __str__(self) -> str:
        return f"{self.code.value}: {self.message}"

    def __repr__(self) -> str:
        return f"FleetError({self.code.value!r}, {self.message!r}, field={self.field!r})"


def not_found(key: str) -> FleetError:
    """No robot has this name or namespace, in Gazebo's words (scripts match on them)."""
    return FleetError(ErrorCode.NOT_FOUND, f"Entity [{key}] does not exist", "name")
