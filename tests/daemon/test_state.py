"""``simd --state FILE``: the fleet survives kill -9 and restarts; bad files are refused untouched."""

from __future__ import annotations

import json
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from protocol import FleetError
from tests.conftest import ROOT, Daemon, simd_command, start_daemon


def _saved_tick(path: Path) -> int:
    try:
        return int(json.loads(path.read_text())["tick"])
    except (OSError, ValueError, KeyError):
        return -1


def _wait_saved(path: Path, tick: int, robots: int, deadline_s: float = 10.0) -> dict[str, object]:
    """The state file once it holds ``tick`` and ``robots`` (the daemon saves soon after a change)."""
    deadline = time.monotonic() + deadline_s
    while time.monotonic() < deadline:
        try:
            saved = json.loads(path.read_text())
            if saved["tick"] == tick and len(saved["robots"]) == robots:
                return dict(saved)
        except (OSError, ValueError, KeyError):
            pass  # not written yet
        time.sleep(0.05)
    raise AssertionError(f"{path} never held tick {tick} with {robots} robots: {path.read_text()[:300]}")


def test_kill_9_and_restart_bring_the_fleet_back(daemon_factory: Callable[..., Daemon], tmp_path: Path) -> None:
    state = tmp_path / "fleet.json"
    d = daemon_factory("--lockstep", "--state", str(state), "--odom-noise", "0.05")
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("tb3_1", 0.5, -2.0, model="waffle")
    c.step(45, cmd_vel={"tb3_0": (0.2, 0.5)})  # tb3_0 moves; its odometry drifts from the truth
    before = {r.name: r for r in c.robots()}
    _wait_saved(state, 45, 2)
    d.proc.kill()  # no chance to save on the way out
    d.proc.wait()
    again = start_daemon(tmp_path, "--lockstep", "--state", str(state), "--odom-noise", "0.05", port=d.port)
    try:
        assert "restored 2 robots" in again.log()
        # the client of before the kill finds the fleet again by itself
        deadline = time.monotonic() + 10
        while True:
            try:
                after = {r.name: r for r in c.robots()}
                break
            except FleetError:
                assert time.monotonic() < deadline, "the client did not reconnect"
                time.sleep(0.05)
        assert c.clock().tick == 45
        assert c.alive() == ["tb3_0", "tb3_1"]  # the restored robots are announced and published like spawned ones
        assert sorted(after) == ["tb3_0", "tb3_1"]
        for name, r in before.items():
            a = after[name]
            assert (a.model, a.namespace) == (r.model, r.namespace)
            assert (a.pose.x, a.pose.y, a.pose.yaw) == (r.pose.x, r.pose.y, r.pose.yaw)  # exactly: JSON keeps floats
            assert (a.spawn_pose.x, a.spawn_pose.y) == (r.spawn_pose.x, r.spawn_pose.y)
        assert before["tb3_0"].pose.x != -2.0  # it had moved
        odom = c.step(1, observe=["tb3_0"]).observations["tb3_0"].odom
        assert abs(odom.pose.pose.position.x - before["tb3_0"].pose.x) < 0.1  # near, not at, the truth
        c.reset()  # the spawn pose survives the restart too
        assert c.robot("tb3_0").pose.x == -2.0  # type: ignore[union-attr]
    finally:
        c.close()
        again.stop()


def test_a_clean_stop_saves_the_last_tick(daemon_factory: Callable[..., Daemon], tmp_path: Path) -> None:
    state = tmp_path / "fleet.json"
    d = daemon_factory("--lockstep", "--state", str(state))
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.step(7)
    assert d.stop(signal.SIGTERM) == 0
    assert _saved_tick(state) == 7
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".fleet.json")]  # no temporary left behind


GOOD_ROBOT = {"name": "a", "namespace": "a", "model": "burger", "pose": [-2.0, -0.5, 0.0],
              "odom": [-2.0, -0.5, 0.0], "spawn_pose": [-2.0, -0.5, 0.0]}  # fmt: skip
GOOD = {"format": "fleetsim-state", "version": 1, "world": "turtlebot3_world", "tick": 3, "dt": 1 / 30,
        "robots": [GOOD_ROBOT]}  # fmt: skip


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\x00\xffnot json", "not a fleetsim state file (not JSON)"),
        (b'{"robots": []}', 'no "format": "fleetsim-state"'),
        (json.dumps({**GOOD, "version": 9}).encode(), "version 9 fleetsim state"),
        (json.dumps({**GOOD, "robots": [{**GOOD_ROBOT, "pose": "here"}]}).encode(), "damaged fleetsim state"),
        (json.dumps({**GOOD, "world": "turtlebot3_house"}).encode(), "saved with world 'turtlebot3_house'"),
        (json.dumps({**GOOD, "robots": [{**GOOD_ROBOT, "pose": [0.0, 0.0, 0.0]}]}).encode(), "cannot be restored"),
        (json.dumps({**GOOD, "robots": [GOOD_ROBOT, GOOD_ROBOT]}).encode(), "cannot be restored"),
        (b"[" * 100_000, "not a fleetsim state file"),
    ],
    ids=["binary", "foreign", "version", "damaged", "other-world", "in-a-wall", "twice", "deep"],
)
def test_a_bad_state_file_is_refused_and_left_untouched(tmp_path: Path, content: bytes, message: str) -> None:
    state = tmp_path / "fleet.json"
    state.write_bytes(content)
    p = subprocess.run(simd_command("--state", str(state), "-l", "tcp/127.0.0.1:0"), capture_output=True,
                       text=True, cwd=ROOT, timeout=60)  # fmt: skip
    assert p.returncode == 2, p.stdout + p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("simd: error: ") and message in lines[0], p.stderr
    assert state.read_bytes() == content


def test_the_state_file_needs_an_existing_directory(tmp_path: Path) -> None:
    p = subprocess.run(simd_command("--state", str(tmp_path / "nope" / "fleet.json")), capture_output=True,
                       text=True, cwd=ROOT, timeout=60)  # fmt: skip
    assert p.returncode == 2 and "does not exist" in p.stderr, p.stderr
