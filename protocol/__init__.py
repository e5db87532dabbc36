"""fleetsim wire protocol: messages, control requests, key space, names, errors, codec.

Shared by the daemon and every client. See ``docs/protocol.md`` for the key-by-key reference.
"""

from protocol.codec import decode, encode, sniff_format
from protocol.control import (
    MODELS,
    Bounds,
    Circle,
    Clock,
    DeleteRequest,
    EmptyRequest,
    Frames,
    ModelLimits,
    Pose2D,
    ResetRequest,
    RobotList,
    RobotRecord,
    SpawnRequest,
    StepRequest,
    Topics,
    WorldInfo,
)
from protocol.errors import ErrorCode, ErrorReply, FleetError
from protocol.keys import DEFAULT_PREFIX, Keys
from protocol.messages import (
    Header,
    LaserScan,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    Quaternion,
    Time,
    Twist,
    TwistWithCovariance,
    Vector3,
)
from protocol.names import MAX_NAME_LENGTH, RESERVED_WORDS, check_name

__all__ = [
    "DEFAULT_PREFIX",
    "MAX_NAME_LENGTH",
    "MODELS",
    "RESERVED_WORDS",
    "Bounds",
    "Circle",
    "Clock",
    "DeleteRequest",
    "EmptyRequest",
    "ErrorCode",
    "ErrorReply",
    "FleetError",
    "Frames",
    "Header",
    "Keys",
    "LaserScan",
    "ModelLimits",
    "Odometry",
    "Point",
    "Pose",
    "Pose2D",
    "PoseWithCovariance",
    "Quaternion",
    "ResetRequest",
    "RobotList",
    "RobotRecord",
    "SpawnRequest",
    "StepRequest",
    "Time",
    "Topics",
    "Twist",
    "TwistWithCovariance",
    "Vector3",
    "WorldInfo",
    "check_name",
    "decode",
    "encode",
    "sniff_format",
]
