"""A secured fleet made by ``fleet-security init``: TLS, users, access control, on loopback.

Each role against each action, allowed and refused; a peer without credentials, with a wrong
password or with another CA cannot connect; a user who declares the daemon's queryables or
publishes its topics is not heard (no impersonation).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest
import zenoh

from clients import FleetClient
from clients.security import init
from fleetcommon.zenoh_config import ZenohOptions
from protocol import FleetError
from protocol.errors import ErrorCode
from tests.conftest import ROOT, free_port, simd_command


@dataclass
class Secured:
    directory: Path
    port: int
    proc: subprocess.Popen[str]

    def client(self, user: str, timeout: float = 2.0) -> FleetClient:
        opts = ZenohOptions(mode="client", config_file=str(self.directory / f"{user}.json5"))
        return FleetClient(options=opts, timeout=timeout)


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Secured]:
    d = tmp_path_factory.mktemp("secure") / "fleet"
    port = free_port()
    init(d, ["tb3_0", "tb3_1"], ["localhost", "127.0.0.1"], None, port)
    log = (d.parent / "simd.log").open("w")
    cmd = simd_command("-c", str(d / "simd" / "simd.json5"), "--lockstep", "--world", "empty")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, text=True, cwd=ROOT)
    s = Secured(d, port, proc)
    deadline = time.monotonic() + 20
    while True:
        assert proc.poll() is None, (d.parent / "simd.log").read_text()
        try:
            with s.client("operator", timeout=1.0) as c:
                c.clock()
                c.spawn("tb3_0", 0.0, 0.0)
                c.spawn("tb3_1", 2.0, 0.0)
            break
        except FleetError:
            assert time.monotonic() < deadline, (d.parent / "simd.log").read_text()
            time.sleep(0.1)
    yield s
    proc.terminate()
    proc.wait(10)
    log.close()
    assert "warning" not in (d.parent / "simd.log").read_text()  # authenticated: no warning


def _refused(call: object) -> FleetError:
    with pytest.raises(FleetError) as e:
        call()  # type: ignore[operator]
    assert e.value.code in (ErrorCode.UNAVAILABLE, ErrorCode.TIMEOUT)
    return e.value


def _drives(c: FleetClient, op: FleetClient, ns: str, tries: int = 8, batched: bool = False) -> bool:
    """Whether ``c``'s cmd_vel (``batched``: a batch on ``P/commands``) moves ``ns``: a command,
    a short step, again until it moves or ``tries`` are used (a put is not acknowledged, and a
    loaded machine routes it late); the robot is stopped again after."""
    start = op.robot(ns)
    assert start is not None
    moved = False
    for _ in range(tries):
        if batched:
            c.drive_many([ns], [(0.2, 0.5)])
        else:
            c.drive(ns, 0.2, 0.5)
        time.sleep(0.1)
        op.step(2)
        now = op.robot(ns)
        assert now is not None
        if abs(now.pose.x - start.pose.x) > 1e-4 or abs(now.pose.yaw - start.pose.yaw) > 1e-4:
            moved = True
            break
    op.step(30)  # the watchdog stops it (0.5 s of sim time without commands)
    return moved


def _steps_until(op: FleetClient, seen: threading.Event, timeout: float = 10.0) -> bool:
    """Step until ``seen`` is set (a new subscription takes a moment to reach the daemon)."""
    deadline = time.monotonic() + timeout
    while not seen.is_set() and time.monotonic() < deadline:
        op.step(1)
        seen.wait(0.05)
    return seen.is_set()


def test_the_operator_does_everything(secured: Secured) -> None:
    with secured.client("operator") as op:
        r = op.spawn("extra", -2.0, 2.0)
        assert r.name == "extra"
        assert _drives(op, op, "tb3_0")
        assert _drives(op, op, "tb3_1", batched=True)
        op.pause()
        op.delete("extra")
        assert sorted(x.name for x in op.robots()) == ["tb3_0", "tb3_1"]


def test_the_observer_reads_and_changes_nothing(secured: Secured) -> None:
    with secured.client("observer") as ob, secured.client("operator") as op:
        assert sorted(r.name for r in ob.robots()) == ["tb3_0", "tb3_1"]
        assert ob.world().name == "empty" and ob.clock().lockstep
        seen = threading.Event()
        ob.on_odom("tb3_1", lambda ns, msg: seen.set())
        assert _steps_until(op, seen)  # every topic is readable
        err = _refused(lambda: ob.spawn("intruder", -2.0, -2.0))
        assert "access control" in err.message and "observer" in err.message
        _refused(lambda: ob.delete("tb3_0"))
        _refused(lambda: ob.step(5))
        _refused(lambda: ob.reset())
        tick = op.clock().tick
        assert not _drives(ob, op, "tb3_0")  # its cmd_vel never reached the daemon
        assert sorted(r.name for r in op.robots()) == ["tb3_0", "tb3_1"] and op.clock().tick == tick + 8 * 2 + 30


def test_a_driver_drives_and_reads_its_own_robot_only(secured: Secured) -> None:
    with secured.client("driver_tb3_0") as dr, secured.client("operator") as op:
        assert [r.name for r in dr.robots()] == ["tb3_0", "tb3_1"]  # the list is for everyone
        mine, theirs = threading.Event(), threading.Event()
        dr.on_odom("tb3_0", lambda ns, msg: mine.set())
        dr.on_odom("tb3_1", lambda ns, msg: theirs.set())
        assert _drives(dr, op, "tb3_0")
        assert _steps_until(op, mine) and not theirs.is_set()
        assert not _drives(dr, op, "tb3_1")
        assert not _drives(dr, op, "tb3_0", batched=True)  # a batch could name any robot: not a driver's
        _refused(lambda: dr.spawn("mine_too", -2.0, -2.0))
        _refused(lambda: dr.pause())


def test_nobody_answers_or_publishes_in_the_daemons_place(secured: Secured) -> None:
    """A user who declares the fleet's queryables and puts fake odometry is not heard."""
    with secured.client("observer") as rogue, secured.client("operator") as op:
        fake = rogue.session.declare_queryable("fleet/spawn", lambda q: q.reply("fleet/spawn", b"\x80"))
        fake_list = rogue.session.declare_queryable("fleet/robots", lambda q: q.reply("fleet/robots", b"\x80"))
        time.sleep(0.5)
        replies = list(op.session.get("fleet/robots?format=json", timeout=2.0))
        assert len(replies) == 1 and replies[0].ok is not None  # the daemon's, and only it
        assert [r["name"] for r in json.loads(replies[0].ok.payload.to_bytes())["robots"]] == ["tb3_0", "tb3_1"]
        raw: list[bytes] = []
        sub = op.session.declare_subscriber("fleet/tb3_0/odom", lambda s: raw.append(s.payload.to_bytes()))
        deadline = time.monotonic() + 10.0
        while len(raw) < 3 and time.monotonic() < deadline:  # until the subscription is surely in place
            op.step(1)
            time.sleep(0.05)
        rogue.session.put("fleet/tb3_0/odom", b"not odometry")
        time.sleep(0.5)
        op.step(2)
        assert len(raw) >= 3 and b"not odometry" not in raw
        sub.undeclare()
        assert op.spawn("real", -2.0, -2.0).name == "real"  # answered by the daemon, not the fake
        op.delete("real")
        fake.undeclare()
        fake_list.undeclare()


