"""``fleet-record``: a fleet's topics into a rosbag2 bag (MCAP) that ROS 2 tools and Foxglove open.

    fleet-record                                  # every robot, until Ctrl-C
    fleet-record -o run1 --robots TB3_1,TB3_2 --duration 60
    fleet-record --topics odom,tf,tf_static,clock
    fleet-record --source ros --topics odom,scan,imu,tf,tf_static   # from simd --ros2's ROS topics

By default it follows the daemon's fleet topics (one message a tick for the whole fleet, so it
keeps up with large fleets) and writes what the ROS 2 adapter would have published:
``/<ns>/odom``, ``/<ns>/scan``, ``/tf``, ``/tf_static`` and ``/clock``, with no ROS on either side.
With ``--source ros`` it records the ROS topics themselves off rmw_zenoh's wire (a daemon
started with ``--ros2``, or any ROS 2 publisher of those topics), the bytes as they came
(clients/record/ros_source.py). A message's time in the bag is its sim-time stamp, as ``ros2 bag record
--use-sim-time`` records, so ``ros2 bag play --clock`` replays the run at its own pace. It shows
its progress while it records and what it wrote when it stops (after ``--duration`` seconds of
wall time, or Ctrl-C).
"""

from __future__ import annotations

import argparse
import os
import queue
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
import zenoh

from clients.api import FleetClient
from clients.fleet_args import add_daemon_args
from clients.follow import UpToStop, drain, follow, stop_on_signals
from clients.record import fleet_to_ros as conv
from clients.record import ros_source
from clients.record.bag import BagExists, BagWriter
from fleetcommon.zenoh_config import options_from_args
from protocol import FleetError
from protocol.errors import ErrorCode
from protocol.frames import static_transforms
from protocol.messages import FleetOdometry, FleetScans
from protocol.ros_domain import domain_id

ROBOT_TOPICS = ("odom", "scan")
FLEET_TOPICS = ("tf", "tf_static", "clock")
DEFAULT_TOPICS = (*ROBOT_TOPICS, *FLEET_TOPICS)
#: what --source ros can take besides: every robot topic the ROS adapter publishes
ROS_TOPICS = (*ros_source.ROBOT_TOPICS, *ros_source.FLEET_TOPICS)
EXIT_OK, EXIT_USAGE, EXIT_NO_DAEMON = 0, 2, 3


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet-record",
        description="Record a fleet's topics into a rosbag2 bag (MCAP) for ros2 bag play/info and Foxglove.",
    )
    p.add_argument("-o", "--output", metavar="DIR", help="the bag directory to create (default: fleet_<date-time>)")
    p.add_argument("--robots", metavar="NS,...", help="namespaces to record (default: every robot, also new ones)")
    p.add_argument(
        "--topics",
        metavar="T,...",
        default=",".join(DEFAULT_TOPICS),
        help=f"what to record, of {', '.join(DEFAULT_TOPICS)}, and with --source ros also imu, joint_states "
        f"(default: {','.join(DEFAULT_TOPICS)})",
    )
    p.add_argument(
        "--source",
        choices=("fleet", "ros"),
        default="fleet",
        help="fleet: the daemon's fleet topics, converted; ros: the ROS 2 topics of simd --ros2 off rmw_zenoh's "
        "wire (default: %(default)s)",
    )
    p.add_argument(
        "--ros-router",
        default="tcp/localhost:7447",
        metavar="ENDPOINT",
        help="with --source ros: the rmw_zenoh router (default: %(default)s)",
    )
    p.add_argument(
        "--ros-domain-id", type=int, default=None, metavar="N", help="with --source ros (default: $ROS_DOMAIN_ID or 0)"
    )
    p.add_argument(
        "--duration", type=float, default=0.0, metavar="S", help="stop after S seconds of wall time (default: Ctrl-C)"
    )
    add_daemon_args(p)
    return p


@dataclass
class Plan:
    """What to record, checked before anything is connected or created."""

    output: Path
    robots: set[str] | None
    topics: set[str]
    duration: float
    source: str = "fleet"
    domain: int = 0


