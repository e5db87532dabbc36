"""bench.learn_bench runs every part against real processes and prints a row for each."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_part_is_timed_and_compared() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bench.learn_bench", "--robots", "12", "--steps", "4", "--runs", "2"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    out = proc.stdout
    assert proc.returncode == 0, out[-3000:] + proc.stderr[-3000:]
    assert "machine: " in out and "commit " in out
    rows = dict(re.findall(r"^\| ([a-z ]+) \| [\d.]+ \| \*\*([\d.]+)\*\* \|", out, re.MULTILINE))
    assert set(rows) == {"core", "env", "daemon messages", "daemon packed", "env remote"}, out
    assert all(float(v) > 0 for v in rows.values())
    assert re.search(r"agents left at the end: \d+-\d+", out)
    ratio = re.search(r"daemon packed / daemon messages \(ratio of medians\): ([\d.]+)x", out)
    assert ratio and float(ratio.group(1)) > 0


def test_bad_arguments_are_one_clear_line() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bench.learn_bench", "--robots", "0"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2 and "--robots, --steps and --runs must be at least 1" in proc.stderr
