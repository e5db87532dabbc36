"""``fleet-ros``: the Nav2 files it writes, and the smoke test's logic on recorded outputs.

No ROS here. The parameter files are read back as YAML and checked against what fleetsim
publishes (frames, topics) and simulates (footprints, speeds: simd's own models); the launch
file runs against a stand-in of ``launch`` and ``launch_ros`` that records the nodes it is
asked to start. The smoke test runs against outputs written by hand from the ROS 2 tools'
documented formats (tests/clients/data/ros_smoke/README.md), through a fake command runner.
"""

from __future__ import annotations

import sys
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from clients.ros import cli, nav2_files, nav2_params, smoke, smoke_checks
from clients.ros.nav2_params import Robot
from clients.ros.smoke_checks import FAIL, PASS, Outcome
from simd.core.models import MODELS

DATA = Path(__file__).parent / "data" / "ros_smoke"


def recorded(name: str) -> str:
    """A recorded output, without its first line (the note that it was written by hand)."""
    text = (DATA / name).read_text()
    assert text.startswith("# hand-written"), name
    return text.split("\n", 1)[1]


# -- fleet-ros nav2: the parameter files -----------------------------------------------------------


@pytest.mark.parametrize("model", list(MODELS))
def test_footprints_and_speeds_are_the_simulated_models(model: str) -> None:
    """The client's table (it may not import simd) against simd's models."""
    m = MODELS[model]
    limits = nav2_params.LIMITS[model]
    outline = m.outline
    assert limits.box == pytest.approx((outline[:, 0].min(), outline[:, 0].max(), outline[:, 1].min(),
                                        outline[:, 1].max()))  # fmt: skip
    assert (limits.max_linear, limits.max_angular) == (m.max_linear_velocity, m.max_angular_velocity)
    assert limits.wheel_acceleration == m.max_wheel_acceleration
    polygon = np.array(yaml.safe_load(nav2_params.footprint(model)))
    assert polygon.shape == (4, 2)
    x = polygon[:, 0]
    y = polygon[:, 1]
    assert 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) == pytest.approx(
        (limits.box[1] - limits.box[0]) * (limits.box[3] - limits.box[2])
    )


def _params(namespaced: bool, distro: str = "jazzy", model: str = "burger") -> dict[str, Any]:
    text = nav2_files.params_text(Robot("TB3_1", model), distro, namespaced)
    data: dict[str, Any] = yaml.safe_load(text)
    assert list(data) == ["TB3_1"]  # one root: the robot's namespace, so only its nodes match
    nodes: dict[str, Any] = data["TB3_1"]
    return nodes


def _all_values(tree: Any, key: str) -> list[Any]:
    if isinstance(tree, dict):
        return [v for k, v in tree.items() if k == key] + [x for v in tree.values() for x in _all_values(v, key)]
    if isinstance(tree, list):
        return [x for v in tree for x in _all_values(v, key)]
    return []


@pytest.mark.parametrize(("namespaced", "odom", "base"), [(True, "odom", "base_footprint"),
                                                          (False, "TB3_1/odom", "TB3_1/base_footprint")])  # fmt: skip
def test_frames_and_topics_are_what_the_daemon_publishes(namespaced: bool, odom: str, base: str) -> None:
    nodes = _params(namespaced)
    local = nodes["local_costmap"]["local_costmap"]["ros__parameters"]
    glob = nodes["global_costmap"]["global_costmap"]["ros__parameters"]
    assert (local["global_frame"], glob["global_frame"]) == (odom, "map")
    assert set(_all_values(nodes, "robot_base_frame")) == {base}
    assert set(_all_values(nodes, "topic")) == {"/TB3_1/scan"}  # absolute: no namespace guessing
    assert set(_all_values(nodes, "odom_topic")) == {"/TB3_1/odom"}
    assert glob["static_layer"]["map_topic"] == "/map" and glob["static_layer"]["map_subscribe_transient_local"]
    assert "static_layer" not in local["plugins"]
    # every node in sim time, and the lifecycle manager brings up exactly the nodes the launch file starts
    for name in nav2_params.NODES:
        assert nodes[name]["ros__parameters"]["use_sim_time"] is True
    manager = nodes[nav2_params.LIFECYCLE_MANAGER]["ros__parameters"]
    assert manager["node_names"] == list(nav2_params.NODES) and manager["autostart"] is True
    assert set(nav2_files.EXECUTABLES) == {*nav2_params.NODES, nav2_params.LIFECYCLE_MANAGER}


