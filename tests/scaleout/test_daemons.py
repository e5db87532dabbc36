"""Daemons announce themselves (P/daemons/<id>, P/daemons), and a second daemon is refused on a
key space another already serves, with a message that says how to run beside it."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable

from clients import wait_until
from tests.conftest import ROOT, Daemon, free_port, simd_command


def test_a_daemon_is_listed_while_it_runs(daemon_factory: Callable[..., Daemon]) -> None:
    d = daemon_factory("--id", "lab_a", "--world", "empty")
    c = d.client()
    [info] = c.daemons()
    assert (info.id, info.world, info.pid) == ("lab_a", "empty", d.proc.pid)
    listed = subprocess.run(
        [sys.executable, "-m", "clients.fleet.cli", "daemons", "-e", d.endpoint],
        cwd=ROOT, capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert listed.returncode == 0, listed.stderr
    header, row = listed.stdout.strip().splitlines()
    assert header.split() == ["ID", "WORLD", "HOST", "PID", "UP"] and row.split()[:2] == ["lab_a", "empty"]
    token = c.keys.daemon("lab_a")
    alive = [str(r.ok.key_expr) for r in c.session.liveliness().get(token, timeout=2.0) if r.ok is not None]
    assert alive == [token]  # its liveliness token, there while it runs


def test_a_second_daemon_on_the_same_prefix_is_refused(daemon_factory: Callable[..., Daemon]) -> None:
    first = daemon_factory("--id", "lab_a", "--world", "empty")
    joined = ["-e", first.endpoint, "-l", f"tcp/127.0.0.1:{free_port()}"]
    second = subprocess.run(
        simd_command(*joined, "--id", "lab_b", "--world", "empty"),
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    lines = second.stderr.strip().splitlines()
    assert second.returncode == 2 and len(lines) == 1, second.stderr
    assert "daemon 'lab_a' already serves prefix 'fleet'" in lines[0] and "another --prefix" in lines[0]
    assert first.alive() and [d.id for d in first.client().daemons()] == ["lab_a"]  # nothing changed there
    beside = daemon_factory(*joined[:2], "--id", "lab_b", "--world", "empty", prefix="other")
    c = beside.client()
    assert [d.id for d in c.daemons()] == ["lab_b"]  # each prefix is its own fleet
    assert wait_until(lambda: [d.id for d in first.client().daemons()] == ["lab_a"], 5.0)


def test_a_bad_id_is_one_line() -> None:
    r = subprocess.run(simd_command("--id", "lab-a"), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and r.stderr.strip() == (
        "simd: error: --id 'lab-a' contains '-': use letters, digits and '_', starting with a letter"
    )
