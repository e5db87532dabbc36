"""The state file's writer when the disk fills: the previous file stays whole, one line says so
(at most one a minute while it lasts), and the next save after room is made succeeds and says
so. A real disk filling up with a real daemon is in tests/daemon/test_full_disk.py; here a
writer that fails as a full disk fails (ENOSPC) and an injected clock pin the logging."""

from __future__ import annotations

import errno
import json
import logging
import os
from pathlib import Path

import pytest

from clients import wait_until
from simd.engine import checkpoint
from simd.engine.checkpoint import FAILURE_LOG_EVERY_S, SavedFleet, Saver


def _fleet(tick: int) -> SavedFleet:
    return SavedFleet(format=checkpoint.FORMAT, version=checkpoint.VERSION, world="empty", tick=tick, dt=1 / 30,
                      robots=[])  # fmt: skip


class Disk:
    """Writes through ``checkpoint.write`` until told it is full, then raises ENOSPC as the
    kernel would."""

    def __init__(self) -> None:
        self.full = False

    def write(self, path: Path, fleet: SavedFleet) -> None:
        if self.full:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        checkpoint.write(path, fleet)


def _attempted(saver: Saver, attempts: int) -> None:
    """Wait until the saver's thread has tried (and logged) ``attempts`` saves."""
    assert wait_until(lambda: saver.attempts >= attempts, 10.0), saver.attempts


def test_a_full_disk_keeps_the_old_file_says_so_once_and_saves_again_with_room(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "fleet.json"
    disk, now = Disk(), [100.0]
    saver = Saver(path, writer=disk.write, clock=lambda: now[0])
    caplog.set_level(logging.WARNING, logger="simd.engine.checkpoint")
    saver.offer(_fleet(30))
    _attempted(saver, 1)
    whole = path.read_bytes()
    assert json.loads(whole)["tick"] == 30

    disk.full = True
    for i in range(5):  # five saves over 8 s of a full disk: one line
        now[0] += 2.0
        saver.offer(_fleet(60 + i))
        _attempted(saver, 2 + i)
    assert path.read_bytes() == whole  # the previous state, byte for byte
    assert [p.name for p in tmp_path.iterdir()] == ["fleet.json"]  # no temporary file left behind
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1, lines
    assert "No space left on device" in lines[0] and "keeps the fleet of before (sim time 1.000 s)" in lines[0]
    assert saver.failures == 5

    now[0] += FAILURE_LOG_EVERY_S  # still full a minute on: one more line, with the count
    saver.offer(_fleet(70))
    _attempted(saver, 7)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and "failed saves so far: 6" in lines[1], lines

    disk.full = False  # room again: the next save writes, and says the trouble is over
    now[0] += 2.0
    saver.offer(_fleet(80))
    _attempted(saver, 8)
    assert json.loads(path.read_text())["tick"] == 80
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 3 and "written again (after 6 failed saves over 70 s)" in lines[2], lines
    assert saver.failures == 0

    disk.full = True  # a new episode is told at once, not a minute after the last line
    now[0] += 2.0
    saver.save_now(_fleet(90))
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 4 and "sim time 2.667 s" in lines[3], lines
    assert json.loads(path.read_text())["tick"] == 80


def test_a_failed_write_leaves_no_temporary_file(tmp_path: Path) -> None:
    """``write`` itself, on a directory the file cannot be renamed into place in: the
    temporary file is removed and the error is the caller's."""
    target = tmp_path / "fleet.json"
    target.mkdir()  # os.replace of a file over a directory fails
    with pytest.raises(OSError):
        checkpoint.write(target, _fleet(1))
    assert [p.name for p in tmp_path.iterdir()] == ["fleet.json"]
