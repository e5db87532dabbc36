"""bench.token_churn runs end to end: a peer declares and undeclares tokens while a client in a
process of its own watches them, and it reports both processes' memory for every thousand
tokens and at the end (the numbers belong in docs/robustness.md, not in assertions)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_token_churn_reports_both_processes_memory() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "bench.token_churn", "--tokens", "1200", "--rate", "2000"],
        cwd=ROOT, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    records = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [r["tokens"] for r in records] == [1000, 1200]
    for r in records:
        assert r["peer_rss_mb"] > 0 and r["client_rss_mb"] > 0
        assert {"peer_kb_per_token", "client_kb_per_token"} <= set(r)
