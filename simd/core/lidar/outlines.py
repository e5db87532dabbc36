"""The robots' outlines in the world frame, as the segments the lidar sees: every lidar batch
needs all of them (a thousand robots: 12 000 segments), on the lidar's thread.

In numpy this is a dozen array passes that hold the GIL between them, and the simulation
thread stalls on that GIL beside it; the compiled twin (``outline_segments`` in
simd/core/lidar/_raycast.c) does the same arithmetic, in the same order, in one pass with the
GIL released. Both give the same bits (tests/core/test_lidar_native.py).
"""

from __future__ import annotations

import numpy as np

from fleetcommon.arrays import F64
from simd.core.lidar import native_kernel


def outline_segments(x: F64, y: F64, cos_yaw: F64, sin_yaw: F64, outline: F64, *, kernel: str | None = None) -> F64:
    """Robot i at (x[i], y[i]) heading (cos_yaw[i], sin_yaw[i]) with the corners ``outline[i]``
    ((N, K, 2), robot frame): its K edges, corner j to corner j + 1 and the last back to the
    first, as rows ``x0, y0, x1, y1`` of an (N * K, 4) array. ``kernel`` "native" or "numpy";
    by default the lidar's (``KERNEL``)."""
    n, corners = outline.shape[0], outline.shape[1]
    out = np.empty((n * corners, 4))
    if (kernel or native_kernel.KERNEL) == "native":
        native_kernel.outline_segments(
            np.ascontiguousarray(x, dtype=np.float64),
            np.ascontiguousarray(y, dtype=np.float64),
            np.ascontiguousarray(cos_yaw, dtype=np.float64),
            np.ascontiguousarray(sin_yaw, dtype=np.float64),
            np.ascontiguousarray(outline, dtype=np.float64).reshape(-1, 2),
            corners,
            out,
        )
        return out
    seg = out.reshape(n, corners, 4)
    c, s = cos_yaw[:, None], sin_yaw[:, None]
    ox, oy = outline[:, :, 0], outline[:, :, 1]
    wx, wy = seg[:, :, 0], seg[:, :, 1]
    np.multiply(ox, c, out=wx)  # x + ox * c - oy * s, as the sum's terms commute exactly
    wx += x[:, None]
    wx -= oy * s
    np.multiply(ox, s, out=wy)  # y + ox * s + oy * c
    wy += y[:, None]
    wy += oy * c
    seg[:, :-1, 2:] = seg[:, 1:, :2]
    seg[:, -1, 2:] = seg[:, 0, :2]
    return out
