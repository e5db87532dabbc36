"""Shared fixtures: a real ``simd`` process on a free loopback port, and clients of it.

Every test that needs a daemon starts its own (no shared state between tests, no fixed
ports) and waits for it to answer, never for a fixed sleep.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from clients import FleetClient
from protocol import FleetError

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Daemon:
    """A running simd process."""

    proc: subprocess.Popen[str]
    endpoint: str
    port: int
    prefix: str = "fleet"
    log_path: Path | None = None
    clients: list[FleetClient] = field(default_factory=list)

    def client(self, timeout: float = 3.0) -> FleetClient:
        c = FleetClient(self.endpoint, prefix=self.prefix, timeout=timeout)
        self.clients.append(c)
        return c

    def log(self) -> str:
        return self.log_path.read_text() if self.log_path and self.log_path.exists() else ""

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 5.0) -> int:
        for c in self.clients:
            c.close()
        self.clients.clear()
        return stop_process(self.proc, sig, timeout)


def stop_process(proc: subprocess.Popen[str], sig: int = signal.SIGTERM, timeout: float = 5.0) -> int:
    """Signal a program to stop, kill it if it has not within ``timeout``; its exit status."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return int(proc.returncode)


def wait_for_listener(port: int, deadline: float, proc: subprocess.Popen[str] | None = None) -> None:
    """Return once something accepts TCP connections on 127.0.0.1:``port`` (or at ``deadline``).

    A zenoh session opened before its peer listens retries after 250 ms, then 500 ms: waiting
    for the listener first saves about half a second on each of the suite's few hundred daemons.
    """
    while time.monotonic() < deadline and (proc is None or proc.poll() is None):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.01)


def simd_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "simd.cli", *args]


def start_daemon(
    tmp_path: Path, *args: str, prefix: str = "fleet", wait: float = 15.0, port: int | None = None
) -> Daemon:
    """A simd on loopback (on ``port``, e.g. to restart one, else a free one), once it answers.
    A free port is free only when asked: another test's daemon (another xdist worker) may bind
    it first. Then this one exits with "address already in use" and the other one answers on
    that port, so the answer counts only from this process (its pid in ``P/daemons``), and a
    port taken meanwhile is given up for another."""
    for _ in range(1 if port else 3):
        d = _start_daemon(tmp_path, args, prefix, wait, port or free_port())
        if d is not None:
            return d
    raise RuntimeError(f"simd found its port taken ({port or 'three free ports in a row'})")


def _start_daemon(tmp_path: Path, args: tuple[str, ...], prefix: str, wait: float, port: int) -> Daemon | None:
    """The daemon once it answers; None if its port was taken before it could listen."""
    endpoint = f"tcp/127.0.0.1:{port}"
    log_path = tmp_path / f"simd-{port}.log"
    with log_path.open("w") as logf:
        proc = subprocess.Popen(
            simd_command("-l", endpoint, "--prefix", prefix, *args),
            stdout=logf,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=ROOT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    d = Daemon(proc, endpoint, port, prefix, log_path)
    deadline = time.monotonic() + wait
    wait_for_listener(port, deadline, proc)
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            if "address already in use" in d.log():
                return None
            raise RuntimeError(f"simd exited with {proc.returncode}:\n{d.log()}")
        try:
            with FleetClient(endpoint, prefix=prefix, timeout=1.0) as c:
                c.clock()
                # its presence (P/daemons) is declared a moment after its clock answers
                if any(info.pid == proc.pid for info in c.daemons()):
                    return d
        except FleetError:
            time.sleep(0.05)
            continue
        time.sleep(0.01)
    d.stop()
    raise RuntimeError(f"simd did not answer within {wait} s:\n{d.log()}")


@pytest.fixture
def daemon_factory(tmp_path: Path) -> Iterator[Callable[..., Daemon]]:
    """Start daemons with extra simd arguments; all are stopped at the end of the test."""
    started: list[Daemon] = []

    def make(*args: str, prefix: str = "fleet") -> Daemon:
        d = start_daemon(tmp_path, *args, prefix=prefix)
        started.append(d)
        return d

    yield make
    for d in started:
        d.stop()


@pytest.fixture
def daemon(daemon_factory: Callable[..., Daemon]) -> Daemon:
    """A daemon on turtlebot3_world, real time, noise on."""
    return daemon_factory()


@pytest.fixture
def client(daemon: Daemon) -> FleetClient:
    return daemon.client()
