"""fleet-router: a daemon and its clients meet through a router, all real processes on loopback."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from clients import FleetClient
from protocol import FleetError
from tests.conftest import ROOT, free_port, simd_command


def _start(cmd: list[str], log: Path) -> subprocess.Popen[str]:
    with log.open("w") as f:
        return subprocess.Popen(
            cmd, stdout=f, stderr=subprocess.STDOUT, text=True, cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1"}
        )


def _stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _wait_for(log: Path, text: str, proc: subprocess.Popen[str], timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if text in log.read_text():
            return
        assert proc.poll() is None, log.read_text()
        time.sleep(0.05)
    raise AssertionError(f"{text!r} not in {log}:\n{log.read_text()}")


@pytest.fixture
def router(tmp_path: Path) -> Iterator[tuple[str, subprocess.Popen[str], Path]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    log = tmp_path / "router.log"
    proc = _start([sys.executable, "-m", "simd.router", "-l", endpoint], log)
    _wait_for(log, "fleet-router: routing on", proc)
    yield endpoint, proc, log
    _stop(proc)


def test_a_daemon_and_its_clients_meet_through_the_router(
    router: tuple[str, subprocess.Popen[str], Path], tmp_path: Path
) -> None:
    endpoint, proc, log = router
    assert f"simd -m client -e {endpoint}" in log.read_text()  # it says how to connect
    daemon = _start(simd_command("-m", "client", "-e", endpoint, "--world", "empty"), tmp_path / "simd.log")
    try:
        with FleetClient(endpoint, timeout=3.0) as c:
            deadline = time.monotonic() + 15.0
            while True:  # the daemon's queryables reach the router a moment after it starts
                try:
                    c.clock()
                    break
                except FleetError:
                    assert time.monotonic() < deadline and daemon.poll() is None, (tmp_path / "simd.log").read_text()
                    time.sleep(0.1)
            c.spawn("tb3_0", 0.0, 0.0)
            before = c.wait_odom("tb3_0").pose.pose.position.x
            moved = before
            deadline = time.monotonic() + 10.0
            while moved < before + 0.05 and time.monotonic() < deadline:
                c.drive("tb3_0", 0.2, 0.0)  # commands through the router, odometry back through it
                moved = c.wait_odom("tb3_0").pose.pose.position.x
            assert moved >= before + 0.05
        listed = subprocess.run(
            [sys.executable, "-m", "clients.fleet.cli", "list", "-e", endpoint],
            cwd=ROOT, capture_output=True, text=True, timeout=30,
        )  # fmt: skip
        assert listed.returncode == 0 and "tb3_0" in listed.stdout, listed.stdout + listed.stderr
    finally:
        _stop(daemon)
    with FleetClient(endpoint, timeout=1.0) as c, pytest.raises(FleetError, match="no fleetsim daemon answered"):
        c.clock()  # the router stays; the daemon is gone
    assert proc.poll() is None


def test_bad_endpoints_and_a_taken_port_are_one_line(router: tuple[str, subprocess.Popen[str], Path]) -> None:
    endpoint, _, _ = router
    for args, words in (
        (["-l", endpoint], "Address already in use"),
        (["-l", "127.0.0.1:7447"], "Endpoints must be of the form <protocol>/<address>"),
    ):
        r = subprocess.run(
            [sys.executable, "-m", "simd.router", *args], cwd=ROOT, capture_output=True, text=True, timeout=30
        )
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and words in lines[0] and ".rs:" not in lines[0], r.stderr
