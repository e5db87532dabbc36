"""Nav2's parameters for one fleetsim robot: its topics, frames, footprint and limits, in sim time.

What differs from nav2_bringup's ``nav2_params.yaml`` and why:

- **Nodes.** Only what ``navigate_to_pose`` needs with the ground truth as localisation (``simd
  --ros-localization``): controller_server, planner_server, behavior_server, bt_navigator and
  their lifecycle manager. No AMCL or map_server (the daemon publishes ``map`` -> ``odom`` and
  ``/map``), no smoother or collision monitor (the default behaviour trees do not use them), no
  docking or route server (Kilted's bringup starts them, and each needs a configuration of its
  own or fails to configure, which stops the whole bringup).
- **Names.** Every file's root key is the robot's namespace (``TB3_1: controller_server: ...``,
  what nav2_bringup's ``RewrittenYaml(root_key=namespace)`` makes), so one file per robot
  matches only that robot's nodes. Topics are absolute (``/TB3_1/scan``, ``/map``): a relative
  observation source resolves against the costmap's own namespace on some distros.
- **Frames.** The layout of ``simd --ros-tf``: ``namespaced`` (Nav2's, ``odom`` and
  ``base_footprint`` on ``/TB3_1/tf``) or ``global`` (``TB3_1/odom`` on the fleet's ``/tf``).
  The map frame is ``map`` either way.
- **The robot.** Footprint: the rectangle around the chassis and wheels that fleetsim simulates
  (its outline's bounding box; the TurtleBot3 Nav2 files give circles of 0.1 m and 0.22 m, the
  first smaller than the burger). Speeds: the model's top speed (0.22 m/s burger, 0.26 waffle,
  as fleetsim clamps them) and the TurtleBot3 DWB's 1.0 rad/s; acceleration: fleetsim's wheel
  limit of 1 m/s² (the TurtleBot3 DWB's 2.5 m/s² would plan starts the robot cannot make).
- **Distros.** Humble names plugins ``pkg/Class`` and has a few parameters of its own
  (``progress_checker_plugin``, the behavior server's ``costmap_topic``); Jazzy and Kilted
  ``pkg::Class``. Parameters a distro does not know are ignored by its nodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

DISTROS = ("humble", "jazzy", "kilted")
MODELS = ("burger", "waffle", "waffle_pi")


@dataclass(frozen=True)
class ModelLimits:
    """What Nav2 must know of a TurtleBot3 model as fleetsim simulates it (simd/core/models.py)."""

    #: x_min, x_max, y_min, y_max of chassis and wheels about base_footprint (m)
    box: tuple[float, float, float, float]
    max_linear: float  # m/s
    max_angular: float  # rad/s, the robot's; Nav2 is given the TurtleBot3 DWB's 1.0
    wheel_acceleration: float  # m/s² at the rim


LIMITS: dict[str, ModelLimits] = {
    "burger": ModelLimits((-0.102, 0.038, -0.089, 0.089), 0.22, 2.84, 1.0),
    "waffle": ModelLimits((-0.1965, 0.0685, -0.153, 0.153), 0.26, 1.82, 1.0),
    "waffle_pi": ModelLimits((-0.1965, 0.0685, -0.153, 0.153), 0.26, 1.82, 1.0),
}
#: the TurtleBot3 Nav2 files' turn rate and inflation (turtlebot3_navigation2/param)
MAX_THETA = 1.0
LOCAL_INFLATION_M, GLOBAL_INFLATION_M = 1.0, 0.55
#: the nodes started per robot, in the order the lifecycle manager brings them up
NODES = ("controller_server", "planner_server", "behavior_server", "bt_navigator")
LIFECYCLE_MANAGER = "lifecycle_manager_navigation"
MAP_FRAME = "map"
MAP_TOPIC = "/map"


@dataclass(frozen=True)
class Robot:
    namespace: str
    model: str


def footprint(model: str) -> str:
    """The footprint polygon as Nav2 reads it, a string: ``[[x, y], ...]`` counter-clockwise."""
    x0, x1, y0, y1 = LIMITS[model].box
    return f"[[{x1}, {y1}], [{x0}, {y1}], [{x0}, {y0}], [{x1}, {y0}]]"


def _plugin(package: str, name: str, distro: str) -> str:
    return f"{package}/{name}" if distro == "humble" else f"{package}::{name}"


class Frames:
    """The robot's frame names in one layout of ``simd --ros-tf``."""

    def __init__(self, namespace: str, namespaced_tf: bool) -> None:
        prefix = "" if namespaced_tf else f"{namespace}/"
        self.odom = f"{prefix}odom"
        self.base = f"{prefix}base_footprint"
        self.map = MAP_FRAME


