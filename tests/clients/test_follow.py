"""UpToStop: what a follower (fleet-map, fleet-record) still takes in after Ctrl-C.

The messages are the fleet topics' own types, put in a real queue as zenoh's threads would;
the daemon's clock is a function returning the stamp it would answer. Through a real daemon,
tests/clients/test_mapping.py and test_record.py stop fleet-map and fleet-record the moment
their last step returns.
"""

from __future__ import annotations

import queue
import threading

import pytest

from clients.follow import UpToStop, drain, follow, stop_on_signals
from protocol import FleetError
from protocol.errors import ErrorCode
from protocol.messages import FleetOdometry, FleetScans, Time

TICK_NS = 33_333_333


def _stamp(tick: int) -> Time:
    return Time(sec=tick * TICK_NS // 10**9, nanosec=tick * TICK_NS % 10**9)


def _odometry(tick: int) -> FleetOdometry:
    return FleetOdometry(stamp=_stamp(tick), namespaces=[], x=b"", y=b"", yaw=b"")


def _scans(tick: int) -> FleetScans:
    return FleetScans(stamp=_stamp(tick), namespaces=[], beams=0, angle_min=0.0, angle_max=0.0,
                      angle_increment=0.0, range_min=0.0, range_max=0.0, ranges=b"")  # fmt: skip


def _tick(msg: FleetOdometry | FleetScans) -> tuple[str, int]:
    return type(msg).__name__, round((msg.stamp.sec * 10**9 + msg.stamp.nanosec) / TICK_NS)


def test_a_lockstep_stop_takes_the_scans_still_behind_the_odometry() -> None:
    """The daemon stopped at tick 12; its odometry is all in, two scans still on their way
    (they come while the follower works): they are taken, and then the quiet ends the wait."""
    inbox: queue.Queue[FleetOdometry | FleetScans] = queue.Queue()
    for t in range(1, 13):
        inbox.put(_odometry(t))
    inbox.put(_scans(0))
    taken: list[tuple[str, int]] = []

    def handle(msg: FleetOdometry | FleetScans) -> None:
        taken.append(_tick(msg))
        if _tick(msg) == ("FleetOdometry", 12):  # the scans of ticks 6 and 12 trail behind
            inbox.put(_scans(6))
            inbox.put(_scans(12))

    up_to = UpToStop(lambda: _stamp(12))
    stop = threading.Event()
    stop.set()
    follow(inbox, handle, stop, 0.0, lambda t: "", up_to_stop=up_to)
    assert taken == [("FleetOdometry", t) for t in range(1, 13)] + [("FleetScans", t) for t in (0, 6, 12)]
    assert up_to.limit == 12 * TICK_NS and up_to.left_out == 0 and up_to.ended == "quiet"


def test_a_running_stop_ends_at_the_first_scan_after_the_clock() -> None:
    """In real time ticks go on after the stop: what is stamped after the clock is left out, and
    the first scan after it says no older one is on its way (scans come in order)."""
    inbox: queue.Queue[FleetOdometry | FleetScans] = queue.Queue()
    for t in range(10, 30):
        inbox.put(_odometry(t))
        if t % 6 == 0:
            inbox.put(_scans(t))
    taken: list[tuple[str, int]] = []
    up_to = UpToStop(lambda: _stamp(20))
    up_to.catch_up(inbox, lambda m: taken.append(_tick(m)))
    assert [t for kind, t in taken if kind == "FleetOdometry"] == list(range(10, 21))
    assert [t for kind, t in taken if kind == "FleetScans"] == [12, 18]
    assert up_to.complete() and up_to.ended == "complete"
    assert up_to.left_out == 10  # odometry 21..29 and the scan of tick 24 (read in the grace after it)
    assert inbox.empty()


def test_no_daemon_at_the_stop_means_what_arrived_is_all() -> None:
    inbox: queue.Queue[FleetOdometry | FleetScans] = queue.Queue()
    inbox.put(_odometry(3))

    def gone() -> Time:
        raise FleetError(ErrorCode.UNAVAILABLE, "no fleetsim daemon answered")

    up_to = UpToStop(gone)
    up_to.catch_up(inbox, lambda m: pytest.fail("nothing is waited for"))
    assert up_to.limit is None and inbox.qsize() == 1 and up_to.ended == "no daemon"
    taken: list[tuple[str, int]] = []
    drain(inbox, lambda m: taken.append(_tick(m)), up_to)
    assert taken == [("FleetOdometry", 3)]


def test_a_fleet_without_robots_ends_the_wait_at_the_quiet(monkeypatch: pytest.MonkeyPatch) -> None:
    """No robot, no odometry: the wait ends after the quiet meant for that, not at the cap."""
    import clients.follow as follow_module

    monkeypatch.setattr(follow_module, "QUIET_NO_ODOMETRY_S", 0.1)
    monkeypatch.setattr(follow_module, "CATCH_UP_S", 30.0)
    inbox: queue.Queue[FleetOdometry | FleetScans] = queue.Queue()
    up_to = UpToStop(lambda: _stamp(40), scans=False)
    up_to.catch_up(inbox, lambda m: pytest.fail("nothing came"))
    assert not up_to.odometry_in() and not up_to.complete() and up_to.ended == "quiet"


def test_the_wait_is_capped_but_not_by_the_followers_own_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """A follower slower than the wait's cap still takes what is in the inbox (its work is not
    counted); a stream that never reaches the stop's tick ends at the cap."""
    import clients.follow as follow_module

    monkeypatch.setattr(follow_module, "CATCH_UP_S", 0.2)
    monkeypatch.setattr(follow_module, "QUIET_NO_ODOMETRY_S", 30.0)
    inbox: queue.Queue[FleetOdometry | FleetScans] = queue.Queue()
    for t in range(1, 4):
        inbox.put(_odometry(t))
    taken: list[tuple[str, int]] = []
    stop_feeding = threading.Event()

    def slow(msg: FleetOdometry | FleetScans) -> None:
        taken.append(_tick(msg))
        stop_feeding.wait(0.15)  # three of these outlast the cap

    up_to = UpToStop(lambda: _stamp(100), scans=False)
    up_to.catch_up(inbox, slow)
    assert taken == [("FleetOdometry", t) for t in range(1, 4)] and up_to.ended == "cap"


def test_a_reset_during_the_follow_starts_the_streams_again() -> None:
    """Stamps taken back by a reset: the stop's limit is the new clock, and its scans are still
    waited for (the old run's newer stamps do not count)."""
    up_to = UpToStop(lambda: _stamp(5))
    for msg in (_odometry(3000), _scans(3000), _odometry(4), _scans(0)):
        assert up_to.keep(msg)
    assert up_to.newest_odometry == 4 * TICK_NS and up_to.newest_scans == 0
    inbox: queue.Queue[FleetOdometry | FleetScans] = queue.Queue()
    for msg in (_odometry(5), _scans(2), _odometry(6), _scans(7)):
        inbox.put(msg)
    taken: list[tuple[str, int]] = []
    up_to.catch_up(inbox, lambda m: taken.append(_tick(m)))
    assert taken == [("FleetOdometry", 5), ("FleetScans", 2)] and up_to.ended == "complete"


def test_ticks_whose_odometry_never_came_are_counted() -> None:
    """Two ticks missing between 2 and 5; a reset and a daemon's late part are no holes."""
    up_to = UpToStop(lambda: _stamp(0), tick_s=TICK_NS / 1e9)
    for t in (1, 2, 5, 6, 6, 4, *range(7, 41), 1, 2):  # ... then a reset back to tick 1
        up_to.keep(_odometry(t))
    assert up_to.missed_ticks == 2 and up_to.newest_odometry == 2 * TICK_NS
    up_to.keep(_odometry(100))
    assert up_to.missed_ticks == 2 + 97


def test_a_second_signal_stops_the_wait_and_the_drain() -> None:
    """The first SIGINT stops following; the second stops taking what is still queued (a
    follower minutes behind the fleet), and the output is written with what was taken."""
    import os
    import signal

    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    try:
        stop = stop_on_signals()
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.is_set() and not stop.hurry.is_set()
        inbox: queue.Queue[FleetOdometry | FleetScans] = queue.Queue()
        for t in range(1, 11):
            inbox.put(_odometry(t))
        taken: list[tuple[str, int]] = []

        def handle(msg: FleetOdometry | FleetScans) -> None:
            taken.append(_tick(msg))
            if len(taken) == 3:
                os.kill(os.getpid(), signal.SIGTERM)  # the second

        up_to = UpToStop(lambda: _stamp(10), hurry=stop.hurry)
        up_to.catch_up(inbox, handle)
        drain(inbox, handle, up_to)
        assert stop.hurry.is_set() and up_to.ended == "hurried"
        assert len(taken) == 3 and inbox.qsize() == 7
    finally:
        signal.signal(signal.SIGINT, before[0])
        signal.signal(signal.SIGTERM, before[1])