def test_the_healthcheck_asks_with_its_own_config(secured: Secured) -> None:
    """In a container the healthcheck must log in too: health.json5, made by init, lets it."""

    def health(*extra: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "simd.healthcheck", "-e", f"tls/127.0.0.1:{secured.port}",
                               *extra], capture_output=True, text=True, cwd=ROOT, timeout=60)  # fmt: skip

    ok = health("-c", str(secured.directory / "simd" / "health.json5"))
    assert ok.returncode == 0 and "healthy" in ok.stdout, ok.stdout
    assert health().returncode == 1  # no TLS, no user: refused
    # as in the image: no -e, nothing the entrypoint could know; the config's own endpoint
    env = {**os.environ, "SIMD_HEALTH_CONFIG": str(secured.directory / "simd" / "health.json5"),
           "SIMD_STATE_FILE": str(secured.directory / "no-such-file.json")}  # fmt: skip
    image_like = subprocess.run([sys.executable, "-m", "simd.healthcheck"], capture_output=True, text=True,
                                cwd=ROOT, timeout=60, env=env)  # fmt: skip
    assert image_like.returncode == 0 and "health.json5" in image_like.stdout, image_like.stdout


def _bare_config(secured: Secured, **changes: object) -> str:
    conf = json.loads("\n".join(line for line in (secured.directory / "observer.json5").read_text().splitlines()
                                if not line.startswith("//")))  # fmt: skip
    tls, auth = conf["transport"]["link"]["tls"], conf["transport"]["auth"]
    if changes.get("no_user"):
        del conf["transport"]["auth"]
    if "password" in changes:
        auth["usrpwd"]["password"] = changes["password"]
    if "ca" in changes:
        tls["root_ca_certificate"] = changes["ca"]
    if "endpoint" in changes:
        conf["connect"]["endpoints"] = [changes["endpoint"]]
    path = secured.directory.parent / f"bare-{len(changes)}-{sorted(changes)[0]}.json5"
    path.write_text(json.dumps(conf))
    return str(path)


