"""bench.scale_bench runs a router, daemons sharing a fleet and a subscriber as real processes,
measures each run and the ghosts' cost, and writes what it measured."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_a_small_fleet_over_two_daemons_is_measured(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bench.scale_bench", "--daemons", "2", "--sizes", "40", "--duration", "1",
         "--settle", "1", "--ghost-robots", "30", "--out", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=240, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    out = proc.stdout
    assert proc.returncode == 0, out[-3000:] + proc.stderr[-3000:]
    rows = re.findall(r"^\| (\d) \| 40 \| ([\d.]+) \| ([\d.]+) / ([\d.]+) \| (\d+) \| (yes|no) \|", out, re.MULTILINE)
    assert [r[0] for r in rows] == ["2"], out
    assert int(rows[0][4]) >= 36, out  # the driver's commands reached the robots of both daemons
    data = json.loads((tmp_path / "scale.json").read_text())
    runs = data["runs"]
    assert [r["status"] for r in runs] == ["ok"]
    assert all(r["spawned"] == 40 and sum(r["robots_per_daemon"].values()) == 40 for r in runs)
    assert set(runs[0]["robots_per_daemon"]) == {"d0", "d1"}  # the fleet spread over both
    assert all(0.5 < r["odom_fraction"] < 1.5 and r["rtf_min"] > 0 for r in runs)
    assert {"router", "d0", "d1", "subscriber"} <= set(runs[0]["cpu_pct"])
    costs = data["ghost_cost"]
    assert [(c["own"], c["layout"]) for c in costs] == [(30, "interleaved"), (30, "beside")]
    assert costs[1]["ghost_bodies"] == 30 and costs[0]["daemon_tick_bytes"] > 30 * 24  # names, models and poses
    assert re.search(r"largest fleet in real time: \d+ robots; target 6000: not met", out)


def test_bad_arguments_are_one_clear_line() -> None:
    proc = subprocess.run([sys.executable, "-m", "bench.scale_bench", "--daemons", "0"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 2 and "must be at least 1" in proc.stderr
