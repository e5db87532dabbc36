"""``fleet-ros smoke``: fleetsim against a real ROS 2 install, one command, a table to paste.

For a user with ROS 2 and rmw_zenoh (``RMW_IMPLEMENTATION=rmw_zenoh_cpp``, a sourced
``setup.bash``). It starts ``simd --ros2`` on turtlebot3_world (joining the rmw_zenoh router on
``tcp/localhost:7447`` if one listens there, else serving as the router itself), then runs the
ROS 2 tools a TurtleBot3 user would, each with a time limit:

1. ``ros2 service call /spawn_entity`` (gazebo_msgs) for burger_1 in TB3_1;
2. ``ros2 topic list -t``: the robot's topics with their types;
3. ``ros2 topic echo --once /TB3_1/odom``: its frames;
4. ``ros2 topic hz /TB3_1/odom`` for a few seconds: about 30 Hz;
5. a teleop publish (``ros2 topic pub`` of TwistStamped, Twist on Humble), then the odometry
   again: the robot moved;
6. ``ros2 param list``: the daemon's nodes, with ``use_sim_time``;
7. ``ros2 bag record`` for 5 s, then ``ros2 bag info``: messages of every topic.

It prints a table (smoke_checks.py) with the versions it ran with, and the output of every
command that failed. What the outputs are expected to look like comes from the tools' sources;
**nobody has run this against ROS yet** (docs/ros2.md): the first run is also the test of that.

The commands run through a :data:`Run` function, so the tests drive all of it with recorded
outputs and no ROS.
"""

from __future__ import annotations

import os
import platform
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

from clients.ros.smoke_checks import (
    FAIL,
    Outcome,
    Verdict,
    check_bag,
    check_echo,
    check_hz,
    check_param_list,
    check_spawn,
    check_teleop,
    check_topic_list,
)

#: run(command, time limit s, stop after s or None): a command's outcome (stop_after: SIGINT then)
Run = Callable[[list[str], float, float | None], Outcome]

NAME, NAMESPACE, X, Y = "burger_1", "TB3_1", -2.0, -0.5
#: a TurtleBot3 model file as the spawner node sends it (only the model name counts to fleetsim)
SDF = '<sdf version="1.6"><model name="turtlebot3_burger"></model></sdf>'
HZ_SECONDS = 8.0
TELEOP_SECONDS = 3.0
BAG_SECONDS = 5.0


class SmokeError(RuntimeError):
    """The test cannot start (no ros2, another RMW, the daemon did not come up)."""


@dataclass(frozen=True)
class Setup:
    distro: str  # ROS_DISTRO
    domain: int
    router: str
    serve_router: bool  # no rmw_zenohd: simd is the router
    simd: list[str]  # how to start the daemon, up to its arguments