def test_the_footprint_and_limits_of_the_model() -> None:
    nodes = _params(True, model="waffle")
    local = nodes["local_costmap"]["local_costmap"]["ros__parameters"]
    assert local["footprint"] == nav2_params.footprint("waffle")
    dwb = nodes["controller_server"]["ros__parameters"]["FollowPath"]
    assert (dwb["max_vel_x"], dwb["acc_lim_x"], dwb["decel_lim_x"]) == (0.26, 1.0, -1.0)


@pytest.mark.parametrize("distro", nav2_params.DISTROS)
def test_plugin_names_follow_the_distro(distro: str) -> None:
    nodes = _params(True, distro)
    sep = "/" if distro == "humble" else "::"
    assert nodes["planner_server"]["ros__parameters"]["GridBased"]["plugin"] == f"nav2_navfn_planner{sep}NavfnPlanner"
    behavior = nodes["behavior_server"]["ros__parameters"]
    assert behavior["spin"]["plugin"] == f"nav2_behaviors{sep}Spin"
    controller = nodes["controller_server"]["ros__parameters"]
    key = "progress_checker_plugin" if distro == "humble" else "progress_checker_plugins"
    assert key in controller
    assert ("navigators" in nodes["bt_navigator"]["ros__parameters"]) == (distro != "humble")
    with pytest.raises(ValueError, match="unknown distro"):
        nav2_params.params(Robot("a", "burger"), "iron", True)


# -- fleet-ros nav2: the launch file ---------------------------------------------------------------


class _Recorded:
    def __init__(self, **kwargs: Any) -> None:
        self.kwargs = kwargs


def run_launch_file(path: Path, monkeypatch: pytest.MonkeyPatch) -> list[dict[str, Any]]:
    """Run the generated launch file's generate_launch_description() against stand-ins of
    ``launch`` and ``launch_ros``: the nodes it would start, as keyword arguments."""
    launch = types.ModuleType("launch")
    launch_ros = types.ModuleType("launch_ros")
    actions = types.ModuleType("launch_ros.actions")
    launch.LaunchDescription = lambda entities: list(entities)  # type: ignore[attr-defined]
    actions.Node = _Recorded  # type: ignore[attr-defined]
    launch_ros.actions = actions  # type: ignore[attr-defined]
    for name, module in (("launch", launch), ("launch_ros", launch_ros), ("launch_ros.actions", actions)):
        monkeypatch.setitem(sys.modules, name, module)
    namespace: dict[str, Any] = {"__file__": str(path), "__name__": "fleetsim_launch"}
    exec(compile(path.read_text(), str(path), "exec"), namespace)
    return [node.kwargs for node in namespace["generate_launch_description"]()]


@pytest.mark.parametrize("namespaced", [True, False])
def test_the_launch_file_starts_each_robots_nodes_with_its_own_parameters(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, namespaced: bool
) -> None:
    robots = [Robot("TB3_1", "burger"), Robot("TB3_2", "waffle")]
    nav2_files.write(tmp_path / "nav2", nav2_files.files(robots, "jazzy", namespaced), force=False)
    nodes = run_launch_file(tmp_path / "nav2" / nav2_files.LAUNCH_FILE, monkeypatch)
    assert len(nodes) == 2 * len(nav2_files.EXECUTABLES)
    for node in nodes:
        ns = node["namespace"]
        params_path, sim_time = node["parameters"]
        assert Path(params_path) == tmp_path / "nav2" / f"nav2_{ns}.yaml" and Path(params_path).is_file()
        assert sim_time == {"use_sim_time": True}
        assert node["name"] in yaml.safe_load(Path(params_path).read_text())[ns]  # its parameters are there
        assert nav2_files.EXECUTABLES[node["name"]] == (node["package"], node["executable"])
        assert node["remappings"] == ([("/tf", "tf"), ("/tf_static", "tf_static")] if namespaced else [])
    assert {n["namespace"] for n in nodes} == {"TB3_1", "TB3_2"}


