"""learn.cem, the example that learns: a tiny real training run, its replay on a real simd --lockstep,
and bad input refused with one line."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from learn.cem import Settings, load
from tests.conftest import ROOT, free_port


def _cem(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "learn.cem", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One generation of a small population on short episodes, in this process's interpreter."""
    out = tmp_path_factory.mktemp("cem")
    run = _cem("--generations", "2", "--population", "4", "--episodes", "1", "--eval-episodes", "2",
               "--max-steps", "15", "--workers", "1", "--seed", "3", "--out", str(out))  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "gen   2/2" in run.stdout and "held-out success" in run.stdout
    return out


def test_a_tiny_training_run_writes_the_policy_the_curve_and_the_picture(trained: Path) -> None:
    settings, params = load(trained / "policy.npz")
    assert settings == Settings(max_steps=15)
    assert params.shape == (settings.size,) == (2 * (24 + 5 + 1),) and np.all(np.isfinite(params))
    with np.load(trained / "policy.npz") as z:
        assert 0 <= int(z["generation"]) <= 2 and 0.0 <= float(z["heldout_success"]) <= 1.0
    with (trained / "curve.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["generation"] for r in rows] == ["0", "1", "2"]
    assert rows[0]["population_mean_return"] == ""  # generation 0 is the starting policy
    for r in rows[1:]:
        assert float(r["population_best_return"]) >= float(r["population_mean_return"])
        assert 0.0 <= float(r["heldout_success"]) <= 1.0
    with Image.open(trained / "learning_curve.png") as image:
        assert image.format == "PNG" and image.width > 100 and image.height > 100


def test_the_policy_replays_on_a_running_daemon(trained: Path, daemon_factory: Any) -> None:
    d = daemon_factory("--lockstep")
    run = _cem("--replay", str(trained / "policy.npz"), "--endpoint", d.endpoint, "--episodes", "1", "--pace", "0")
    assert run.returncode == 0, run.stderr
    assert "episode 1 (seed 1000000000): " in run.stdout
    assert any(word in run.stdout for word in ("arrived after", "collided after", "out of time"))
    assert "cem: arrived in" in run.stdout
    c = d.client()
    assert c.clock().tick > 0  # the replay stepped the daemon's clock
    assert c.robots() == []  # the replay closed its env, which took its robot away


def test_a_corrupt_policy_or_no_daemon_is_one_line_and_exit_2(trained: Path, tmp_path: Path) -> None:
    bad = tmp_path / "policy.npz"
    bad.write_bytes(b"PK\x03\x04 not really a zip")
    nowhere = f"tcp/127.0.0.1:{free_port()}"
    for policy, endpoint, says in (
        (bad, nowhere, "is not a policy written by learn.cem"),
        (tmp_path / "missing.npz", nowhere, "no policy file"),
        (trained / "policy.npz", nowhere, "cannot reach a fleetsim daemon"),
    ):
        run = _cem("--replay", str(policy), "--endpoint", endpoint, "--timeout", "1")
        assert run.returncode == 2, run.stderr
        assert run.stderr.count("\n") == 1 and run.stderr.startswith("cem: ") and says in run.stderr, run.stderr
        assert "Traceback" not in run.stderr and run.stdout == ""
