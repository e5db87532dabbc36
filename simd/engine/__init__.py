"""The engine: the loop that owns the simulation, and the seam its adapters plug into."""

from simd.engine.engine import Engine
from simd.engine.ports import (
    Adapter,
    Deleted,
    Event,
    Reply,
    Result,
    RobotList,
    ScanRow,
    Spawned,
    StepResult,
    WorldReset,
)

__all__ = [
    "Adapter",
    "Deleted",
    "Engine",
    "Event",
    "Reply",
    "Result",
    "RobotList",
    "ScanRow",
    "Spawned",
    "StepResult",
    "WorldReset",
]
