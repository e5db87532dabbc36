"""Starting and stopping the benchmark's child processes (``simd`` and the subscriber).

Children run in their own session, so that Ctrl-C reaches the benchmark alone and it can stop
them in order, and (on Linux) get SIGTERM when the benchmark dies, so that a killed benchmark
never leaves a daemon spinning.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.wire import PREFIX

ROOT = Path(__file__).resolve().parents[1]  # children run here, where simd, protocol and bench import


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _prctl_deathsig() -> Callable[[], None] | None:
    """A preexec_fn that makes a child get SIGTERM when this process dies (Linux), so that a
    killed benchmark never leaves a daemon spinning. Resolved before any fork."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None

    def set_deathsig() -> None:
        prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG

    return set_deathsig


PREEXEC = _prctl_deathsig()


def raise_exit(signum: int, frame: object) -> None:
    """A SIGTERM handler that unwinds like Ctrl-C, so that every child is stopped on the way out."""
    raise SystemExit(128 + signum)


def stop_process(proc: subprocess.Popen[Any], grace: float) -> None:
    """Wait ``grace`` s for a process asked to stop, then SIGTERM, then SIGKILL."""
    for sig in (None, signal.SIGTERM, signal.SIGKILL):
        if proc.poll() is not None:
            return
        if sig is not None:
            with contextlib.suppress(OSError):
                proc.send_signal(sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(grace)


def terminate(proc: subprocess.Popen[Any], grace: float) -> None:
    """Ask a process to stop (SIGTERM, what simd and the router end cleanly on), then as
    ``stop_process``. (Waiting ``grace`` for a process nobody asked to stop only waits:
    bench.scale_bench spent 10 s on each of its router and daemons that way.)"""
    if proc.poll() is None:
        with contextlib.suppress(OSError):
            proc.send_signal(signal.SIGTERM)
    stop_process(proc, grace)


@dataclass
class DaemonProc:
    """A running ``simd``; its log is kept so that a failed run can report why the daemon died."""

    proc: subprocess.Popen[Any]
    endpoint: str
    log_path: Path

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def log_tail(self, lines: int = 15) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    def stop(self) -> None:
        terminate(self.proc, 10.0)


def start_daemon(world: Path, rtf: float, max_robots: int, tmp: Path, extra: Sequence[str] = ()) -> DaemonProc:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    log_path = tmp / f"simd-{port}.log"
    cmd = [
        sys.executable,
        "-m",
        "simd.cli",
        "--world",
        str(world),
        "-l",
        endpoint,
        "--prefix",
        PREFIX,
        "--rtf",
        f"{rtf:g}",
        "--max-robots",
        str(max_robots),
        "--seed",
        "1",
        "--log-level",
        "warning",
        *extra,
    ]
    with log_path.open("w") as logf:
        proc = subprocess.Popen(
            cmd,
            stdout=logf,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            cwd=ROOT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
            start_new_session=True,
            preexec_fn=PREEXEC,
        )
    return DaemonProc(proc, endpoint, log_path)
