"""The fleet protocol adapter: the engine as the key space of docs/protocol.md, over zenoh.

It is the only place where the daemon touches zenoh objects. Requests are decoded at the
edge (requests.py) and submitted to the engine with a reply that maps the engine's answer
(a core value) to the protocol's message; commands come from the cmd_vel intake
(commands.py); ticks, events and the clock go out through the publisher (publisher.py).
Output and replies leave in the engine's order, so a spawn's reply always follows the
robot's first odometry and a delete's reply its last.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import zenoh

from protocol.codec import encode
from protocol.control import Clock, Observation, Request, RobotList, StepReply
from protocol.errors import FleetError
from protocol.keys import Keys
from protocol.messages import Header, LaserScan, Time
from simd.adapters.fleet import requests
from simd.adapters.fleet.commands import CommandIntake
from simd.adapters.fleet.publisher import Publisher
from simd.core.snapshot import RobotState, TickSnapshot
from simd.core.worldfile import WorldGeometry
from simd.engine import Deleted, Engine, Event, Result, Spawned, StepResult
from simd.engine import RobotList as EngineRobotList
from simd.wire import convert

log = logging.getLogger(__name__)


class FleetAdapter:
    """Serves one engine on one zenoh session under one key prefix."""

    def __init__(self, session: zenoh.Session, keys: Keys, engine: Engine) -> None:
        self.keys = keys
        self.engine = engine
        spec = engine.sim.config.lidar
        self.spec = spec
        self._world_info = convert.world_info(engine.sim.world)
        self.publisher = Publisher(session, keys, spec)
        self.commands = CommandIntake(session, keys)
        self._queryables: list[Any] = requests.declare(session, keys, self._submit)
        engine.attach(self)

    # -- requests (zenoh threads) ---------------------------------------------------------------

    def _submit(self, request: Request, pending: requests.Pending) -> None:
        def reply(result: Result | FleetError) -> None:
            if isinstance(result, FleetError):
                pending.error(result)
            else:
                pending.ok(self._message(result))

        self.engine.submit(request, reply)

    def _message(self, result: Result) -> object:
        """The protocol's message for an engine answer."""
        if isinstance(result, RobotState):
            return convert.robot_record(result, self.keys)
        if isinstance(result, EngineRobotList):
            return RobotList(
                stamp=Time.from_seconds(result.time),
                robots=[convert.robot_record(s, self.keys) for s in result.robots],
            )
        if isinstance(result, WorldGeometry):
            return self._world_info
        if isinstance(result, StepResult):
            return self._step_reply(result)
        return result  # a Clock already is the message

    def _step_reply(self, result: StepResult) -> StepReply:
        spec = self.spec
        stamp = result.clock.clock
        observations: dict[str, Observation] = {}
        for key, s in result.states.items():
            odom = convert.odometry(
                s.namespace, stamp, s.x, s.y, s.yaw, s.linear_velocity, s.lateral_velocity, s.angular_velocity
            )
            row = result.scans.get(key)
            scan = None
            if row is not None:
                scan = LaserScan(
                    header=Header(stamp=Time.from_seconds(row.time), frame_id=f"{s.namespace}/base_scan"),
                    angle_min=spec.angle_min,
                    angle_max=spec.angle_max,
                    angle_increment=spec.angle_increment,
                    range_min=spec.range_min,
                    range_max=spec.range_max,
                    ranges=row.ranges.astype("<f4", copy=False).tobytes(),
                )
            observations[key] = Observation(odom=odom, scan=scan)
        fields = {f: getattr(result.clock, f) for f in result.clock.__struct_fields__}
        return StepReply(**fields, ticks_run=result.ticks_run, cancelled=result.cancelled, observations=observations)

    # -- the engine's side (simulation thread) ----------------------------------------------------

    def on_tick(self, snapshot: TickSnapshot) -> None:
        self.publisher.publish_tick(snapshot)

    def on_event(self, event: Event) -> None:
        if isinstance(event, Spawned):
            self.publisher.add_robot(event.robot, event.time)
        elif isinstance(event, Deleted):
            self.publisher.remove_robot(event.robot.namespace)

    def on_clock(self, clock: Clock) -> None:
        self.publisher.publish_clock(encode(clock))

    def take_commands(self) -> Mapping[str, tuple[float, float]]:
        return self.commands.take()

    def dropped_commands(self) -> int:
        return self.commands.dropped

    def close(self) -> None:
        for q in self._queryables:
            try:
                q.undeclare()
            except zenoh.ZError:
                pass
        self._queryables.clear()
        self.commands.close()
        self.publisher.close()
