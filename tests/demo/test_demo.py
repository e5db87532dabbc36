"""``./demo`` as a newcomer runs it: it talks only to the daemon it started, and Ctrl-C ends it
cleanly. Real processes on loopback ports of their own."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.conftest import ROOT, Daemon, free_port

DEMO = ROOT / "demo"
pytestmark = pytest.mark.skipif(
    not (ROOT / ".venv" / "bin" / "fleet-view").exists(), reason="./demo runs from the repository's .venv"
)


def as_in_a_terminal() -> None:
    """A shell started in the background inherits SIGINT ignored, and a signal ignored on
    entry cannot be trapped; a terminal's foreground job has the default, as here."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_demo(endpoint: str, tmp_path: Path) -> subprocess.Popen[str]:
    """./demo in a session of its own (a terminal's Ctrl-C reaches its whole process group)."""
    with (tmp_path / "demo.out").open("w") as out:
        return subprocess.Popen(
            [str(DEMO)], cwd=ROOT, env={**os.environ, "FLEETSIM_ENDPOINT": endpoint}, stdout=out,
            stderr=subprocess.STDOUT, text=True, start_new_session=True, preexec_fn=as_in_a_terminal,
        )  # fmt: skip


def output(tmp_path: Path) -> str:
    return (tmp_path / "demo.out").read_text()


def processes_with(text: str) -> list[int]:
    found = []
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if text in cmdline and "pytest" not in cmdline:
                found.append(int(pid))
    return found


def test_a_busy_port_is_one_clear_line_and_the_other_daemon_is_untouched(
    daemon_factory: Callable[..., Daemon], tmp_path: Path
) -> None:
    other = daemon_factory()
    c = other.client()
    c.spawn("theirs", -2.0, -0.5)
    demo = run_demo(other.endpoint, tmp_path)
    assert demo.wait(30) != 0
    text = output(tmp_path)
    assert f"demo: {other.endpoint} is taken" in text and "FLEETSIM_ENDPOINT=" in text, text
    assert "spawned" not in text and "Drive it" not in text
    assert [r.name for r in c.robots()] == ["theirs"]  # no tb3_0 in somebody else's daemon
    assert other.alive()


def test_ctrl_c_ends_the_demo_with_status_0_and_leaves_no_daemon(tmp_path: Path) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    demo = run_demo(endpoint, tmp_path)
    try:
        deadline = time.monotonic() + 30
        while "Stop the daemon" not in output(tmp_path):
            assert demo.poll() is None, output(tmp_path)
            assert time.monotonic() < deadline, output(tmp_path)
            time.sleep(0.1)
        assert "spawned tb3_0" in output(tmp_path)
        assert processes_with(endpoint), "the demo's simd is running"
        # what it tells a newcomer to do next works as printed: tb3_0 drives across the world
        goto = next(line for line in output(tmp_path).splitlines() if "fleet goto" in line)
        command = goto.split(":", 1)[1].strip().split()
        assert command[:2] == [".venv/bin/fleet", "goto"] and "--wait" in command
        went = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
        assert went.returncode == 0, went.stdout + went.stderr
        assert "reached" in went.stdout
        os.killpg(demo.pid, signal.SIGINT)  # what Ctrl-C in its terminal does
        assert demo.wait(15) == 0, output(tmp_path)
    finally:
        if demo.poll() is None:
            os.killpg(demo.pid, signal.SIGKILL)
    assert not processes_with(endpoint), "simd or the log follower outlived the demo"
    with socket.socket() as s:  # and its port is free again, for a new daemon (zenoh's listener reuses
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # addresses: a closed connection in
        s.bind(("127.0.0.1", port))  # TIME_WAIT, seen on a loaded machine, does not keep it out)
