"""``fleet-ros nav2``'s files: a parameter file per robot (nav2_params.py) and one launch file.

The launch file starts, in every robot's namespace, the nodes the parameter files configure
(nav2_params.NODES and a lifecycle manager that brings them up), with sim time and, for Nav2's
multi-robot layout, the ``/tf`` -> ``tf`` remapping nav2_bringup puts in every node. It uses
only ``launch_ros.actions.Node`` (the same from Humble to Rolling) and finds its parameter
files beside itself, so the directory can be moved. Run it with ``ros2 launch DIR/FILE``.

Nothing here runs ROS: the launch file is text, checked by the tests with a stand-in for
``launch`` and ``launch_ros`` that records what it builds.
"""

from __future__ import annotations

import os
import tempfile
import textwrap
from collections.abc import Sequence
from pathlib import Path

import yaml

from clients.ros.nav2_params import LIFECYCLE_MANAGER, NODES, Robot, params

LAUNCH_FILE = "fleetsim_nav2.launch.py"
#: the package and executable of each node
EXECUTABLES = {
    "controller_server": ("nav2_controller", "controller_server"),
    "planner_server": ("nav2_planner", "planner_server"),
    "behavior_server": ("nav2_behaviors", "behavior_server"),
    "bt_navigator": ("nav2_bt_navigator", "bt_navigator"),
    LIFECYCLE_MANAGER: ("nav2_lifecycle_manager", "lifecycle_manager"),
}


class FilesError(ValueError):
    """Files that cannot be written (already there without --force, no directory)."""


def params_file(namespace: str) -> str:
    return f"nav2_{namespace}.yaml"


def simd_command(namespaced_tf: bool) -> str:
    """The daemon these files fit: its own navigator off (Nav2's bt_navigator serves
    navigate_to_pose), the ground truth as localisation, the same TF layout."""
    tf = " --ros-tf namespaced" if namespaced_tf else ""
    return f"simd --ros2 --no-nav --ros-localization{tf}"


def params_text(robot: Robot, distro: str, namespaced_tf: bool) -> str:
    head = (
        f"# Nav2 for fleetsim's robot {robot.namespace} ({robot.model}, ROS 2 {distro}), written by fleet-ros nav2.\n"
        f"# For a daemon started as: {simd_command(namespaced_tf)}\n"
        "# Frames, topics, footprint and limits: docs/ros2.md, section Nav2.\n"
    )
    return head + yaml.safe_dump(params(robot, distro, namespaced_tf), sort_keys=False, width=120)


def launch_text(robots: Sequence[Robot], distro: str, namespaced_tf: bool) -> str:
    """The launch file (Python, as ``ros2 launch`` takes it)."""
    entries = "".join(f"    ({r.namespace!r}, {params_file(r.namespace)!r}),\n" for r in robots)
    executables = "".join(f"    {name!r}: {pkg_exe!r},\n" for name, pkg_exe in EXECUTABLES.items())
    remap = "[('/tf', 'tf'), ('/tf_static', 'tf_static')]" if namespaced_tf else "[]"
    layout = (
        "each robot's tree on /<ns>/tf, frames odom and base_footprint"
        if namespaced_tf
        else "the fleet's tree on /tf, frames <ns>/odom and <ns>/base_footprint"
    )
    names = ", ".join(r.namespace for r in robots)
    about = textwrap.fill(
        f"Then spawn the robots and run this file with ``ros2 launch <this file>``. In every robot's namespace it "
        f"starts {', '.join(NODES)} and {LIFECYCLE_MANAGER}, which brings them up, in sim time, each configured "
        "by the robot's file beside this one (nav2_<namespace>.yaml).",
        width=96,
    )
    return f'''"""Nav2 for fleetsim's robots {names} (ROS 2 {distro}), written by fleet-ros nav2.

Start the daemon first ({layout};
map -> odom and /map from the ground truth):

    {simd_command(namespaced_tf)}

{about}
"""

import os

from launch import LaunchDescription
from launch_ros.actions import Node

HERE = os.path.dirname(os.path.abspath(__file__))
#: each robot's namespace and its parameter file
ROBOTS = [
{entries}]
#: node name -> (package, executable); the lifecycle manager brings the others up (it waits for them)
EXECUTABLES = {{
{executables}}}
#: Nav2's multi-robot layout reads each robot's own /<ns>/tf (empty: the fleet's /tf)
REMAPPINGS = {remap}


def generate_launch_description():
    actions = []
    for namespace, params in ROBOTS:
        path = os.path.join(HERE, params)
        for name, (package, executable) in EXECUTABLES.items():
            actions.append(Node(package=package, executable=executable, name=name, namespace=namespace,
                                output='screen', parameters=[path, {{'use_sim_time': True}}],
                                remappings=REMAPPINGS))
    return LaunchDescription(actions)
'''


def files(robots: Sequence[Robot], distro: str, namespaced_tf: bool) -> dict[str, str]:
    """Every file by name: the launch file, then one parameter file per robot."""
    out = {LAUNCH_FILE: launch_text(robots, distro, namespaced_tf)}
    for r in robots:
        out[params_file(r.namespace)] = params_text(r, distro, namespaced_tf)
    return out


def write(directory: Path, contents: dict[str, str], force: bool) -> list[Path]:
    """Write the files into ``directory`` (made if missing, its parent must exist); refuse,
    writing nothing, when one exists and ``force`` is not given. Each file is written whole or
    not at all."""
    if directory.exists() and not directory.is_dir():
        raise FilesError(f"{directory} is not a directory")
    if not directory.exists() and not directory.parent.is_dir():
        raise FilesError(f"{directory.parent} is not a directory: create it first")
    paths = [directory / name for name in contents]
    if not force:
        taken = [p for p in paths if p.exists()]
        if taken:
            raise FilesError(f"{taken[0]} already exists: choose another -o, or --force to replace it")
    directory.mkdir(exist_ok=True)
    for path, text in zip(paths, contents.values(), strict=True):
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(text)
            os.chmod(tmp, 0o644)  # as any file the user writes (mkstemp makes it private)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    return paths
