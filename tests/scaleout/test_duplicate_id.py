"""A duplicate ``--id`` in a shared fleet is always refused: after the fleet has been busy
(hundreds of robots spread over two daemons, paused, stepped and resumed) and with it running,
a third daemon with the first one's id exits with the one-line refusal, try after try; of two
started with one id at once, one runs. Real processes through a router on loopback, and a
look at a fleet that never finishes answering on two real sessions."""

from __future__ import annotations

import re
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from clients import FleetClient, wait_until
from protocol.control import SpawnRequest
from protocol.keys import Keys
from simd.adapters.fleet.presence import Unanswered, infos
from tests.conftest import ROOT, free_port, simd_command
from tests.scaleout.test_router import _start, _stop, router  # noqa: F401  (the router fixture)
from tests.zraw import client_config

Router = tuple[str, subprocess.Popen[str], Path]
REFUSAL = "a daemon with --id 'a' already serves prefix 'fleet': give this one another --id"


@pytest.fixture
def busy_fleet(router: Router, tmp_path: Path) -> Iterator[str]:  # noqa: F811
    """Daemons a and b sharing 400 robots, after a pause, a step and a resume: running."""
    endpoint = router[0]
    args = ["-m", "client", "-e", endpoint, "--join", "--world", "empty", "--no-noise", "--max-robots", "1000"]
    daemons = [_start(simd_command(*args, "--id", d), tmp_path / f"simd-{d}.log") for d in ("a", "b")]
    try:
        with FleetClient(endpoint, timeout=10.0) as c:
            assert wait_until(lambda: [d.id for d in c.daemons()] == ["a", "b"], 20.0)
            spread = c.spawn_many(
                SpawnRequest(name=f"r{i}", x=float(i % 20) - 9.5, y=float(i // 20) - 9.5) for i in range(400)
            )
            assert {r.daemon for r in spread} == {"a", "b"}
            c.pause()
            c.step(30)
            c.resume()
        yield endpoint
    finally:
        for p in daemons:
            _stop(p)


def _drive_all(endpoint: str, stop: threading.Event) -> None:
    """A driver at full rate: cmd_vel to every robot, as fast as it can put them."""
    with FleetClient(endpoint, timeout=10.0) as c:
        names = [f"r{i}" for i in range(400)]
        while not stop.is_set():
            for ns in names:
                c.drive(ns, 0.05, 0.1)


def test_a_third_daemon_with_a_taken_id_is_refused_every_time(busy_fleet: str) -> None:
    endpoint = busy_fleet
    stop = threading.Event()
    driver = threading.Thread(target=_drive_all, args=(endpoint, stop))
    driver.start()
    try:
        for _ in range(3):
            r = subprocess.run(
                simd_command("-m", "client", "-e", endpoint, "--join", "--id", "a", "--world", "empty"),
                cwd=ROOT, capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            lines = r.stderr.strip().splitlines()
            assert r.returncode == 2 and lines == [f"simd: error: {REFUSAL}"], (
                r.returncode,
                r.stderr,
                r.stdout[-2000:],
            )
    finally:
        stop.set()
        driver.join(30)
    with FleetClient(endpoint, timeout=10.0) as c:
        assert [d.id for d in c.daemons()] == ["a", "b"]
        assert len(c.robots()) == 400  # the fleet is as it was


def test_of_two_daemons_started_with_one_id_at_once_one_runs(router: Router, tmp_path: Path) -> None:  # noqa: F811
    endpoint = router[0]
    cmd = simd_command("-m", "client", "-e", endpoint, "--join", "--id", "c", "--world", "empty")
    twins = [_start(cmd, tmp_path / f"simd-c{k}.log") for k in range(2)]
    try:
        assert wait_until(lambda: any(p.poll() is not None for p in twins), 60.0)
        left = [k for k, p in enumerate(twins) if p.poll() is not None]
        assert len(left) == 1 and twins[left[0]].returncode == 2, left
        said = (tmp_path / f"simd-c{left[0]}.log").read_text()
        assert "a daemon with --id 'c' already serves prefix 'fleet'" in said, said
        with FleetClient(endpoint, timeout=10.0) as c:
            assert [d.id for d in c.daemons()] == ["c"]
            assert twins[1 - left[0]].poll() is None
    finally:
        for p in twins:
            _stop(p)


def test_a_fleet_that_does_not_finish_answering_is_never_taken_for_an_empty_one() -> None:
    """The look ends on every answer, not on a timer: a daemon that never finishes its answer
    makes the look fail (the daemon does not start) rather than look like nobody there."""
    port = free_port()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{port}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    held: list[zenoh.Query] = []
    with zenoh.open(conf) as mute, zenoh.open(client_config(f"tcp/127.0.0.1:{port}")) as joiner:
        queryable = mute.declare_queryable("fleet/daemons", held.append)  # holds each query, answers nothing
        querier = joiner.declare_querier("fleet/daemons")
        assert wait_until(lambda: querier.matching_status.matching, 5.0)  # type: ignore[attr-defined]  # stub: bool
        with pytest.raises(Unanswered, match=re.escape("no complete answer on fleet/daemons within 0.5 s")):
            infos(joiner, Keys(), timeout=0.5)
        assert held  # it was asked
        held.clear()
        querier.undeclare()
        queryable.undeclare()
