"""The ``fleet`` / ``fleet-spawn`` command lines, run as real processes against a real daemon."""

from __future__ import annotations

import math
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import pytest

from clients.fleet import cli
from clients.fleet.output import Outcome
from clients.fleetfile import FleetFileError, load_fleet
from protocol import RobotRecord
from tests.conftest import ROOT, Daemon, free_port

BIN = Path(sys.executable).parent


def run(argv: list[str], env: dict[str, str] | None = None, timeout: float = 20.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        argv,
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
        # a Gazebo user's TURTLEBOT3_MODEL would change the default model: only tests set it
        env={**{k: v for k, v in os.environ.items() if k != "TURTLEBOT3_MODEL"}, **(env or {})},
    )


def fleet(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return run([sys.executable, "-m", "clients.fleet.cli", *args], env)


def fleet_spawn(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    script = BIN / "fleet-spawn"
    if script.exists():
        return run([str(script), *args], env)
    code = "import sys; from clients.fleet.cli import spawn_main; sys.exit(spawn_main())"
    return run([sys.executable, "-c", code, *args], env)


def test_the_teleop_hint_is_the_bare_name_when_it_is_on_path(daemon: Daemon) -> None:
    path = f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"
    p = fleet("spawn", "tb3_0", "-2", "-0.5", "-e", daemon.endpoint, env={"PATH": path})
    assert p.returncode == 0, p.stderr
    assert f"drive it: fleet-teleop tb3_0 -e {daemon.endpoint}" in p.stdout


def lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


# --- spawn, list, delete ------------------------------------------------------------------------


def test_spawn_both_forms_and_the_teleop_hint(daemon: Daemon) -> None:
    ep = daemon.endpoint
    p = fleet("spawn", "tb3_0", "-2", "-0.5", "-e", ep)
    assert p.returncode == 0, p.stderr
    assert "spawned tb3_0 (burger) in namespace tb3_0 at x -2.000 m, y -0.500 m" in p.stdout
    assert "fleet/tb3_0/cmd_vel" in p.stdout and "fleet/tb3_0/odom" in p.stdout
    hint = next(line for line in p.stdout.splitlines() if "drive it:" in line).split("drive it: ")[1]
    program, *rest = shlex.split(hint)
    assert rest == ["tb3_0", "-e", ep]
    # it runs as printed, from where fleet ran (here the venv is not on PATH: its path is given)
    assert run([program, "--help"]).returncode == 0 if "/" in program else shutil.which(program)

    # the seed's spawn_turtlebot NAME NS X Y Z (Z ignored)
    p = fleet("spawn", "burger_1", "TB3_1", "0.5", "-2", "0.01", "-e", ep)
    assert p.returncode == 0, p.stderr
    assert "fleet-teleop TB3_1" in p.stdout

    # spawn_entity.py's flags, through the fleet-spawn script
    p = fleet_spawn(
        "-entity",
        "waffle_1",
        "-robot_namespace",
        "W1",
        "-x",
        "2",
        "-y",
        "0.5",
        "-Y",
        "1.5",
        "--model",
        "waffle",
        "-e",
        ep,
    )
    assert p.returncode == 0, p.stderr

    # Gazebo users have TURTLEBOT3_MODEL set
    p = fleet("spawn", "pi_1", "-0.5", "2", "--json", "-e", ep, env={"TURTLEBOT3_MODEL": "waffle_pi"})
    assert p.returncode == 0, p.stderr
    rec = msgspec.json.decode(p.stdout, type=RobotRecord)
    assert (rec.name, rec.namespace, rec.model) == ("pi_1", "pi_1", "waffle_pi")
    assert rec.topics is not None and rec.topics.odom == "fleet/pi_1/odom"

    c = daemon.client()
    by_ns = {r.namespace: r for r in c.robots()}
    assert set(by_ns) == {"tb3_0", "TB3_1", "W1", "pi_1"}
    assert (by_ns["TB3_1"].name, by_ns["TB3_1"].pose.x, by_ns["TB3_1"].pose.y) == (
        "burger_1",
        0.5,
        -2.0,
    )
    w1 = by_ns["W1"]
    assert (w1.name, w1.model) == ("waffle_1", "waffle")
    assert math.isclose(w1.spawn_pose.yaw, 1.5) and (w1.spawn_pose.x, w1.spawn_pose.y) == (2.0, 0.5)


def test_list_table_json_and_delete(daemon: Daemon) -> None:
    ep = daemon.endpoint
    c = daemon.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("burger_2", 0.5, -2.0, 0.25, namespace="TB3_2")

    p = fleet("list", "-e", ep)
    assert p.returncode == 0, p.stderr
    rows = lines(p.stdout)
    assert rows[0].split() == ["NAME", "NAMESPACE", "MODEL", "X", "Y", "YAW", "V", "W"]
    table = {row.split()[0]: row.split() for row in rows[1:3]}
    assert table["burger_2"][:6] == ["burger_2", "TB3_2", "burger", "0.500", "-2.000", "0.250"]
    assert table["tb3_0"][:5] == ["tb3_0", "tb3_0", "burger", "-2.000", "-0.500"]

    p = fleet("list", "--json", "-e", ep)
    assert p.returncode == 0, p.stderr
    records = msgspec.json.decode(p.stdout, type=list[RobotRecord])
    assert sorted(r.namespace for r in records) == ["TB3_2", "tb3_0"]

    p = fleet("list", "TB3_2", "-e", ep)  # only the robots named
    assert p.returncode == 0, p.stderr
    assert [row.split()[0] for row in lines(p.stdout)[1:-1]] == ["burger_2"]
    p = fleet("list", "tb3_0", "nope", "no pe", "-e", ep)  # the ones there, a line for each other
    assert p.returncode == 1
    assert [row.split()[0] for row in lines(p.stdout)[1:-1]] == ["tb3_0"]
    assert lines(p.stderr)[0] == "fleet: nope: not_found: Entity [nope] does not exist"  # as delete says it
    assert lines(p.stderr)[1].startswith("fleet: no pe: invalid_name: ") and len(lines(p.stderr)) == 2

    p = fleet("delete", "tb3_0", "TB3_2", "-e", ep)
    assert p.returncode == 0, p.stderr
    assert "deleted tb3_0" in p.stdout and "deleted burger_2 (namespace TB3_2" in p.stdout
    assert c.robots() == []

    p = fleet("delete", "nope", "-e", ep)
    assert p.returncode == 1
    assert lines(p.stderr) == ["fleet: nope: not_found: Entity [nope] does not exist"]

    p = fleet("list", "-e", ep)
    assert p.returncode == 0 and "no robots" in p.stdout


def test_fleet_file_spawns_the_multi_robot_launch(daemon: Daemon) -> None:
    ep = daemon.endpoint
    expected = {
        "TB3_1": (-2.0, -0.5),
        "TB3_2": (0.5, -2.0),
        "TB3_3": (2.0, 0.5),
        "TB3_4": (-0.5, 2.0),
    }
    p = fleet("spawn", "--file", "tb3_multi", "--json", "-e", ep)
    assert p.returncode == 0, p.stderr
    outcomes = msgspec.json.decode(p.stdout, type=list[Outcome])
    assert [o.name for o in outcomes] == ["burger_1", "burger_2", "burger_3", "burger_4"]
    assert all(o.ok and o.robot is not None for o in outcomes)

    c = daemon.client()
    assert c.alive() == sorted(expected)
    # spawned in parallel, answered in any order: the list is in name order, every time
    for _ in range(3):
        p = fleet("list", "-e", ep)
        assert [row.split()[0] for row in lines(p.stdout)[1:5]] == ["burger_1", "burger_2", "burger_3", "burger_4"]
    for ns, (x, y) in expected.items():
        pos = c.wait_odom(ns).pose.pose.position  # each answers on its own namespace
        assert (round(pos.x, 3), round(pos.y, 3)) == (x, y), ns

    # the same file again: every entry refused, each reason reported, exit 1
    p = fleet("spawn", "--file", "tb3_multi", "-e", ep)
    assert p.returncode == 1
    refusals = lines(p.stderr)
    assert len(refusals) == 4
    assert all(r.startswith("fleet: burger_") and "already_exists" in r for r in refusals)


def test_fleet_file_by_path_with_a_partial_refusal(daemon: Daemon, tmp_path: Path) -> None:
    f = tmp_path / "two.yaml"
    f.write_text("- {name: a1, x: -2.0, y: -0.5}\n- {name: a2, model: waffle, x: 0.0, y: 0.0}\n")
    p = fleet("spawn", "--file", str(f), "-e", daemon.endpoint)
    assert p.returncode == 1
    assert "spawned a1 (burger)" in p.stdout
    assert lines(p.stderr) == ["fleet: a2: collision: a waffle at (0, 0, yaw 0) would overlap a wall or obstacle"]
    assert daemon.client().alive() == ["a1"]


REFUSALS = [
    (["spawn", "tb3_0", "2", "0.5"], "already_exists"),  # duplicate name
    (["spawn", "other", "tb3_0", "2", "0.5"], "already_exists"),  # duplicate namespace
    (["spawn", "bad-name", "2", "0.5"], "invalid_name"),
    (["spawn", "cmd_vel", "2", "0.5"], "reserved_name"),
    (["spawn", "walled", "0", "0"], "collision"),  # the pillar at the origin
    (["spawn", "far", "100", "0"], "out_of_bounds"),
    (["spawn", "m1", "2", "0.5", "--model", "burgerr"], "unknown_model"),
]


def test_refusals_exit_1_with_the_daemons_reason(daemon: Daemon) -> None:
    c = daemon.client()
    c.spawn("tb3_0", -2.0, -0.5)
    for args, code in REFUSALS:  # one daemon for all: each case is one short process
        p = fleet(*args, "-e", daemon.endpoint)
        assert p.returncode == 1, (args, p.stdout + p.stderr)
        assert p.stdout == ""
        (line,) = lines(p.stderr)
        assert line.startswith(f"fleet: {code}: "), (args, line)
    assert c.alive() == ["tb3_0"]  # the world untouched


def test_unknown_model_from_the_environment_says_so(daemon: Daemon) -> None:
    p = fleet("spawn", "m1", "2", "0.5", "-e", daemon.endpoint, env={"TURTLEBOT3_MODEL": "wafle"})
    assert p.returncode == 1
    assert "unknown model 'wafle'" in p.stderr and "$TURTLEBOT3_MODEL" in p.stderr


# --- usage errors and no daemon -------------------------------------------------------------------


def test_usage_errors_exit_2_as_processes() -> None:
    p = fleet("spawn", "tb3_0", "1")  # half a position
    assert p.returncode == 2
    assert "fleet spawn: error: after NAME [NS] expected X Y [Z]" in p.stderr
    p = fleet_spawn("--x", "one")
    assert p.returncode == 2 and "invalid float value: 'one'" in p.stderr
    p = fleet("frobnicate")
    assert p.returncode == 2 and "invalid choice" in p.stderr


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "COMMAND"),
        (["spawn"], "a robot NAME is required"),
        (["spawn", "a", "b", "c"], "got 'c'"),
        (["spawn", "a", "1", "2", "--x", "3"], "position given twice"),
        (["spawn", "a", "NS", "--namespace", "N2"], "namespace given twice"),
        (["spawn", "--file", "tb3_multi", "extra"], "--file cannot be combined"),
        (["spawn", "--file", "tb3_mult"], "did you mean 'tb3_multi'?"),
        (["spawn", "--file", "missing.yaml"], "missing.yaml: file not found"),
        (["list", "--timeout", "0"], "--timeout must be a positive"),
        (["list", "--prefix", "a b"], "prefix 'a b'"),
        (["list", "--cfg", "novalue"], "--cfg expects KEY:VALUE"),
        (["step", "0"], "N must be at least 1"),
    ],
)
def test_usage_errors_exit_2(argv: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    code: int | str | None
    try:
        code = cli.main(argv)  # no command at all: help on stderr and 2
    except SystemExit as e:  # argparse's error()
        code = e.code
    assert code == 2
    assert message in capsys.readouterr().err


def test_fleet_file_errors_name_the_file_and_location(tmp_path: Path) -> None:
    f = tmp_path / "bad.yaml"
    f.write_text("- {name: a1, x: 1.0}\n- name: a2\n  yaw: 0.5\n  z: 0.01\n")
    with pytest.raises(FleetFileError, match=r"bad\.yaml: \$\[1\] \(line 2\): Object contains unknown field `z`"):
        load_fleet(str(f))
    f.write_text("- {name: a1, x: one}\n")
    with pytest.raises(FleetFileError, match=r"\$\[0\]\.x \(line 1\): Expected `float`, got `str`"):
        load_fleet(str(f))
    f.write_text("- {name: a1}\n- {name: a2, namespace: a1}\n")
    with pytest.raises(
        FleetFileError,
        match=r"\$\[1\]\.namespace \(line 2\): 'a1' is already used by entry \$\[0\]",
    ):
        load_fleet(str(f))
    f.write_text("robots: []\n")
    with pytest.raises(FleetFileError, match="a fleet file is a YAML list of robots"):
        load_fleet(str(f))
    p = fleet("spawn", "--file", str(f))
    assert p.returncode == 2 and str(f) in p.stderr


def test_shipped_fleet_reproduces_the_seed_launch() -> None:
    robots = load_fleet("tb3_multi")
    assert [(r.name, r.namespace, r.model, r.x, r.y, r.yaw) for r in robots] == [
        (f"burger_{n}", f"TB3_{n}", "burger", x, y, 0.0)
        for n, (x, y) in enumerate([(-2.0, -0.5), (0.5, -2.0), (2.0, 0.5), (-0.5, 2.0)], start=1)
    ]


def test_no_daemon_exits_3_promptly_with_one_line() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    for argv in (
        [sys.executable, "-m", "clients.fleet.cli", "list", "-e", endpoint, "--timeout", "1"],
        [sys.executable, "-m", "clients.fleet.cli", "spawn", "tb3_0", "-e", endpoint, "--timeout", "1"],
    ):
        start = time.monotonic()
        p = run(argv)
        elapsed = time.monotonic() - start
        assert p.returncode == 3, p.stderr
        assert lines(p.stderr) == [
            f"fleet: no fleetsim daemon answered at {endpoint} within 1 s (start one with: simd)"
        ]
        assert p.stdout == ""
        assert elapsed < 1 + 3.0, elapsed  # the timeout plus interpreter start, never a hang
