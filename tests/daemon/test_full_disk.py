"""A full disk under ``simd --state``: a real daemon, its state file on a small tmpfs that a
test file fills up. The previous state file stays whole, simd says so in one line and keeps
answering, and it saves again once there is room. (The logging's rate limit, on an injected
clock: tests/engine/test_checkpoint.py.)

Mounting a tmpfs needs root (or CAP_SYS_ADMIN); where it is not allowed the test skips and
says why."""

from __future__ import annotations

import contextlib
import errno
import json
import re
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from clients import wait_until
from tests.conftest import Daemon, start_daemon
from tests.daemon.test_state import _wait_saved

DISK_BYTES = 256 * 1024


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A directory on a tmpfs of ``DISK_BYTES``, unmounted at the end."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command here: the full-disk test needs to mount a small tmpfs")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK_BYTES},mode=0755", "tmpfs", str(mnt)],
                       capture_output=True, text=True)  # fmt: skip
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root or CAP_SYS_ADMIN): {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def fill(disk: Path) -> Path:
    """Fill ``disk`` to the last byte with one file; that file."""
    filler = disk / "filler"
    chunk = b"\0" * 4096
    with filler.open("wb", buffering=0) as f, contextlib.suppress(OSError):
        while True:
            f.write(chunk)
    probe = disk / "probe"
    with pytest.raises(OSError) as e, probe.open("wb", buffering=0) as f:
        f.write(chunk)
    assert e.value.errno == errno.ENOSPC
    probe.unlink()  # (an empty file: it frees no room)
    return filler


def _lines(d: Daemon, words: str) -> list[str]:
    return [line for line in d.log().splitlines() if words in line]


@pytest.mark.slow  # it lets the daemon fail to save for a few seconds of wall time
def test_a_full_disk_keeps_the_state_file_whole_and_the_daemon_running(small_disk: Path, tmp_path: Path) -> None:
    state = small_disk / "fleet.json"
    d = start_daemon(tmp_path, "--lockstep", "--world", "empty", "--no-noise", "--state", str(state))
    try:
        c = d.client(timeout=5.0)
        c.spawn("tb3_0", 0.0, 0.0)
        c.spawn("tb3_1", 1.0, 0.0)
        c.step(30, cmd_vel={"tb3_0": (0.2, 0.0)})
        before = _wait_saved(state, 30, 2)
        whole = state.read_bytes()

        filler = fill(small_disk)
        c.step(30, cmd_vel={"tb3_0": (0.2, 0.0)})  # the fleet changes while nothing can be saved
        c.spawn("tb3_2", 2.0, 0.0)
        assert wait_until(lambda: bool(_lines(d, "cannot write the state file")), 15.0), d.log()
        time.sleep(4.5)  # two more saves' worth (every 2 s) of a full disk: still the one line
        said = _lines(d, "cannot write the state file")
        assert len(said) == 1, said
        assert "No space left on device" in said[0] and "sim time 1.000 s" in said[0], said[0]
        assert state.read_bytes() == whole  # the previous state, byte for byte
        assert json.loads(whole)["robots"] == before["robots"]
        assert sorted(p.name for p in small_disk.iterdir()) == ["filler", "fleet.json"]  # no temporary file
        assert c.clock().tick == 60 and len(c.robots()) == 3  # the daemon runs on and answers

        filler.unlink()  # room again: the next save writes the fleet as it is now
        assert wait_until(lambda: bool(_lines(d, "is written again")), 15.0), d.log()
        again = _lines(d, "is written again")[0]
        failed = re.search(r"after (\d+) failed saves", again)
        assert failed is not None and int(failed.group(1)) >= 1, again
        _wait_saved(state, 60, 3)
    finally:
        assert d.stop() == 0, d.log()
    restored = start_daemon(tmp_path, "--lockstep", "--world", "empty", "--no-noise", "--state", str(state))
    try:
        assert "restored 3 robots at sim time 2.000 s" in restored.log()
    finally:
        restored.stop()