@pytest.mark.parametrize(
    "changes",
    [{"no_user": True}, {"password": "guess"}, {"ca": "OTHER"}, {"endpoint": "tcp/127.0.0.1:PORT"}],
    ids=["no credentials", "wrong password", "another CA", "plain tcp"],
)
def test_without_the_right_credentials_nobody_connects(
    secured: Secured, tmp_path: Path, changes: dict[str, object]
) -> None:
    if changes.get("ca") == "OTHER":
        other = tmp_path / "other"
        init(other, [], ["localhost"], None, secured.port)  # a CA of its own
        changes = {"ca": str(other / "ca.pem")}
    if "endpoint" in changes:
        changes = {"endpoint": f"tcp/127.0.0.1:{secured.port}"}
    opts = ZenohOptions(mode="client", config_file=_bare_config(secured, **changes))
    with pytest.raises(FleetError) as e:
        FleetClient(options=opts, timeout=1.0).clock()
    assert e.value.code == ErrorCode.UNAVAILABLE
    with pytest.raises(zenoh.ZError):  # as any zenoh tool would see it
        conf = zenoh.Config.from_file(str(opts.config_file))
        conf.insert_json5("connect/timeout_ms", "1000")
        zenoh.open(conf).close()


def test_fleet_security_init_refuses_what_it_cannot_do(tmp_path: Path) -> None:
    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "clients.security", "init", *args], capture_output=True,
                              text=True, cwd=ROOT, timeout=60)  # fmt: skip

    ok = run(str(tmp_path / "a"), "--robots", "tb3_0")
    assert ok.returncode == 0, ok.stderr
    assert oct((tmp_path / "a" / "simd" / "users.txt").stat().st_mode & 0o777) == "0o600"
    before = (tmp_path / "a" / "simd" / "users.txt").read_bytes()
    for args, message in [
        ((str(tmp_path / "a"),), "is not empty"),
        ((str(tmp_path / "b"), "--robots", "bad/name"), "--robots"),
        ((str(tmp_path / "c"), "--simd-dir", "relative"), "absolute"),
        ((str(tmp_path / "no" / "such" / "d"),), "does not exist"),
        ((str(tmp_path / "e"), "--port", "0"), "--port"),
        ((str(tmp_path / "f"), "--daemons", "a,a"), "twice"),
        ((str(tmp_path / "g"), "--daemons", "a,b/c"), "--daemons"),
    ]:
        p = run(*args)
        assert p.returncode == 2 and p.stderr.count("\n") == 1 and message in p.stderr, p.stderr
    unwritable = run("/proc/fleetsim-security-test")  # (procfs: no directory can be made there, even as root)
    assert unwritable.returncode == 1 and unwritable.stderr.count("\n") == 1, unwritable.stderr
    assert "error: /proc/fleetsim-security-test: No such file" in unwritable.stderr, unwritable.stderr
    assert (tmp_path / "a" / "simd" / "users.txt").read_bytes() == before
    for never in "bcfg":
        assert not (tmp_path / never).exists(), never


