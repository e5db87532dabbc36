from __future__ import annotations

from tests.conftest import Daemon


def test_daemon_answers_clock(daemon: Daemon) -> None:
    c = daemon.client()
    clock = c.clock()
    assert clock.robots == 0
    assert not clock.lockstep
