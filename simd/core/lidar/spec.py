"""The lidar's layout (:class:`LidarSpec`) and the tolerances and sizes both kernels share.

Every number here is part of the contract between the numpy kernel and its compiled twin: the
C kernel receives them as arguments (native_kernel.py), so they are defined once.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from fleetcommon.arrays import F64

TWO_PI = 2.0 * np.pi

# Padding (rad) added to both ends of a primitive's angular interval before it is turned into
# beam indices.  Segment bearings are computed in float32 (a pure speed choice): input rounding,
# atan2 and the shift into beam units add up to < 3e-6 rad, so 2e-5 rad is a safe margin, and
# only adds a beam to ~0.2% of the runs.  The exact float64 per-beam test decides hits.
EPS_ANGLE = 2e-5

# The native kernel takes bearings in float64 (error < 2e-10 rad) and pads by this much more, so
# that it tests every beam that the numpy kernel tests (whose float32 bearings err by < 3e-6 rad).
EPS_ANGLE_NATIVE = EPS_ANGLE + 1e-5

# Tolerance on the segment parameter s in [0, 1] of a ray/segment hit.  A ray through the shared
# vertex of two polygon edges must hit at least one of them despite rounding; 1e-9 of an edge
# length is far below any physical size.  It also rejects the hits on an edge's extension that
# the beam padding (EPS_ANGLE) lets through.
EPS_SEG = 1e-9

# Bounds of a LidarSpec, the same as the compiled kernel's: a range beyond MAX_RANGE (m) would
# let squared distances overflow, and more than MAX_SAMPLES beams is no lidar.
MAX_RANGE = 1e6
MAX_SAMPLES = 1 << 24

# Slack (m) on every range cull, so that rounding never drops a primitive at exactly range_max.
EPS_CULL = 1e-9

# Static grid cell size (m).  A sensor reads the candidate list of its own cell, which holds the
# primitives within range_max + half a cell diagonal of the cell centre: smaller cells give
# tighter lists but a bigger one-off index.
STATIC_CELL = 1.0

# Static segments are split into pieces no longer than this (m), so that a long wall only
# contributes the beams of the pieces that are within range_max of the sensor.
STATIC_PIECE = 1.0

# Upper bound on the number of static grid cells; the cell size doubles for huge worlds.
STATIC_MAX_CELLS = 1 << 22

# Moving segments are culled per group: a run of consecutive segments of one owner (a robot
# outline), at most GROUP_MAX long and at most GROUP_MAX_RADIUS (m) in bounding radius.
GROUP_MAX = 16
GROUP_MAX_RADIUS = 0.5

# Dynamic grid cell size (m): a sensor's candidate groups are those whose centre lies in the
# cells that its range disc (grown by the largest group radius) touches; smaller cells hug the
# disc more tightly but cost more runs.  bench/lidar_bench.py: 0.5 to 1 m equal, 0.25 m slower.
DYN_CELL = 1.0

# Upper bound on the number of dynamic grid cells (cell ids then fit uint16, which numpy sorts
# with a radix sort); the cell size doubles when the robots spread wider.
DYN_MAX_CELLS = 1 << 16

# Sensors handled per pass: bounds the temporaries of very large batches.  Smaller chunks were
# measured slower at 167 sensors: the fixed cost of ~200 numpy calls per pass dominates.
CHUNK_SENSORS = 512


# One call allocates a few MB of numpy temporaries.  With glibc's default malloc thresholds that
# memory goes back to the OS after every call and is page-faulted in again on the next (~1 500
# minor faults per 167-sensor batch, measured at ~40% of the call time).  Allocating and freeing
# one block of HEAP_WARMUP_BYTES once raises glibc's dynamic mmap/trim thresholds to that size,
# so the heap keeps the memory between calls.  Elsewhere it is just one short-lived allocation.
HEAP_WARMUP_BYTES = 16 << 20


def _warm_heap() -> None:
    np.empty(HEAP_WARMUP_BYTES, dtype=np.uint8)


_warm_heap()


@dataclass(frozen=True)
class LidarSpec:
    """Ray layout and range of a planar lidar (defaults: TurtleBot3 LDS-01 in Gazebo)."""

    samples: int = 360
    angle_min: float = 0.0
    angle_max: float = 6.28
    range_min: float = 0.12
    range_max: float = 3.5

    def __post_init__(self) -> None:
        if self.samples < 2:
            raise ValueError("samples must be >= 2")
        if not 0.0 < self.angle_max - self.angle_min <= TWO_PI:
            raise ValueError("angle_max - angle_min must lie in (0, 2*pi]")
        if not 0.0 <= self.range_min < self.range_max <= MAX_RANGE:
            raise ValueError(f"need 0 <= range_min < range_max <= {MAX_RANGE:g} m")
        if self.samples > MAX_SAMPLES:
            raise ValueError(f"samples must be at most {MAX_SAMPLES}")

    @property
    def angle_increment(self) -> float:
        return (self.angle_max - self.angle_min) / (self.samples - 1)

    def angles(self) -> F64:
        """Beam angles relative to the sensor heading, shape (samples,)."""
        k = np.arange(self.samples, dtype=np.float64)
        return self.angle_min + k * self.angle_increment


@functools.lru_cache(maxsize=8)
def beam_table(spec: LidarSpec) -> F64:
    """Unit beam directions in the sensor frame over the extended range: rows dx, dy."""
    rel = np.tile(spec.angles() - spec.angle_min, 2)
    table = np.stack([np.cos(rel), np.sin(rel)])
    table.flags.writeable = False
    return table
