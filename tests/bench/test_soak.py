"""The soak, in small: six robots for a few sim seconds with every part of the real one (drivers,
subscribers, the churn, hostile traffic, a pause and a reset), all real processes. Its promises
that hold at any length are asserted; memory, threads and open files need minutes to mean
anything and are only checked to be measured (the ten-minute figures: docs/robustness.md)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_a_short_soak_accounts_for_every_reply_and_robot(tmp_path: Path) -> None:
    out = tmp_path / "soak.json"
    args = ["--robots", "6", "--duration", "6", "--drivers", "2", "--subscribers", "2", "--churn-rate", "5",
            "--fuzz-rate", "10", "--every", "1", "--pause", "1", "--warmup", "0", "--out", str(out)]  # fmt: skip
    proc = subprocess.run([sys.executable, "-m", "bench.soak", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=240, env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip
    assert out.exists(), proc.stdout[-3000:] + proc.stderr[-3000:]
    r = json.loads(out.read_text())
    v = r["verdict"]
    for promise in ("completed", "alive", "no_lost_reply", "hostile_refused", "no_lost_robot", "churned",
                    "paused_and_resumed", "reset"):  # fmt: skip
        assert v[promise], (promise, r["events"], r["requests"], proc.stderr[-3000:])
    assert r["sim_s"] >= 6 and r["lost_replies"] == 0
    churn = r["requests"]["churn"]
    assert churn["spawned"] > 4 and churn["answered"] > churn["spawned"]  # spawns and deletes both went through
    assert r["requests"]["fuzz"]["queries"] > 0 and r["requests"]["fuzz"]["no_reply"] == 0
    assert [e["event"] for e in r["events"]] == ["pause", "reset"]
    samples = r["samples"]
    assert samples and all(s["threads"] and s["fds"] and s["rss_mb"] > 0 for s in samples)
    assert all(s["missing"] == 0 for s in samples)
    assert all(0 < s["odom_delivered"] <= 1.05 for s in samples)  # every subscriber received (not a bar)
    assert (tmp_path / "soak.png").stat().st_size > 0
    assert "soak: 6 robots" in proc.stdout and r["machine"]["cores"]
    assert proc.returncode == (0 if all(v.values()) else 1)