def params(robot: Robot, distro: str, namespaced_tf: bool) -> dict[str, Any]:
    """The whole parameter file of one robot: ``{namespace: {node: {ros__parameters: ...}}}``."""
    if distro not in DISTROS:
        raise ValueError(f"unknown distro {distro!r}: one of {', '.join(DISTROS)}")
    limits = LIMITS[robot.model]
    f = Frames(robot.namespace, namespaced_tf)
    ns = f"/{robot.namespace}"
    scan, odom = f"{ns}/scan", f"{ns}/odom"
    common = {"use_sim_time": True}
    scan_source = {
        "topic": scan, "data_type": "LaserScan", "clearing": True, "marking": True, "max_obstacle_height": 2.0,
        "raytrace_max_range": 3.5, "raytrace_min_range": 0.0, "obstacle_max_range": 3.0, "obstacle_min_range": 0.0,
    }  # fmt: skip

    def costmap(global_frame: str, rolling: bool, inflation: float) -> dict[str, Any]:
        layers = ["obstacle_layer", "inflation_layer"] if rolling else ["static_layer", "obstacle_layer",
                                                                        "inflation_layer"]  # fmt: skip
        c: dict[str, Any] = {
            **common, "global_frame": global_frame, "robot_base_frame": f.base, "update_frequency": 5.0,
            "publish_frequency": 2.0, "resolution": 0.05, "footprint": footprint(robot.model),
            "footprint_padding": 0.01, "map_topic": MAP_TOPIC, "plugins": layers,
            "obstacle_layer": {"plugin": "nav2_costmap_2d::ObstacleLayer", "enabled": True,
                               "observation_sources": "scan", "scan": scan_source},
            "inflation_layer": {"plugin": "nav2_costmap_2d::InflationLayer", "cost_scaling_factor": 3.0,
                                "inflation_radius": inflation},
            "always_send_full_costmap": True,
        }  # fmt: skip
        if rolling:
            c.update(rolling_window=True, width=3, height=3)
        else:
            c.update(track_unknown_space=True, update_frequency=1.0, publish_frequency=1.0)
            c["static_layer"] = {"plugin": "nav2_costmap_2d::StaticLayer", "map_topic": MAP_TOPIC,
                                 "map_subscribe_transient_local": True}  # fmt: skip
        return {"ros__parameters": c}

    accel = limits.wheel_acceleration
    dwb = {
        "plugin": "dwb_core::DWBLocalPlanner", "min_vel_x": 0.0, "min_vel_y": 0.0, "max_vel_x": limits.max_linear,
        "max_vel_y": 0.0, "max_vel_theta": MAX_THETA, "min_speed_xy": 0.0, "max_speed_xy": limits.max_linear,
        "min_speed_theta": 0.0, "acc_lim_x": accel, "acc_lim_y": 0.0, "acc_lim_theta": 3.2, "decel_lim_x": -accel,
        "decel_lim_y": 0.0, "decel_lim_theta": -3.2, "vx_samples": 20, "vy_samples": 5, "vtheta_samples": 20,
        "sim_time": 1.7, "linear_granularity": 0.05, "angular_granularity": 0.025, "transform_tolerance": 0.2,
        "xy_goal_tolerance": 0.25, "trans_stopped_velocity": 0.25, "short_circuit_trajectory_evaluation": True,
        "stateful": True,
        "critics": ["RotateToGoal", "Oscillation", "BaseObstacle", "GoalAlign", "PathAlign", "PathDist", "GoalDist"],
        "BaseObstacle.scale": 0.02, "PathAlign.scale": 32.0, "PathAlign.forward_point_distance": 0.1,
        "GoalAlign.scale": 24.0, "GoalAlign.forward_point_distance": 0.1, "PathDist.scale": 32.0,
        "GoalDist.scale": 24.0, "RotateToGoal.scale": 32.0, "RotateToGoal.slowing_factor": 5.0,
        "RotateToGoal.lookahead_time": -1.0,
    }  # fmt: skip
    controller: dict[str, Any] = {
        **common, "controller_frequency": 20.0, "odom_topic": odom, "min_x_velocity_threshold": 0.001,
        "min_y_velocity_threshold": 0.5, "min_theta_velocity_threshold": 0.001, "failure_tolerance": 0.3,
        "goal_checker_plugins": ["general_goal_checker"], "controller_plugins": ["FollowPath"],
        "progress_checker": {"plugin": "nav2_controller::SimpleProgressChecker", "required_movement_radius": 0.5,
                             "movement_time_allowance": 10.0},
        "general_goal_checker": {"plugin": "nav2_controller::SimpleGoalChecker", "stateful": True,
                                 "xy_goal_tolerance": 0.25, "yaw_goal_tolerance": 0.25},
        "FollowPath": dwb,
    }  # fmt: skip
    if distro == "humble":
        controller["progress_checker_plugin"] = "progress_checker"
    else:
        controller["progress_checker_plugins"] = ["progress_checker"]
    behaviors = ("spin", "Spin"), ("backup", "BackUp"), ("drive_on_heading", "DriveOnHeading"), ("wait", "Wait")
    behavior: dict[str, Any] = {
        **common, "cycle_frequency": 10.0, "behavior_plugins": [b for b, _ in behaviors],
        **{b: {"plugin": _plugin("nav2_behaviors", cls, distro)} for b, cls in behaviors},
        "robot_base_frame": f.base, "transform_tolerance": 0.1, "simulate_ahead_time": 2.0,
        "max_rotational_vel": MAX_THETA, "min_rotational_vel": 0.4, "rotational_acc_lim": 3.2,
    }  # fmt: skip
    if distro == "humble":
        behavior.update(costmap_topic="local_costmap/costmap_raw", footprint_topic="local_costmap/published_footprint",
                        global_frame=f.odom)  # fmt: skip
    else:
        behavior.update(
            local_costmap_topic="local_costmap/costmap_raw", global_costmap_topic="global_costmap/costmap_raw",
            local_footprint_topic="local_costmap/published_footprint",
            global_footprint_topic="global_costmap/published_footprint", local_frame=f.odom, global_frame=f.map,
        )  # fmt: skip
    navigator: dict[str, Any] = {
        **common, "global_frame": f.map, "robot_base_frame": f.base, "odom_topic": odom, "bt_loop_duration": 10,
        "default_server_timeout": 20, "wait_for_service_timeout": 1000,
    }  # fmt: skip
    if distro != "humble":
        navigator.update(
            navigators=["navigate_to_pose", "navigate_through_poses"],
            navigate_to_pose={"plugin": "nav2_bt_navigator::NavigateToPoseNavigator"},
            navigate_through_poses={"plugin": "nav2_bt_navigator::NavigateThroughPosesNavigator"},
            error_code_names=["compute_path_error_code", "follow_path_error_code"],
        )
    planner = {
        **common, "expected_planner_frequency": 20.0, "planner_plugins": ["GridBased"],
        "GridBased": {"plugin": _plugin("nav2_navfn_planner", "NavfnPlanner", distro), "tolerance": 0.5,
                      "use_astar": False, "allow_unknown": True},
    }  # fmt: skip
    manager = {**common, "autostart": True, "node_names": list(NODES), "bond_timeout": 4.0}
    return {
        robot.namespace: {
            "bt_navigator": {"ros__parameters": navigator},
            "controller_server": {"ros__parameters": controller},
            "local_costmap": {"local_costmap": costmap(f.odom, True, LOCAL_INFLATION_M)},
            "global_costmap": {"global_costmap": costmap(f.map, False, GLOBAL_INFLATION_M)},
            "planner_server": {"ros__parameters": planner},
            "behavior_server": {"ros__parameters": behavior},
            LIFECYCLE_MANAGER: {"ros__parameters": manager},
        }
    }
