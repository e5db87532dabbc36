"""Draw docs/img/fleet-view-navigation.png: fleet-view with ten robots navigating a warehouse.

    .venv/bin/python scripts/draw_viewer_navigation.py        # needs chromium on PATH

A generated warehouse (worlds/warehouse.py, 2 x 2 blocks, seed 3), ``simd --lockstep`` on it,
ten burgers on the main corridors, each sent to a cell in an aisle far from it (seeded), stepped
for a few seconds of sim time; then ``fleet-view`` and a headless Chromium (tests/cdp.py, the
viewer tests' driver) take a screenshot with one robot selected. The same run gives the same
goals; the robots' progress at the moment of the picture depends on the machine only through
the page's last frame.
"""

from __future__ import annotations

import random
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.cdp import Chromium  # noqa: E402
from tests.clients.viewer_harness import start_viewer  # noqa: E402
from tests.conftest import start_daemon  # noqa: E402
from worlds.warehouse import warehouse_text  # noqa: E402

OUT = ROOT / "docs" / "img" / "fleet-view-navigation.png"
CELL = 0.5
ROBOTS = 10
SEED = 3
SIM_SECONDS = 9.0


def cells(rows: list[str], height: int) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
    """Open cells of the outermost ring of the edge corridor (where robots start) and of the
    aisles, between two shelves (their goals), as world points (a cell's centre: docs/worlds.md)."""
    width = len(rows[0])
    corridor, aisle = [], []
    for r, line in enumerate(rows):
        for c, ch in enumerate(line):
            if ch != ".":
                continue
            xy = ((c + 0.5) * CELL, (height - r - 0.5) * CELL)
            if r in (0, height - 1) or c in (0, width - 1):
                corridor.append(xy)
            elif 0 < r < height - 1 and rows[r - 1][c] == "@" and rows[r + 1][c] == "@":
                aisle.append(xy)
    return corridor, aisle


def main() -> int:
    text = warehouse_text(blocks_x=2, blocks_y=2, shelf_length=8, rows_per_block=3, seed=SEED)
    lines = text.splitlines()
    height = int(lines[1].split()[1])
    rows = lines[4 : 4 + height]
    corridor, aisle = cells(rows, height)
    rng = random.Random(SEED)
    starts = rng.sample(corridor[:: max(1, len(corridor) // (3 * ROBOTS))], ROBOTS)
    tmp = Path(tempfile.mkdtemp(prefix="fleet-view-nav-"))
    world = tmp / "warehouse.map"
    world.write_text(text)
    daemon = start_daemon(tmp, "--world", str(world), "--cell-size", str(CELL), "--lockstep")
    viewer = None
    try:
        c = daemon.client(timeout=10.0)
        for i, (x, y) in enumerate(starts):
            c.spawn(f"tb3_{i}", x, y, yaw=rng.uniform(-3.1, 3.1))
        for i, (x, y) in enumerate(starts):
            far = [p for p in aisle if abs(p[0] - x) + abs(p[1] - y) > 6.0]
            gx, gy = rng.choice(far)
            c.navigate(f"tb3_{i}", gx, gy, yaw=rng.choice([None, 0.0, 1.5708, 3.1416]))
        viewer = start_viewer(daemon)
        with Chromium(tmp / "chromium", 1280, 800) as browser:
            browser.navigate(viewer.url)
            browser.wait_for(f"viewerStats.robots === {ROBOTS} && viewerStats.frames > 2", 20)
            browser.evaluate("document.getElementById('show-scans').click()")
            t = 0.0
            while t < SIM_SECONDS:
                c.step(15)
                t += 0.5
                time.sleep(0.15)  # let the page draw the step (it is not in lockstep)
            browser.evaluate("viewerStats.select('tb3_4')")
            browser.wait_for("document.getElementById('sel-nav').textContent !== '—'", 10)
            frames = browser.evaluate("viewerStats.frames")
            browser.wait_for(f"viewerStats.frames > {frames} + 3", 10)
            OUT.write_bytes(browser.screenshot())
        print(f"wrote {OUT.relative_to(ROOT)}")
        return 0
    finally:
        if viewer is not None:
            viewer.stop()
        daemon.stop()


if __name__ == "__main__":
    sys.exit(main())