# -- fleet-ros nav2: the command line --------------------------------------------------------------


def test_nav2_command_writes_the_files_and_says_how_to_run_them(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    monkeypatch.delenv("ROS_DISTRO", raising=False)
    monkeypatch.delenv("TURTLEBOT3_MODEL", raising=False)
    out = tmp_path / "nav2"
    assert cli.main(["nav2", "--file", "tb3_multi", "-o", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [nav2_files.LAUNCH_FILE] + [f"nav2_TB3_{i}.yaml" for i in range(1, 5)]
    )
    said = capsys.readouterr().out
    assert "simd --ros2 --no-nav --ros-localization --ros-tf namespaced" in said
    assert f"ros2 launch {out / nav2_files.LAUNCH_FILE}" in said
    assert "ROS 2 jazzy" in said
    # never over a user's files without --force; with it, replaced
    (out / "nav2_TB3_1.yaml").write_text("mine")
    assert cli.main(["nav2", "TB3_1", "-o", str(out)]) == 2
    assert (out / "nav2_TB3_1.yaml").read_text() == "mine"
    assert "already exists" in capsys.readouterr().err
    again = ["nav2", "TB3_1:waffle", "-o", str(out), "--force", "--ros-tf", "global", "--distro", "humble"]
    assert cli.main(again) == 0
    params = yaml.safe_load((out / "nav2_TB3_1.yaml").read_text())["TB3_1"]
    assert params["local_costmap"]["local_costmap"]["ros__parameters"]["global_frame"] == "TB3_1/odom"
    assert params["planner_server"]["ros__parameters"]["GridBased"]["plugin"] == "nav2_navfn_planner/NavfnPlanner"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "name the robots"),
        (["TB3_1:pr2"], "unknown model 'pr2'"),
        (["TB3-1"], "robot 'TB3-1'"),
        (["TB3_1", "TB3_1:waffle"], "given twice"),
        (["--file", "no_such_fleet"], "no_such_fleet"),
        (["TB3_1", "-o", "/no/such/dir/nav2"], "is not a directory"),
    ],
)
def test_nav2_usage_errors_are_one_line_and_exit_2(args: list[str], message: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    assert cli.main(["nav2", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("fleet-ros nav2: error:") and message in err


# -- fleet-ros smoke: the checks on recorded outputs -----------------------------------------------


def _out(name: str, command: str = "ros2", returncode: int | None = 0) -> Outcome:
    return Outcome(command.split(), recorded(name), "", returncode)


def test_spawn_call() -> None:
    ok = smoke_checks.check_spawn(_out("spawn_ok.txt"))
    assert (ok.status, ok.detail) == (PASS, "SpawnEntity: Successfully spawned entity [burger_1]")
    exists = smoke_checks.check_spawn(_out("spawn_exists.txt"))
    assert (exists.status, exists.detail) == (FAIL, "Entity [burger_1] already exists.")
    bad = smoke_checks.check_spawn(_out("spawn_bad_type.txt", returncode=1))
    assert bad.status == FAIL and "The passed service type is invalid" in bad.detail
    hung = smoke_checks.check_spawn(Outcome(["ros2"], "waiting for service to become available...\n", "", None, True))
    assert hung.status == FAIL and "time limit" in hung.detail


def test_topic_list() -> None:
    topics = smoke_checks.topic_types(recorded("topic_list_jazzy.txt"))
    assert topics["/TB3_1/cmd_vel"] == ["geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"]
    assert smoke_checks.check_topic_list(_out("topic_list_jazzy.txt"), "TB3_1").status == PASS
    missing = smoke_checks.check_topic_list(_out("topic_list_no_robot.txt"), "TB3_1")
    assert missing.status == FAIL and "/TB3_1/odom missing" in missing.detail and "/tf_static missing" in missing.detail


def test_echo_hz_and_teleop() -> None:
    before, after = _out("echo_odom_before.txt"), _out("echo_odom_after.txt")
    echo = smoke_checks.check_echo(before, "TB3_1")
    assert (echo.status, echo.detail) == (PASS, "frames TB3_1/odom -> TB3_1/base_footprint, x -2.000")
    assert smoke_checks.check_echo(before, "TB3_2").status == FAIL  # another robot's frames
    assert smoke_checks.check_echo(Outcome(["ros2"], "", "", 0), "TB3_1").status == FAIL
    hz = smoke_checks.check_hz(_out("hz.txt", returncode=None), "TB3_1")
    assert hz.status == PASS and hz.detail.startswith("29.998 Hz")
    assert smoke_checks.check_hz(_out("hz.txt"), "TB3_1", expected_hz=10.0).status == FAIL
    teleop = smoke_checks.check_teleop(Outcome(["ros2"]), before, after, "TB3_1")
    assert (teleop.status, teleop.detail) == (PASS, "x -2.000 -> -1.571 (+0.429 m)")
    still = smoke_checks.check_teleop(Outcome(["ros2"]), before, before, "TB3_1")
    assert still.status == FAIL and "+0.000 m" in still.detail


def test_param_list_passes_when_the_daemons_nodes_list_use_sim_time() -> None:
    jazzy = smoke_checks.check_param_list(_out("param_list_jazzy.txt"))
    assert jazzy.status == PASS and jazzy.detail == "use_sim_time on /TB3_1/turtlebot3, /fleetsim"
    timeout = smoke_checks.check_param_list(_out("param_list_timeout.txt"))
    assert timeout.status == FAIL and timeout.detail == "timed out on /TB3_1/turtlebot3, /fleetsim"
    humble = smoke_checks.check_param_list(_out("param_list_humble.txt"))
    assert humble.status == FAIL and humble.detail == "no fleetsim node listed"
    other = smoke_checks.check_param_list(Outcome(["ros2"], "/fleetsim:\n  qos_overrides\n", "", 0))
    assert other.status == FAIL and other.detail == "no use_sim_time on /fleetsim"
    assert smoke_checks.check_param_list(Outcome(["ros2"], "", "", None, True)).status == FAIL


def test_bag_record_and_info() -> None:
    record = Outcome(["ros2", "bag", "record"], "", "", None)  # stopped by SIGINT after 5 s, as meant
    ok = smoke_checks.check_bag(record, _out("bag_info_jazzy.txt"), "TB3_1", 5.0)
    assert ok.status == PASS and "/TB3_1/odom 150" in ok.detail
    empty = smoke_checks.check_bag(record, _out("bag_info_empty.txt"), "TB3_1", 5.0)
    assert empty.status == FAIL and "/TB3_1/scan 0" in empty.detail


# -- fleet-ros smoke: the whole run through a fake runner ------------------------------------------


class FakeRos:
    """The ROS 2 commands' recorded outputs, by command; the odometry moves after the teleop."""

    def __init__(self, **overrides: Outcome) -> None:
        self.ran: list[list[str]] = []
        self.moved = False
        self.overrides = overrides

    def __call__(self, command: list[str], timeout: float, stop_after: float | None) -> Outcome:
        self.ran.append(command)
        verb = " ".join(command[1:3])
        if verb in self.overrides:
            return self.overrides[verb]
        if verb == "topic pub":
            self.moved = True
            return Outcome(command, "publisher: beginning loop\n", "", 0)
        files = {"service call": "spawn_ok.txt", "topic list": "topic_list_jazzy.txt", "topic hz": "hz.txt",
                 "param list": "param_list_jazzy.txt", "bag info": "bag_info_jazzy.txt"}  # fmt: skip
        if verb == "topic echo":
            return Outcome(command, recorded("echo_odom_after.txt" if self.moved else "echo_odom_before.txt"))
        if verb == "bag record":
            assert stop_after == smoke.BAG_SECONDS
            return Outcome(command, "", "[INFO] [rosbag2_recorder]: Recording...\n", None)
        if verb == "pkg xml":
            return Outcome(command, "0.2.9\n")
        return Outcome(command, recorded(files[verb]), "", None if verb == "topic hz" else 0)


def test_the_checks_in_order_and_the_report() -> None:
    ros = FakeRos()
    verdicts = smoke.checks(ros, "jazzy", "/tmp/bag")
    assert [v.status for v in verdicts] == [PASS] * 7
    verbs = [" ".join(c[1:3]) for c in ros.ran]
    assert verbs == ["service call", "topic list", "topic echo", "topic hz", "topic pub", "topic echo",
                     "param list", "bag record", "bag info"]  # fmt: skip
    pub = ros.ran[4]
    assert pub[-2:] == ["geometry_msgs/msg/TwistStamped", "{twist: {linear: {x: 0.15}}}"]
    assert smoke.commands("humble", "/b")["teleop"][-2] == "geometry_msgs/msg/Twist"
    s = smoke.Setup("jazzy", 3, "tcp/localhost:7447", True, ["simd"])
    report = smoke_checks.table(verdicts, smoke.header(ros, s))
    assert "rmw_zenoh_cpp 0.2.9" in report and "ROS_DOMAIN_ID 3" in report and "simd as the router" in report
    assert "| 6 | ros2 param list | PASS | use_sim_time on /TB3_1/turtlebot3, /fleetsim |" in report
    assert report.rstrip().endswith("7 of 7 passed, 0 failed.")
    assert smoke.simd_args(s, "tcp/127.0.0.1:9")[-1] == "--ros-serve-router"


def test_a_failure_puts_its_commands_output_in_the_report() -> None:
    ros = FakeRos(**{"topic list": _out("topic_list_no_robot.txt", "ros2 topic list -t")})
    verdicts = smoke.checks(ros, "jazzy", "/tmp/bag", settle=0.0)
    assert verdicts[1].status == FAIL
    report = smoke_checks.table(verdicts, ["head"])
    assert "1 failed" in report
    assert "<details><summary>ros2 topic list -t: output</summary>" in report
    assert "$ ros2 topic list -t\n/clock [rosgraph_msgs/msg/Clock]" in report


def test_smoke_refuses_to_start_without_ros(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
                                            tmp_path: Path) -> None:  # fmt: skip
    monkeypatch.setattr("clients.ros.smoke.shutil.which", lambda name: None)
    assert cli.main(["smoke"]) == 2
    assert "ros2 is not on PATH" in capsys.readouterr().err
    monkeypatch.setattr("clients.ros.smoke.shutil.which", lambda name: f"/opt/ros/bin/{name}")
    with pytest.raises(smoke.SmokeError, match="RMW_IMPLEMENTATION is 'rmw_fastrtps_cpp'"):
        smoke.setup({"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp", "ROS_DISTRO": "jazzy"}, "tcp/localhost:7447")
    s = smoke.setup({"RMW_IMPLEMENTATION": "rmw_zenoh_cpp", "ROS_DISTRO": "humble", "ROS_DOMAIN_ID": "7"},
                    "tcp/127.0.0.1:1")  # fmt: skip
    assert (s.distro, s.domain, s.serve_router) == ("humble", 7, True)  # nothing listens on port 1
    taken = tmp_path / "report.md"
    taken.write_text("mine")
    assert cli.main(["smoke", "-o", str(taken)]) == 2
    assert taken.read_text() == "mine"
