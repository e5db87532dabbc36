"""bench.overload runs a daemon, a subscriber and a driver as real processes, asks every kind
of request while paused and while running, and writes what it measured."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("driver", ["robots", "batched"])
def test_a_small_fleet_is_asked_every_kind_of_request(tmp_path: Path, driver: str) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bench.overload", "--sizes", "30", "--paused-s", "1", "--running-s", "2",
         "--settle", "1", "--out", str(tmp_path), "--driver", driver],
        cwd=ROOT, capture_output=True, text=True, timeout=240, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    out = proc.stdout
    assert proc.returncode in (0, 1), out[-3000:] + proc.stderr[-3000:]  # 1: some p99 above 100 ms
    data = json.loads((tmp_path / "overload.json").read_text())
    (run,) = data["runs"]
    assert run["status"] == "ok" and run["spawned"] == 30, run
    assert set(run["paused"]) == {"clock", "robots", "named", "page", "world", "spawn", "spawn_refused", "delete"}
    assert set(run["running"]) == set(run["paused"]) | {"pause", "resume"}
    for phase in ("paused", "running"):
        assert all(v["n"] >= 1 and v["lost"] == 0 for v in run[phase].values()), run[phase]
    assert not run["unexpected"], run["unexpected"]  # each spawn accepted, each one beyond the limit refused
    assert run["rtf"] > 0 and run["watched_messages"] > 0
    assert data["driver"] == driver and run["driver"]["batched"] == (driver == "batched")
    assert run["driver"]["robots"] == 30 and run["driver"]["cycles"] > 0
    # the fleet was driven before the running phase (the daemon keeps a command: --cmd-timeout 0)
    assert run["moving_at_start"] >= 27 and run["moving_at_end"] >= 27, run
    # the machine's own wake-up lateness beside each phase, from a process that only naps
    assert all(run["machine"][phase]["n"] > 10 for phase in ("paused", "running")), run["machine"]
    assert re.search(r"^\| 30 \| running \| [\d.]+ \| [\d.]+ \| [\d.]+ \|$", out, re.MULTILINE), out
    assert re.search(r"^\| 30 \| running \| clock \| \d+ \|", out, re.MULTILINE), out
    assert re.search(r"every request answered within 100 ms p99: (yes|no)", out)


def test_bad_arguments_are_one_clear_line() -> None:
    proc = subprocess.run([sys.executable, "-m", "bench.overload", "--sizes", "0"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 2 and "must be at least 1" in proc.stderr
