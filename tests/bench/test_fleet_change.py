"""The fleet-change benchmark runs end to end and prints every figure (numbers are not checked
here: they belong in docs/robustness.md, measured on a quiet machine)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_fleet_change_benchmark_prints_every_figure() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bench.fleet_change", "--robots", "20", "--rounds", "2"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=100,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "20 robots spawned" in proc.stdout
    for row in ("spawn", "list after a spawn", "delete", "list after a delete", "tick after", "list, nothing changed"):
        assert any(line.startswith(row + " ") for line in proc.stdout.splitlines()), (row, proc.stdout)
