"""bench.zenoh_declare runs end to end: a peer and a driver process, each operation timed
quiet and driven, a table of p50/p99 and the ratio (the numbers belong in docs/robustness.md,
not in assertions)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from bench.zenoh_declare import OPERATIONS

ROOT = Path(__file__).resolve().parents[2]


def test_zenoh_declare_times_each_operation_quiet_and_driven() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bench.zenoh_declare", "--publishers", "200", "--samples", "10", "--settle", "0.3"],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    rows = {line.split("|")[1].strip(): line for line in proc.stdout.splitlines() if line.startswith("| ")}
    assert set(OPERATIONS) <= set(rows)
    head = proc.stdout.splitlines()[0]
    assert "a driver (client)" in head and "commands a second of 2,000" in head and "a second arrived here" in head
    for op in OPERATIONS:
        numbers = [float(cell) for cell in rows[op].strip("|").split("|")[1:]]
        assert len(numbers) == 5 and all(n >= 0 for n in numbers), rows[op]


def test_bad_flags_are_one_clear_line() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bench.zenoh_declare", "--publishers", "0"],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 2 and "--publishers" in proc.stderr.splitlines()[-1]
    proc = subprocess.run(
        [sys.executable, "-m", "bench.zenoh_declare", "--tokens", "-1"],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 2 and "--tokens" in proc.stderr.splitlines()[-1]