def run_command(command: list[str], timeout: float, stop_after: float | None = None) -> Outcome:
    """Run a command in a process group of its own; with ``stop_after``, interrupt it then
    (SIGINT, as Ctrl-C: ``hz`` and ``bag record`` end cleanly on it). Killed at ``timeout``."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)  # fmt: skip
    try:
        out, err = proc.communicate(timeout=stop_after if stop_after is not None else timeout)
        return Outcome(command, out, err, proc.returncode)
    except subprocess.TimeoutExpired:
        pass
    if stop_after is not None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=max(timeout - stop_after, 5.0))
            return Outcome(command, out, err, None)
        except subprocess.TimeoutExpired:
            pass
    os.killpg(proc.pid, signal.SIGKILL)
    out, err = proc.communicate()
    return Outcome(command, out, err, None, timed_out=True)


def _listening(endpoint: str) -> bool:
    """Whether something accepts TCP at ``tcp/HOST:PORT``."""
    host, _, port = endpoint.removeprefix("tcp/").rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=1.0):
            return True
    except (OSError, ValueError):
        return False


def setup(env: dict[str, str], router: str) -> Setup:
    """What the run needs from the environment, or :class:`SmokeError` with what to do."""
    if shutil.which("ros2") is None:
        raise SmokeError("ros2 is not on PATH: source /opt/ros/<distro>/setup.bash first")
    rmw = env.get("RMW_IMPLEMENTATION", "")
    if rmw != "rmw_zenoh_cpp":
        raise SmokeError(f"RMW_IMPLEMENTATION is {rmw!r}: export RMW_IMPLEMENTATION=rmw_zenoh_cpp (fleetsim speaks "
                         "rmw_zenoh's wire only)")  # fmt: skip
    distro = env.get("ROS_DISTRO", "")
    if not distro:
        raise SmokeError("ROS_DISTRO is not set: source /opt/ros/<distro>/setup.bash first")
    try:
        domain = int(env.get("ROS_DOMAIN_ID") or 0)
    except ValueError:
        raise SmokeError(f"ROS_DOMAIN_ID is {env['ROS_DOMAIN_ID']!r}, not a number") from None
    simd = [shutil.which("simd") or ""] if shutil.which("simd") else [sys.executable, "-m", "simd.cli"]
    return Setup(distro, domain, router, not _listening(router), simd)


def simd_args(s: Setup, fleet_endpoint: str) -> list[str]:
    distro = "humble" if s.distro == "humble" else "jazzy"  # Jazzy's keys from Jazzy on
    args = [*s.simd, "--ros2", "--ros-distro", distro, "--ros-domain-id", str(s.domain), "--ros-router", s.router,
            "-l", fleet_endpoint, "--world", "turtlebot3_world"]  # fmt: skip
    return [*args, "--ros-serve-router"] if s.serve_router else args


def commands(distro: str, bag_dir: str) -> dict[str, list[str]]:
    """Every ROS 2 command the test runs, by step."""
    odom = f"/{NAMESPACE}/odom"
    spawn = (f"{{name: {NAME}, xml: '{SDF}', robot_namespace: {NAMESPACE}, "
             f"initial_pose: {{position: {{x: {X}, y: {Y}, z: 0.01}}}}}}")  # fmt: skip
    if distro == "humble":  # Humble's teleop sends Twist, Jazzy's TurtleBot3 teleop TwistStamped
        twist = ["geometry_msgs/msg/Twist", "{linear: {x: 0.15}}"]
    else:
        twist = ["geometry_msgs/msg/TwistStamped", "{twist: {linear: {x: 0.15}}}"]
    times = str(int(TELEOP_SECONDS * 10))
    return {
        "spawn": ["ros2", "service", "call", "/spawn_entity", "gazebo_msgs/srv/SpawnEntity", spawn],
        "topics": ["ros2", "topic", "list", "-t"],
        "echo": ["ros2", "topic", "echo", "--once", odom],
        "hz": ["ros2", "topic", "hz", odom],
        "teleop": ["ros2", "topic", "pub", "-r", "10", "-t", times, f"/{NAMESPACE}/cmd_vel", *twist],
        "params": ["ros2", "param", "list"],
        "record": ["ros2", "bag", "record", "-o", bag_dir, odom, f"/{NAMESPACE}/scan", "/tf", "/tf_static", "/clock"],
        "info": ["ros2", "bag", "info", bag_dir],
    }


def checks(run: Run, distro: str, bag_dir: str, settle: float = 15.0) -> list[Verdict]:
    """Every step against a daemon that is up, in order; a step that depends on one that
    failed still runs (its own verdict says what it saw). ``topic list`` is asked again for up
    to ``settle`` seconds: the graph may take a moment to show a new robot's topics."""
    c = commands(distro, bag_dir)
    verdicts = [check_spawn(run(c["spawn"], 60.0, None))]
    deadline = time.monotonic() + settle
    while True:
        topics = check_topic_list(run(c["topics"], 30.0, None), NAMESPACE)
        if topics.status != FAIL or time.monotonic() > deadline:
            break
        time.sleep(1.0)
    verdicts.append(topics)
    before = run(c["echo"], 20.0, None)
    verdicts.append(check_echo(before, NAMESPACE))
    verdicts.append(check_hz(run(c["hz"], HZ_SECONDS + 10.0, HZ_SECONDS), NAMESPACE))
    publish = run(c["teleop"], TELEOP_SECONDS + 30.0, None)
    verdicts.append(check_teleop(publish, before, run(c["echo"], 20.0, None), NAMESPACE))
    verdicts.append(check_param_list(run(c["params"], 90.0, None)))
    record = run(c["record"], BAG_SECONDS + 15.0, BAG_SECONDS)
    verdicts.append(check_bag(record, run(c["info"], 30.0, None), NAMESPACE, BAG_SECONDS))
    return verdicts


def _version(run: Run, command: list[str]) -> str:
    out = run(command, 20.0, None)
    return out.stdout.strip().splitlines()[0] if out.stdout.strip() and out.returncode == 0 else "unknown"


def header(run: Run, s: Setup) -> list[str]:
    """Who ran what: to read a report without asking."""

    def dist(name: str) -> str:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return "not installed"

    rmw = _version(run, ["ros2", "pkg", "xml", "rmw_zenoh_cpp", "--tag", "version"])
    router = f"simd as the router on {s.router}" if s.serve_router else f"the router at {s.router}"
    return [
        f"**fleetsim ROS 2 smoke test** ({datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC)",
        "",
        f"- fleetsim {dist('fleetsim')}, eclipse-zenoh {dist('eclipse-zenoh')}, Python {platform.python_version()}, "
        f"{platform.platform()}",
        f"- ROS 2 {s.distro}, rmw_zenoh_cpp {rmw}, ROS_DOMAIN_ID {s.domain}, {router}",
    ]


class Daemon:
    """simd for the test: started, waited for, stopped (only the process it started)."""

    def __init__(self, args: list[str], log: Path) -> None:
        self.log = log
        with log.open("w") as f:
            self.proc = subprocess.Popen(args, stdout=f, stderr=subprocess.STDOUT, text=True,
                                         env={**os.environ, "PYTHONUNBUFFERED": "1"})  # fmt: skip

    def wait_ready(self, endpoint: str, timeout: float = 30.0) -> None:
        from clients.api import FleetClient
        from protocol.errors import FleetError

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise SmokeError(f"simd exited with {self.proc.returncode}:\n{self.log.read_text()[-2000:]}")
            try:
                with FleetClient(endpoint, timeout=1.0) as c:
                    c.clock()
                return
            except FleetError:
                time.sleep(0.2)
        raise SmokeError(f"simd did not answer within {timeout:g} s:\n{self.log.read_text()[-2000:]}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(10.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def smoke(s: Setup, run: Run = run_command) -> tuple[list[str], list[Verdict]]:
    """The whole test: the daemon up, every check, the daemon down. The header and verdicts."""
    with tempfile.TemporaryDirectory(prefix="fleet-ros-smoke-") as tmp:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        daemon = Daemon(simd_args(s, endpoint), Path(tmp) / "simd.log")
        try:
            daemon.wait_ready(endpoint)
            verdicts = checks(run, s.distro, str(Path(tmp) / "bag"))
        finally:
            daemon.stop()
        return header(run, s), verdicts
