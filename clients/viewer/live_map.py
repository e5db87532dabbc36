"""The viewer's map layer (``fleet-view --map``): the occupancy map the fleet's scans build, live.

The viewer already follows the fleet topics; with ``--map`` the same messages also feed a
log-odds grid (clients/mapping), which the page fetches as a small PNG once a second
(``/map.png``) and draws under the robots: walls dark, free space light, unknown clear. The
grid covers the world's bounds plus half a metre, at 0.05 m a cell, as ``fleet-map`` builds it.
"""

from __future__ import annotations

import io
import threading

import numpy as np

from clients.mapping.grid import LogOddsGrid
from clients.mapping.mapper import Mapper
from fleetcommon.mapfile import FREE, OCCUPIED
from protocol.control import WorldInfo
from protocol.messages import FleetOdometry, FleetScans

MARGIN_M = 0.5
#: RGBA of the layer's cells
WALL = (40, 44, 52, 235)
OPEN = (255, 255, 255, 110)


class LiveMap:
    """A grid fed from zenoh's threads (one lock: odometry and scans come on two of them)."""

    def __init__(self, world: WorldInfo, resolution: float = 0.05) -> None:
        b = world.bounds
        bounds = (b.x_min - MARGIN_M, b.x_max + MARGIN_M, b.y_min - MARGIN_M, b.y_max + MARGIN_M)
        self.grid = LogOddsGrid(bounds, resolution)
        self.mapper = Mapper(self.grid, None, {})
        self._lock = threading.Lock()

    def set_models(self, models: dict[str, str]) -> None:
        with self._lock:
            self.mapper.models.update(models)

    def on_fleet_odom(self, msg: FleetOdometry) -> None:
        with self._lock:
            self.mapper.on_odometry(msg)

    def on_fleet_scans(self, msg: FleetScans) -> None:
        with self._lock:
            self.mapper.on_scans(msg)

    def png(self) -> tuple[bytes, dict[str, str]]:
        """The layer as a PNG (row 0 at the top) and headers that place it in the world."""
        from PIL import Image

        with self._lock:
            cells = np.flipud(self.grid.occupancy().cells)
            scans = self.grid.scans
        rgba = np.zeros((*cells.shape, 4), dtype=np.uint8)
        rgba[cells == FREE] = OPEN
        rgba[cells == OCCUPIED] = WALL
        buf = io.BytesIO()
        Image.fromarray(rgba, mode="RGBA").save(buf, format="PNG")
        x0, y0 = self.grid.origin
        headers = {
            "X-Map-Origin": f"{x0:.6f},{y0:.6f}",
            "X-Map-Resolution": f"{self.grid.resolution:.6f}",
            "X-Map-Scans": str(scans),
            "Cache-Control": "no-store",
        }
        return buf.getvalue(), headers
