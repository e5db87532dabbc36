"""The simulation loop: one thread owns the simulation, paces it, serves requests.

It wakes for whichever comes first, the next tick's deadline or a control request, so
spawns are answered within milliseconds while ticks stay on a fixed sim-time grid. In
lockstep mode time advances only through ``P/sim/step``.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math
import queue
import threading
import time

import numpy as np

from protocol.codec import decode, encode
from protocol.control import (
    Clock,
    DeleteRequest,
    ResetRequest,
    RobotList,
    SpawnRequest,
    StepRequest,
)
from protocol.errors import ErrorCode, FleetError
from protocol.keys import Keys
from protocol.messages import Time
from simd.adapters.fleet.bridge import Bridge, Request, reply_error, reply_ok
from simd.core.sim import Simulation, TickOutput
from simd.wire import convert
from simd.wire.fleet_codec import encode_fleet_odometry, encode_fleet_scans
from simd.wire.odom_codec import OdometryEncoder
from simd.wire.scan_codec import ScanEncoder

log = logging.getLogger(__name__)

#: Most ticks one step request may ask for (about 9 hours of sim time).
MAX_STEP_TICKS = 1_000_000
#: Ticks between clock messages: 10 Hz, as gazebo_ros publishes /clock.
CLOCK_EVERY = 3
#: If the loop falls this many ticks behind its schedule it stops trying to catch up.
MAX_LAG_TICKS = 5


def _without(out: TickOutput, gone: set[str]) -> TickOutput:
    """A tick's output without the robots in ``gone`` (deleted after it was computed)."""
    keep = np.asarray([ns not in gone for ns in out.namespaces], dtype=bool)
    keep_scan = np.asarray([ns not in gone for ns in out.scan_namespaces], dtype=bool)
    return dataclasses.replace(
        out,
        namespaces=[ns for ns in out.namespaces if ns not in gone],
        x=out.x[keep],
        y=out.y[keep],
        yaw=out.yaw[keep],
        linear_x=out.linear_x[keep],
        linear_y=out.linear_y[keep],
        angular_z=out.angular_z[keep],
        scan_namespaces=[ns for ns in out.scan_namespaces if ns not in gone],
        scans=out.scans[keep_scan],
    )


