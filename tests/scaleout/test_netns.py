"""The shared fleet across network namespaces, as across hosts on one LAN: the router, two
``--join`` daemons and the clients each in a namespace of its own, joined by veth pairs on a
bridge. A daemon's link is cut for 5 s and brought back (the fleet recovers without a
restart); a daemon is killed and restarted with its state file (its robots come back). The
clients are the ``fleet`` CLI, run in the clients' namespace. Needs root and ``ip netns``:
skipped, with the reason, where the test runner may not create namespaces."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from protocol.placement import owner
from tests.conftest import ROOT
from tests.scaleout.test_router import _stop, _wait_for

SUBNET = "10.77.0"  # inside the namespaces only: the host's own network is untouched
ROLES = ("router", "a", "b", "client")
ROUTER = f"tcp/{SUBNET}.1:7447"
CUT_S = 5.0


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)


class Lan:
    """A bridge in a namespace of its own and one namespace per role, each with a veth pair to
    the bridge and the address ``SUBNET.<k>`` (router 1, a 2, b 3, client 4)."""

    def __init__(self) -> None:
        self.tag = uuid.uuid4().hex[:6]
        self.created: list[str] = []

    def ns(self, role: str) -> str:
        return f"fs{self.tag}-{role}"

    def up(self) -> None:
        hub = self.ns("hub")
        self._must("netns", "add", hub)
        self.created.append(hub)
        self._must("-n", hub, "link", "add", "br0", "type", "bridge")
        self._must("-n", hub, "link", "set", "br0", "up")
        for k, role in enumerate(ROLES, start=1):
            ns, host_end, ns_end = self.ns(role), f"fs{self.tag}{k}h", f"fs{self.tag}{k}e"
            self._must("netns", "add", ns)
            self.created.append(ns)
            self._must("link", "add", host_end, "type", "veth", "peer", "name", ns_end)
            self._must("link", "set", host_end, "netns", hub)
            self._must("link", "set", ns_end, "netns", ns)
            self._must("-n", hub, "link", "set", host_end, "master", "br0", "up")
            self._must("-n", ns, "link", "set", ns_end, "name", "eth0")
            self._must("-n", ns, "addr", "add", f"{SUBNET}.{k}/24", "dev", "eth0")
            self._must("-n", ns, "link", "set", "eth0", "up")
            self._must("-n", ns, "link", "set", "lo", "up")

    def link(self, role: str, state: str) -> None:
        self._must("-n", self.ns(role), "link", "set", "eth0", state)

    def down(self) -> None:
        for ns in reversed(self.created):  # a namespace's veth end goes with it
            _ip("netns", "del", ns)

    def _must(self, *args: str) -> None:
        done = _ip(*args)
        if done.returncode != 0:
            raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.strip()}")

    def start(self, role: str, args: list[str], log: Path) -> subprocess.Popen[str]:
        with log.open("w") as f:
            return subprocess.Popen(
                ["ip", "netns", "exec", self.ns(role), sys.executable, *args],
                stdout=f, stderr=subprocess.STDOUT, text=True, cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )  # fmt: skip

    def fleet(self, *args: str, timeout: float = 3.0) -> Any:
        """``fleet ARGS --json`` from the clients' namespace, decoded."""
        done = subprocess.run(
            ["ip", "netns", "exec", self.ns("client"), sys.executable, "-m", "clients.fleet.cli", *args,
             "-e", ROUTER, "--timeout", str(timeout), "--json"],
            capture_output=True, text=True, cwd=ROOT, timeout=60,
        )  # fmt: skip
        assert done.returncode in (0, 3), done.stderr
        return json.loads(done.stdout) if done.returncode == 0 else None


@pytest.fixture
def lan() -> Iterator[Lan]:
    if not sys.platform.startswith("linux") or shutil.which("ip") is None:
        pytest.skip("network namespaces need Linux and iproute2's ip")
    net = Lan()
    try:
        net.up()
    except (RuntimeError, OSError) as e:
        net.down()
        pytest.skip(f"this test runner may not create network namespaces ({e})")
    try:
        yield net
    finally:
        net.down()


def _wait(predicate: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, what
        time.sleep(0.2)


def test_a_fleet_across_namespaces_survives_a_cut_link_and_a_killed_daemon(lan: Lan, tmp_path: Path) -> None:
    procs: list[subprocess.Popen[str]] = []

    def daemon(d: str, log: str) -> subprocess.Popen[str]:
        args = ["-m", "simd.cli", "-m", "client", "-e", ROUTER, "--join", "--id", d, "--world", "empty",
                "--no-noise", "--state", str(tmp_path / f"state-{d}.json")]  # fmt: skip
        p = lan.start(d, args, tmp_path / log)
        procs.append(p)
        return p

    def daemons() -> list[str]:
        found = lan.fleet("daemons")
        return sorted(d["id"] for d in found) if found else []

    def robots() -> dict[str, str]:
        found = lan.fleet("list")
        return {r["name"]: r["daemon"] for r in found} if found else {}

    try:
        router = lan.start("router", ["-m", "simd.router", "-l", ROUTER], tmp_path / "router.log")
        procs.append(router)
        _wait_for(tmp_path / "router.log", "fleet-router: routing on", router)
        daemon("a", "simd-a.log")
        b = daemon("b", "simd-b.log")
        _wait(lambda: daemons() == ["a", "b"], 30.0, "both daemons listed from the clients' namespace")
        names = [f"r{i}" for i in range(6)]
        placed = {n: owner(n, ["a", "b"]) for n in names}
        assert set(placed.values()) == {"a", "b"}
        for i, n in enumerate(names):
            assert lan.fleet("spawn", n, "--x", str(float(i)))["daemon"] == placed[n]
        assert robots() == placed

        # b's link goes down for 5 s: b cannot answer meanwhile, and the fleet recovers without a restart
        lan.link("b", "down")
        cut = time.monotonic()
        assert daemons() == ["a"]
        assert robots() == {n: d for n, d in placed.items() if d == "a"}
        time.sleep(max(0.0, CUT_S - (time.monotonic() - cut)))
        lan.link("b", "up")
        _wait(lambda: robots() == placed, 30.0, "b's robots back after its link came back")
        assert b.poll() is None and daemons() == ["a", "b"]
        late = next(n for n in (f"s{i}" for i in range(50)) if owner(n, ["a", "b"]) == "b")
        assert lan.fleet("spawn", late, "--y", "3")["daemon"] == "b"  # b places spawns again
        placed[late] = "b"

        # b killed: its robots leave, spawns go to a; restarted with its state file, they come back
        state = tmp_path / "state-b.json"
        _wait(lambda: late in state.read_text(), 10.0, "the spawn saved (within 0.2 s: docs/robustness.md)")
        b.send_signal(signal.SIGKILL)
        b.wait(10)
        on_a = {n: d for n, d in placed.items() if d == "a"}
        _wait(lambda: robots() == on_a, 30.0, "b's robots gone with b")
        assert lan.fleet("spawn", "while_b_is_away", "--y", "-3")["daemon"] == "a"
        placed["while_b_is_away"] = "a"
        daemon("b", "simd-b2.log")
        _wait(lambda: robots() == placed, 30.0, "b's robots back from its state file")
        assert "restored" in (tmp_path / "simd-b2.log").read_text()
    finally:
        for p in procs:
            _stop(p)