def plan_from_args(args: argparse.Namespace, now: time.struct_time | None = None) -> Plan:
    """The recording asked for, or ValueError with a one-line reason."""
    topics = {t.strip().lstrip("/") for t in args.topics.split(",") if t.strip()}
    known = ROS_TOPICS if args.source == "ros" else DEFAULT_TOPICS
    unknown = topics - set(known)
    if unknown or not topics:
        more = " (imu and joint_states need --source ros)" if unknown & set(ROS_TOPICS) else ""
        raise ValueError(f"--topics takes {', '.join(known)}; not {', '.join(sorted(unknown)) or 'nothing'}{more}")
    domain = domain_id(args.ros_domain_id, os.environ) if args.source == "ros" else 0
    robots = None
    if args.robots is not None:
        robots = {r.strip().strip("/") for r in args.robots.split(",") if r.strip()}
        if not robots:
            raise ValueError("--robots needs at least one namespace")
    if not args.duration >= 0:
        raise ValueError(f"--duration must be >= 0, got {args.duration}")
    output = Path(args.output or time.strftime("fleet_%Y_%m_%d-%H_%M_%S", now or time.localtime()))
    if output.exists():
        raise ValueError(f"{output} already exists: choose another -o (nothing was written)")
    return Plan(output, robots, topics, args.duration, args.source, domain)


RosSample = tuple[str, str, int, bytes, bool]  # topic, type, stamp (ns), CDR, latched


@dataclass
class Recorder:
    """Turns the fleet topics into bag messages; runs on the main thread, fed by a queue."""

    plan: Plan
    bag: BagWriter
    client: FleetClient
    models: dict[str, str] = field(default_factory=dict)  # namespace -> model, of robots seen
    covariance: npt.NDArray[np.float64] | None = None
    inbox: queue.Queue[FleetOdometry | FleetScans | RosSample] = field(default_factory=queue.Queue)

    def wanted(self, namespaces: list[str]) -> list[int]:
        robots = self.plan.robots
        return [i for i, ns in enumerate(namespaces) if robots is None or ns in robots]

    def _meet(self, namespaces: list[str], rows: list[int], t_ns: int) -> None:
        """Robots seen for the first time: their model (for /tf_static) and the covariance."""
        new = [namespaces[i] for i in rows if namespaces[i] not in self.models]
        if not new:
            return
        by_ns = {r.namespace: r for r in self.client.robots()}
        if self.covariance is None:
            odom = self.client.latest_odom(new[0])
            if odom is not None:
                self.covariance = np.asarray(odom.pose.covariance, dtype=np.float64)
        for ns in new:
            record = by_ns.get(ns)
            self.models[ns] = record.model if record is not None else "burger"
            if "tf_static" in self.plan.topics:
                message = conv.static_tf(self.bag.make, static_transforms(ns, self.models[ns]))
                self.bag.write("/tf_static", "tf2_msgs/msg/TFMessage", t_ns, message, latched=True)

    def handle(self, msg: FleetOdometry | FleetScans | RosSample) -> None:
        if isinstance(msg, tuple):  # off the ROS wire: written as it came
            topic, typename, t_ns, data, latched = msg
            self.bag.write_cdr(topic, typename, t_ns, data, latched=latched)
            return
        t_ns = conv.stamp_ns(msg.stamp)
        rows = self.wanted(msg.namespaces)
        topics = self.plan.topics
        if isinstance(msg, FleetScans):
            if "scan" in topics and rows:
                for i, scan in zip(rows, conv.scans(self.bag.make, msg, rows), strict=True):
                    self.bag.write(f"/{msg.namespaces[i]}/scan", "sensor_msgs/msg/LaserScan", t_ns, scan)
            return
        self._meet(msg.namespaces, rows, t_ns)
        if "clock" in topics:
            self.bag.write("/clock", "rosgraph_msgs/msg/Clock", t_ns, conv.clock(self.bag.make, msg.stamp))
        if not rows:
            return
        if "tf" in topics:
            self.bag.write("/tf", "tf2_msgs/msg/TFMessage", t_ns, conv.tf(self.bag.make, msg, rows))
        if "odom" in topics:
            cov = self.covariance if self.covariance is not None else np.zeros(36)
            for i, odom in zip(rows, conv.odometry(self.bag.make, msg, rows, cov), strict=True):
                self.bag.write(f"/{msg.namespaces[i]}/odom", "nav_msgs/msg/Odometry", t_ns, odom)