class Daemon:
    def __init__(
        self,
        sim: Simulation,
        bridge: Bridge,
        keys: Keys,
        *,
        rtf: float = 1.0,
        lockstep: bool = False,
        paused: bool = False,
    ) -> None:
        self.sim = sim
        self.bridge = bridge
        self.keys = keys
        self.rtf = rtf
        self.lockstep = lockstep
        self.paused = paused or lockstep
        self.stop_event = threading.Event()
        self._rtf_window: collections.deque[tuple[float, float]] = collections.deque(maxlen=64)
        self._world_info = convert.world_info(sim.world)
        self._odom = OdometryEncoder()
        self._scans = ScanEncoder(sim.config.lidar)
        self._deleted: set[str] = set()  # namespaces deleted while a tick is half done
        self._resets = 0
        self.fleet_messages = 0  # P/odometry and P/scans messages sent (built only when wanted)
        self._fleet_failed = False

    # -- status ---------------------------------------------------------------------------

    def measured_rtf(self) -> float:
        w = self._rtf_window
        if self.paused or len(w) < 2:
            return 0.0
        (w0, s0), (w1, s1) = w[0], w[-1]
        return (s1 - s0) / (w1 - w0) if w1 > w0 else 0.0

    def clock(self) -> Clock:
        return Clock(
            clock=Time.from_seconds(self.sim.time),
            tick=self.sim.tick,
            dt=self.sim.config.dt,
            paused=self.paused,
            lockstep=self.lockstep,
            real_time_factor=self.measured_rtf(),
            target_real_time_factor=self.rtf,
            robots=len(self.sim),
            dropped_commands=self.bridge.dropped_commands,
        )

    def stop(self) -> None:
        self.stop_event.set()
        try:
            self.bridge.requests.put_nowait(None)  # wake the loop
        except queue.Full:
            pass

    # -- the loop -------------------------------------------------------------------------

    def run(self) -> None:
        period = self.sim.config.dt / self.rtf if self.rtf > 0 else 0.0
        next_tick = time.monotonic()
        while not self.stop_event.is_set():
            now = time.monotonic()
            timeout = max(0.0, next_tick - now) if not self.paused else 0.25
            try:
                req = self.bridge.requests.get(timeout=timeout) if timeout > 0 else self.bridge.requests.get_nowait()
            except queue.Empty:
                req = None
            if req is not None:
                self._serve(req)
                continue
            if self.paused:
                self.bridge.poll_commands()  # keep the ring drained while time stands still
                next_tick = time.monotonic()
                continue
            if time.monotonic() >= next_tick:
                self.tick(serve_between=True)
                next_tick += period
                now = time.monotonic()
                if now - next_tick > MAX_LAG_TICKS * period:
                    next_tick = now  # fell behind: run slower than real time rather than burst

    def tick(self, serve_between: bool = False) -> TickOutput:
        """Apply commands, step once, publish the tick's messages.

        With ``serve_between`` the requests that arrived during the step (the long part of a
        tick) are served before publishing, so a spawn waits at most for that part and not for
        the whole tick. A robot deleted there is left out of this tick's messages; a reset
        there makes this tick's measurements stale, so they are not published.
        """
        sim = self.sim
        sim.command_many(self.bridge.take_commands())
        resets = self._resets
        out = sim.step()
        if serve_between and not self.bridge.requests.empty():
            deleted = self._serve_pending()
            # a reset, or steps, served meanwhile: this tick's measurements are stale (a reset
            # followed by as many steps would bring the tick count back, hence both checks)
            if sim.tick != out.tick or self._resets != resets:
                return out
            if deleted:
                out = _without(out, deleted)
        odom = self._odom.encode(
            out.namespaces, out.time, out.x, out.y, out.yaw, out.linear_x, out.linear_y, out.angular_z
        )
        scans = self._scans.encode(out.scan_namespaces, out.time, out.scans)
        self.bridge.publish(out.namespaces, odom, out.scan_namespaces, scans)
        self._publish_fleet_topics(out)
        self._rtf_window.append((time.monotonic(), out.time))
        if out.tick % CLOCK_EVERY == 0:
            self._publish_clock()
        return out

    def _publish_fleet_topics(self, out: TickOutput) -> None:
        """The tick as one message per topic, for whoever follows the whole fleet (if anyone).

        After the per-robot topics, and never fatal: these are a convenience on top of the
        contract, so a failure here is logged (once) and the simulation goes on.
        """
        bridge = self.bridge
        try:
            if out.namespaces and bridge.wants_fleet_odom():
                bridge.fleet_odom_pub.put(
                    encode_fleet_odometry(
                        out.namespaces, out.time, out.x, out.y, out.yaw, out.linear_x, out.linear_y, out.angular_z
                    )
                )
                self.fleet_messages += 1
            if out.scan_namespaces and bridge.wants_fleet_scan():
                bridge.fleet_scan_pub.put(
                    encode_fleet_scans(self.sim.config.lidar, out.scan_namespaces, out.time, out.scans)
                )
                self.fleet_messages += 1
        except Exception:
            if not self._fleet_failed:
                log.exception("the fleet topics failed (logged once; the robots' own topics go on)")
            self._fleet_failed = True

    def _serve_pending(self) -> set[str]:
        """Serve every queued request; return the namespaces deleted meanwhile."""
        self._deleted = set()
        while True:
            try:
                req = self.bridge.requests.get_nowait()
            except queue.Empty:
                break
            if req is None:  # stop() woke us
                self.stop_event.set()
                break
            self._serve(req)
        deleted, self._deleted = self._deleted, set()
        return deleted

    def _publish_clock(self) -> None:
        self.bridge.clock_pub.put(encode(self.clock()))

    # -- requests -------------------------------------------------------------------------

    def _serve(self, req: Request) -> None:
        self.bridge.poll_commands()  # so that the clock's dropped count is current
        key = self.bridge.control_keys[req.kind]
        try:
            result = getattr(self, f"_on_{req.kind}")(req)
            reply_ok(req, key, result)
        except FleetError as e:
            log.info("%s refused: %s", req.kind, e)
            reply_error(req, e)
        except Exception as e:  # a bug must not kill the daemon; the client gets told
            log.exception("%s failed", req.kind)
            reply_error(req, FleetError(ErrorCode.MALFORMED, f"internal error: {type(e).__name__}: {e}"))
        finally:
            req.query.drop()

    def _on_spawn(self, req: Request) -> object:
        spawn = decode(req.payload, SpawnRequest)
        robot = self.sim.spawn(spawn)
        self.bridge.add_robot(robot.namespace)
        state = self.sim.state(robot)
        # its first odometry now, so a robot is never silent, even while paused
        first = convert.odometry(
            robot.namespace,
            Time.from_seconds(self.sim.time),
            state.x,
            state.y,
            state.yaw,
            0.0,
            0.0,
            0.0,
        )
        data = encode(first)
        self.bridge.publish([robot.namespace], [data], [], [])
        log.info("spawned %s (%s) at (%.3f, %.3f, %.3f) ns=%s", robot.name, robot.model.name,
                 state.x, state.y, state.yaw, robot.namespace)  # fmt: skip
        return convert.robot_record(state, self.keys)

    def _on_delete(self, req: Request) -> object:
        d = decode(req.payload, DeleteRequest)
        last = self.sim.delete(d.name)
        self.bridge.remove_robot(last.namespace)
        self._odom.forget(last.namespace)
        self._scans.forget(last.namespace)
        self._deleted.add(last.namespace)
        log.info("deleted %s", last.name)
        return convert.robot_record(last, self.keys)

    def _on_robots(self, req: Request) -> object:
        return RobotList(
            stamp=Time.from_seconds(self.sim.time),
            robots=[convert.robot_record(s, self.keys) for s in self.sim.states()],
        )

    def _on_world(self, req: Request) -> object:
        return self._world_info

    def _on_clock(self, req: Request) -> object:
        return self.clock()

    def _on_pause(self, req: Request) -> object:
        self.paused = True
        self._rtf_window.clear()
        self._publish_clock()
        return self.clock()

    def _on_resume(self, req: Request) -> object:
        if self.lockstep:
            raise FleetError(
                ErrorCode.NOT_ALLOWED,
                "the daemon runs in lockstep: time advances only through sim/step",
            )
        self.paused = False
        self._rtf_window.clear()
        self._publish_clock()
        return self.clock()

    def _on_reset(self, req: Request) -> object:
        r = decode(req.payload, ResetRequest)
        self.sim.reset(r.seed)
        self._resets += 1
        self.bridge.take_commands()
        self._rtf_window.clear()
        self._publish_clock()
        return self.clock()

    def _on_step(self, req: Request) -> object:
        s = decode(req.payload, StepRequest)
        if not self.paused:
            raise FleetError(
                ErrorCode.NOT_ALLOWED,
                "step needs a paused simulation or --lockstep (pause it first with sim/pause)",
            )
        if not 1 <= s.ticks <= MAX_STEP_TICKS:
            raise FleetError(
                ErrorCode.INVALID_VALUE,
                f"ticks must be in 1..{MAX_STEP_TICKS}, got {s.ticks}",
                "ticks",
            )
        if s.cmd_vel:
            cmds = {}
            for ns, tw in s.cmd_vel.items():
                v, w = float(tw.linear.x), float(tw.angular.z)
                if not (math.isfinite(v) and math.isfinite(w)):
                    raise FleetError(ErrorCode.NON_FINITE, f"cmd_vel for {ns!r} is not finite", "cmd_vel")
                if self.sim.find(ns) is None:
                    raise FleetError(ErrorCode.NOT_FOUND, f"no robot with namespace {ns!r}", "cmd_vel")
                cmds[ns] = (v, w)
            self.sim.command_many(cmds)
        for _ in range(s.ticks):
            if self.stop_event.is_set():
                break
            self.tick()
        return self.clock()
