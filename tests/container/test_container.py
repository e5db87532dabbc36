"""The container image (docker/Dockerfile) built and run with podman, driven from the host.

The ``container`` tests build ``localhost/fleetsim:test`` from the repo on the local
Debian base image (``docker/ci-setup.sh`` makes it; the image build stays cached between
runs), start it with ``--network=host`` on a free loopback port, and check what a user
relies on: robots over zenoh from the host, the healthcheck, a non-root PID 1 and a clean
exit 0 on SIGTERM.

Skip rule: they skip, with the reason, when podman cannot run here (no ``podman`` binary,
``podman info`` fails, or the base image is missing: run ``docker/ci-setup.sh`` as root).
With ``FLEETSIM_REQUIRE_CONTAINER=1`` (set it on CI, after ci-setup.sh) each of these is a
failure instead, so a broken setup cannot hide behind a skip.

The other tests here (the ``SIMD_*`` mapping and the healthcheck's target) need no podman.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from clients import FleetClient
from protocol import FleetError
from simd import container_entry, healthcheck
from simd.cli import build_parser
from tests.conftest import free_port

ROOT = Path(__file__).resolve().parents[2]
BASE_IMAGE = os.environ.get("FLEETSIM_BASE_IMAGE", "localhost/bookworm-py:base")
IMAGE = "localhost/fleetsim:test"
BUILD_TIMEOUT = 900.0


def _podman(*args: str, timeout: float = 60.0, check: bool = False) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["podman", *args], capture_output=True, text=True, timeout=timeout, check=check, cwd=ROOT)


def _unavailable() -> str | None:
    """Why podman cannot run the image here, or None."""
    if shutil.which("podman") is None:
        return "podman is not installed (run docker/ci-setup.sh as root)"
    info = _podman("info", "--format", "{{.Host.OCIRuntime.Name}}")
    if info.returncode != 0:
        return f"`podman info` fails: {(info.stderr or info.stdout).strip()[-300:]}"
    if _podman("image", "exists", BASE_IMAGE).returncode != 0:
        return f"base image {BASE_IMAGE} is missing (run docker/ci-setup.sh as root to build it)"
    return None


@pytest.fixture(scope="module")
def image() -> str:
    reason = _unavailable()
    if reason is not None:
        if os.environ.get("FLEETSIM_REQUIRE_CONTAINER") == "1":
            pytest.fail(f"FLEETSIM_REQUIRE_CONTAINER=1 but {reason}")
        pytest.skip(reason)
    t0 = time.monotonic()
    # --format docker: OCI images (podman's default) drop the HEALTHCHECK
    build = _podman(
        "build", "--format", "docker", "--network=host", "--build-arg", f"BASE={BASE_IMAGE}",
        "-f", "docker/Dockerfile", "-t", IMAGE, ".",
        timeout=BUILD_TIMEOUT,
    )  # fmt: skip
    if build.returncode != 0:
        pytest.fail(f"podman build failed ({build.returncode}):\n{(build.stdout + build.stderr)[-4000:]}")
    print(f"podman build: {time.monotonic() - t0:.1f} s")
    return IMAGE


@dataclass
class Container:
    name: str
    port: int
    clients: list[FleetClient] = field(default_factory=list)

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    def client(self, timeout: float = 3.0) -> FleetClient:
        c = FleetClient(self.endpoint, timeout=timeout)
        self.clients.append(c)
        return c

    def close_clients(self) -> None:
        for c in self.clients:
            c.close()
        self.clients.clear()

    def logs(self) -> str:
        r = _podman("logs", self.name)
        return r.stdout + r.stderr

    def inspect(self, fmt: str) -> str:
        return _podman("inspect", "--format", fmt, self.name).stdout.strip()


@pytest.fixture
def container(image: str) -> Iterator[Container]:
    port = free_port()
    name = f"fleetsim-test-{os.getpid()}-{port}"
    run = _podman(
        "run", "-d", "--name", name, "--network=host",
        "-e", "SIMD_SEED=7", "-e", "SIMD_WORLD=turtlebot3_world",
        image, "-l", f"tcp/127.0.0.1:{port}",
    )  # fmt: skip
    ctr = Container(name, port)
    try:
        if run.returncode != 0:
            pytest.fail(f"podman run failed ({run.returncode}): {run.stderr.strip()}")
        deadline = time.monotonic() + 30.0
        while True:
            if ctr.inspect("{{.State.Running}}") != "true":
                pytest.fail(f"the container exited early:\n{ctr.logs()}")
            try:
                with FleetClient(ctr.endpoint, timeout=1.0) as c:
                    c.clock()
                break
            except FleetError:
                if time.monotonic() > deadline:
                    pytest.fail(f"simd in the container did not answer within 30 s:\n{ctr.logs()}")
                time.sleep(0.1)
        yield ctr
    finally:
        ctr.close_clients()
        _podman("rm", "-f", "-t", "0", name)  # the image stays, cached


@pytest.mark.container
@pytest.mark.slow
@pytest.mark.timeout(BUILD_TIMEOUT + 120)
def test_image_serves_robots_is_healthy_and_stops_on_sigterm(container: Container) -> None:
    ctr = container
    # startup line on stdout, flags from the command line and from SIMD_* variables
    logs = ctr.logs()
    assert "simd: world turtlebot3_world" in logs, logs
    assert f"listening on tcp/127.0.0.1:{ctr.port}" in logs, logs
    assert "seed 7" in logs, logs

    # simd itself is PID 1 (no shell in between), as a non-root user
    cmdline = _podman("exec", ctr.name, "cat", "/proc/1/cmdline").stdout.split("\0")
    assert cmdline[:3] == ["python", "-m", "simd.container_entry"], cmdline
    uid = _podman("exec", ctr.name, "id", "-u").stdout.strip()
    assert uid.isdigit() and int(uid) != 0, uid

    # robots from the host: spawn, odom, scan, drive and move
    fleet = ctr.client()
    rec = fleet.spawn("tb3_0", x=-2.0, y=-0.5)
    assert rec.namespace == "tb3_0"
    assert fleet.wait_for_robot("tb3_0", timeout=5.0)
    start = fleet.wait_odom("tb3_0").pose.pose.position
    scan = fleet.wait_scan("tb3_0")
    ranges = scan.ranges_array()
    assert len(ranges) == 360
    assert any(math.isfinite(r) for r in ranges)
    t_end = time.monotonic() + 1.5
    while time.monotonic() < t_end:
        fleet.drive("tb3_0", 0.2, 0.0)
        time.sleep(0.1)
    fleet.stop("tb3_0")
    end = fleet.wait_odom("tb3_0").pose.pose.position
    moved = math.hypot(end.x - start.x, end.y - start.y)
    assert moved > 0.1, (start, end)

    # healthcheck: podman cannot run it on a timer without systemd here, so it is run by
    # hand; the status goes starting -> healthy
    flow = [ctr.inspect("{{.State.Health.Status}}")]
    assert flow[0] in ("starting", "healthy"), flow
    deadline = time.monotonic() + 30.0
    while flow[-1] != "healthy":
        assert time.monotonic() < deadline, f"not healthy within 30 s: {flow}\n{ctr.inspect('{{json .State.Health}}')}"
        _podman("healthcheck", "run", ctr.name)
        status = ctr.inspect("{{.State.Health.Status}}")
        if status != flow[-1]:
            flow.append(status)
        else:
            time.sleep(0.5)
    health = json.loads(ctr.inspect("{{json .State.Health}}"))
    assert health["Log"][-1]["ExitCode"] == 0
    assert "fleet/clock answered" in health["Log"][-1]["Output"]
    print(f"health: {' -> '.join(flow)}")
    # ... and it is the daemon that answers: a wrong prefix is unhealthy
    wrong = _podman("exec", ctr.name, "python", "-m", "simd.healthcheck", "--prefix", "nope", "--timeout", "1")
    assert wrong.returncode == 1, wrong.stdout + wrong.stderr
    assert "UNHEALTHY" in wrong.stdout

    # SIGTERM (the image's STOPSIGNAL): exit code 0, well before podman's 10 s SIGKILL
    ctr.close_clients()
    t0 = time.monotonic()
    stop = _podman("stop", "-t", "10", ctr.name, timeout=30.0)
    took = time.monotonic() - t0
    assert stop.returncode == 0, stop.stderr
    exit_code = ctr.inspect("{{.State.ExitCode}}")
    print(f"SIGTERM: exit code {exit_code} after {took:.2f} s")
    assert exit_code == "0", ctr.logs()
    assert took < 5.0
    assert "received SIGTERM, stopping" in ctr.logs()


# -- no podman needed ----------------------------------------------------------------------


def test_env_becomes_flags_and_command_line_wins() -> None:
    env = {
        "SIMD_WORLD": "empty",
        "SIMD_SEED": "3",
        "SIMD_RTF": "2",
        "SIMD_LOCKSTEP": "yes",
        "SIMD_NO_NOISE": "0",
        "SIMD_LISTEN": "tcp/0.0.0.0:1, tcp/[::]:2",
        "SIMD_CFG": "a/b:[1,2]\nc:true",
        "HOME": "/x",
    }
    argv = container_entry.build_argv(["--seed", "5", "--rtf=0"], env)
    args = build_parser().parse_args(argv)
    assert args.world == "empty"
    assert args.seed == 5 and args.rtf == 0.0
    assert args.lockstep and not args.no_noise
    assert args.listen == ["tcp/0.0.0.0:1", "tcp/[::]:2"]
    assert args.cfg == ["a/b:[1,2]", "c:true"]
    # a repeatable flag on the command line replaces its variable, it does not add to it
    argv = container_entry.build_argv(["-l", "tcp/127.0.0.1:9"], env)
    assert argv.count("--listen") + argv.count("-l") == 1
    # nothing said: every interface of the container; a config file: its own endpoints
    assert container_entry.build_argv([], {})[:2] == ["--listen", "tcp/0.0.0.0:7447"]
    assert "--listen" not in container_entry.build_argv(["-c", "z.json5"], {})
    # a daemon that is a client of a router (docker/compose.fleet.yaml) listens on nothing
    assert "--listen" not in container_entry.build_argv(["-m", "client", "-e", "tcp/router:7447"], {})
    assert "--listen" not in container_entry.build_argv([], {"SIMD_MODE": "client", "SIMD_CONNECT": "tcp/r:1"})
    with pytest.raises(container_entry.EnvError):
        container_entry.build_argv([], {"SIMD_PAUSED": "maybe"})


def test_healthcheck_target(tmp_path: Path) -> None:
    state = tmp_path / "state.json"
    env = {"SIMD_STATE_FILE": str(state), "SIMD_LISTEN": "tcp/0.0.0.0:7500", "SIMD_PREFIX": "p"}
    t = healthcheck.resolve_target(None, None, env)
    assert (t.connect, t.prefix) == (["tcp/127.0.0.1:7500"], "p")
    container_entry.write_state(["-l", "tcp/[::]:7600", "--prefix", "q"], str(state))
    t = healthcheck.resolve_target(None, None, env)
    assert (t.connect, t.prefix) == (["tcp/[::1]:7600"], "q")
    t = healthcheck.resolve_target(["tcp/h:1"], "r", env)
    assert (t.connect, t.prefix) == (["tcp/h:1"], "r")
    assert healthcheck.resolve_target(None, None, {"SIMD_STATE_FILE": str(tmp_path / "no")}).connect == [
        "tcp/127.0.0.1:7447"
    ]
    assert (
        t.daemon is None and healthcheck.resolve_target(None, None, env).daemon is None
    )  # one daemon: the fleet's clock
    # a daemon sharing a fleet: the entrypoint records its id, and its own clock is asked
    container_entry.write_state(["-m", "client", "-e", "tcp/router:7447", "--join", "--id", "a"], str(state))
    t = healthcheck.resolve_target(None, None, env)
    assert (t.connect, t.prefix, t.daemon) == (["tcp/router:7447"], "fleet", "a")
    assert healthcheck.resolve_target(None, None, env, "b").daemon == "b"  # --id wins