def summary(bag: BagWriter, wall: float) -> str:
    """What ``ros2 bag info`` would say, in short."""
    size = bag.size_bytes()
    if bag.first_ns is None or bag.last_ns is None:
        span = "no messages (is the daemon paused, or are there no robots?)"
    else:
        t0, t1 = bag.first_ns / 1e9, bag.last_ns / 1e9
        span = f"sim time {t0:.3f} .. {t1:.3f} s ({t1 - t0:.3f} s)"
    lines = [
        f"fleet-record: wrote {bag.path} ({size / 1e6:.2f} MB, {sum(bag.counts.values())} messages) "
        f"in {wall:.1f} s of wall time; {span}"
    ]
    width = max((len(t) for t in bag.counts), default=5)
    for topic in sorted(bag.counts, key=_topic_order):
        lines.append(f"  {topic:<{width}}  {bag.counts[topic]:>8} messages")
    lines.append(f"  play it: ros2 bag play {bag.path} --clock     info: ros2 bag info {bag.path}")
    return "\n".join(lines)


def _topic_order(topic: str) -> tuple[int, str]:
    return (0 if topic.count("/") == 1 else 1, topic)


def progress_line(bag: BagWriter, elapsed: float, backlog: int) -> str:
    n = sum(bag.counts.values())
    robots = len({t.split("/")[1] for t in bag.counts if t.count("/") == 2})
    late = f", {backlog} waiting" if backlog > 100 else ""
    return f"recording {elapsed:6.1f} s: {n} messages, {robots} robots{late}"


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        plan = plan_from_args(args)
    except ValueError as e:
        print(f"fleet-record: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    stop = stop_on_signals()
    client: FleetClient | None = None
    source: ros_source.RosSource | None = None
    session: zenoh.Session | None = None
    try:
        if plan.source == "ros":
            session = ros_source.ros_session(args.ros_router, args.timeout)
        else:
            client = FleetClient(
                prefix=args.prefix, timeout=args.timeout, options=options_from_args(args, server=False)
            )
            tick_s = client.clock().dt  # fail now, with the usual message, if no daemon answers
    except FleetError as e:
        print(f"fleet-record: {e.message}", file=sys.stderr)
        return EXIT_NO_DAEMON if e.code in (ErrorCode.UNAVAILABLE, ErrorCode.TIMEOUT) else EXIT_USAGE
    except zenoh.ZError as e:
        print(f"fleet-record: cannot reach the ROS router at {args.ros_router}: {e} (is rmw_zenohd running?)",
              file=sys.stderr)  # fmt: skip
        return EXIT_NO_DAEMON
    try:
        bag = BagWriter(plan.output)
    except (BagExists, OSError) as e:
        if client is not None:
            client.close()
        if session is not None:
            session.close()
        print(f"fleet-record: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    rec = Recorder(plan, bag, client)  # type: ignore[arg-type]  # None with --source ros, which never asks it
    up_to_stop = None
    if client is not None:
        fleet = client
        up_to_stop = UpToStop(lambda: fleet.clock().clock, scans="scan" in plan.topics, tick_s=tick_s,
                              hurry=stop.hurry)  # fmt: skip
        client.on_fleet_odom(rec.inbox.put)
        if "scan" in plan.topics:
            client.on_fleet_scans(rec.inbox.put)
    if session is not None:
        wanted = ros_source.topic_filter(plan.topics, plan.robots)
        source = ros_source.RosSource(session, plan.domain, wanted, lambda *sample: rec.inbox.put(sample))
    print(f"fleet-record: recording {', '.join(sorted(plan.topics))} ({plan.source} source) of "
          f"{'every robot' if plan.robots is None else ', '.join(sorted(plan.robots))} into {plan.output} "
          "(Ctrl-C stops)", file=sys.stderr, flush=True)  # fmt: skip
    try:
        wall = follow(rec.inbox, rec.handle, stop, plan.duration, lambda t: progress_line(bag, t, rec.inbox.qsize()),
                      None, up_to_stop)  # fmt: skip
    finally:  # no more input; what arrived is written
        if client is not None:
            client.close()
        if source is not None:
            source.close()
        if session is not None:
            session.close()
        drain(rec.inbox, rec.handle, up_to_stop)
        bag.close()
    print(summary(bag, wall), flush=True)
    for line in up_to_stop.report("fleet-record", rec.inbox.qsize()) if up_to_stop is not None else []:
        print(line, file=sys.stderr, flush=True)
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
