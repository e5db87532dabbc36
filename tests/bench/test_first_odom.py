"""bench.first_odom runs a real daemon and a follower of its last-spawned robot, and says when
the robot's first odometry came (the figures belong in docs/robustness.md, measured there)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_a_follower_of_the_last_robot_hears_from_it_and_the_run_is_reported() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bench.first_odom", "--robots", "40", "--settle", "0.5", "--timeout", "30"],
        cwd=ROOT, capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["robots"] == 40 and out["follow"] == "r39"
    assert out["first_odom_s"] is not None and out["timed_out_after_s"] is None
    assert out["ticks_meanwhile"] >= 1


@pytest.mark.parametrize(("args", "said"), [(["--robots", "x"], "invalid int value"),
                                            (["--robots", "0"], "--robots must be at least 1"),
                                            (["--timeout", "-1"], "--timeout positive")])  # fmt: skip
def test_bad_arguments_are_one_clear_line(args: list[str], said: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "bench.first_odom", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 2 and said in proc.stderr.strip().splitlines()[-1]