def test_a_fleet_of_daemons_behind_a_secured_router(tmp_path: Path) -> None:
    """``fleet-security init --daemons a,b``: the router checks everyone (TLS, users, access
    control); the daemons are its clients as users of their own and do everything a shared
    fleet needs through it (placement, one list, one clock); users keep their roles; nobody
    but a daemon answers the fleet or puts a daemon's tick."""
    from clients.api import observed_arrays
    from protocol.control import DaemonTick
    from protocol.placement import owner

    d = tmp_path / "fleet"
    port = free_port()
    init(d, ["tb3_0"], ["localhost", "127.0.0.1"], None, port, daemons=["a", "b"])
    assert not (d / "simd").exists() and (d / "router" / "router.json5").exists()
    logs = {k: (tmp_path / f"{k}.log").open("w") for k in ("router", "a", "b")}
    procs = [subprocess.Popen([sys.executable, "-m", "simd.router", "-c", str(d / "router" / "router.json5")],
                              stdout=logs["router"], stderr=subprocess.STDOUT, text=True, cwd=ROOT)]  # fmt: skip
    for daemon in ("a", "b"):
        cmd = simd_command("-c", str(d / f"simd_{daemon}" / "simd.json5"), "--join", "--id", daemon, "--lockstep",
                           "--world", "empty")  # fmt: skip
        procs.append(subprocess.Popen(cmd, stdout=logs[daemon], stderr=subprocess.STDOUT, text=True, cwd=ROOT))
    secured = Secured(d, port, procs[0])
    try:
        with secured.client("operator") as op, secured.client("observer") as ob:
            deadline = time.monotonic() + 30
            while [x.id for x in op.daemons()] != ["a", "b"]:
                assert time.monotonic() < deadline and all(p.poll() is None for p in procs), [
                    (tmp_path / f"{k}.log").read_text() for k in logs
                ]
                time.sleep(0.2)
            names = [f"r{i}" for i in range(6)]
            for i, n in enumerate(names):
                assert op.spawn(n, float(i), 0.0).daemon == owner(n, ["a", "b"])
            assert [(r.name, r.daemon) for r in ob.robots()] == [(n, owner(n, ["a", "b"])) for n in names]
            assert [x.id for x in ob.daemons()] == ["a", "b"]  # the observer reads the daemons too
            ticks: list[DaemonTick] = []
            op.session.declare_subscriber(
                "fleet/daemons/*/tick",
                lambda s: ticks.append(msgspec.msgpack.decode(s.payload.to_bytes(), type=DaemonTick)),
            )
            rogue = ob.session
            fake = rogue.declare_queryable("fleet/spawn", lambda q: q.reply("fleet/spawn", b"\x80"))
            time.sleep(0.5)
            evil = DaemonTick(daemon="evil", tick=0, namespaces=["ghost"], models=["burger"], poses=bytes(24))
            rogue.put("fleet/daemons/evil/tick", msgspec.msgpack.encode(evil))
            reply = op.step(6, observe=names, packed=True, publish=False)  # both daemons, one clock, through the router
            assert reply.packed is not None and observed_arrays(reply.packed).names == names
            assert {t.daemon for t in ticks} == {"a", "b"}  # the daemons' ticks, and not the rogue's
            assert op.spawn("r9", 9.0, 0.0).name == "r9"  # the daemons answer, not the fake
            fake.undeclare()  # (its own session would hear it)
            _refused(lambda: ob.spawn("intruder", -2.0, -2.0))
        health = subprocess.run([sys.executable, "-m", "simd.healthcheck", "-c", str(d / "simd_a" / "health.json5"),
                                 "--id", "a"], capture_output=True, text=True, cwd=ROOT, timeout=60)  # fmt: skip
        assert health.returncode == 0 and "fleet/daemons/a/clock answered" in health.stdout, health.stdout
    finally:
        for p in procs:
            p.terminate()
            p.wait(10)
        for f in logs.values():
            f.close()
    for k in ("a", "b"):
        assert "warning" not in (tmp_path / f"{k}.log").read_text()  # clients of the router: nothing listens
