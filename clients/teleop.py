"""``fleet-teleop NS``: drive one robot from the keyboard, as TurtleBot3's ``teleop_keyboard``.

Same keys and numbers as ``turtlebot3_teleop``: ``w``/``x`` change the linear target by
±0.01 m/s, ``a``/``d`` the angular target by +0.1/−0.1 rad/s, ``s`` or space stop at once
(target and output to zero, no ramp); the arrow keys do the same as w/x/a/d. The output ramps
toward the target by at most 0.005 m/s and 0.05 rad/s per loop iteration, the loop runs at
10 Hz and publishes ``cmd_vel`` on every iteration, so the daemon's 0.5 s watchdog never stops
a robot that is being driven. Targets clamp to the limits in the robot's record (no
``TURTLEBOT3_MODEL`` needed). ``q``, Esc or Ctrl-C quit, after one zero command.

The logic lives in :class:`TeleopState` (pure, no I/O); :class:`Teleop` connects it to a
daemon and to a small prompt_toolkit application that also shows odometry, the nearest
obstacle of the latest scan and whether the robot and the daemon are there.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import signal
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from prompt_toolkit.application import Application
from prompt_toolkit.formatted_text import StyleAndTextTuples
from prompt_toolkit.input import Input
from prompt_toolkit.key_binding import KeyBindings, KeyPressEvent
from prompt_toolkit.layout import Layout, Window
from prompt_toolkit.layout.controls import FormattedTextControl
from prompt_toolkit.output import Output
from prompt_toolkit.styles import Style

from clients.api import FleetClient
from protocol.control import RobotRecord
from protocol.errors import ErrorCode, FleetError
from protocol.keys import DEFAULT_PREFIX, Keys
from protocol.messages import LaserScan, Odometry
from protocol.zenoh_config import ZenohOptions, add_zenoh_args, options_from_args

#: turtlebot3_teleop's steps and smoothing (half a step per loop iteration).
LIN_VEL_STEP = 0.01
ANG_VEL_STEP = 0.1
LIN_RAMP = LIN_VEL_STEP / 2
ANG_RAMP = ANG_VEL_STEP / 2
RATE_HZ = 10.0

#: A status poll of the daemon (clock query) every this many seconds.
POLL_PERIOD = 0.5
#: Odometry older than this is shown as stale (the daemon publishes at 30 Hz while running).
ODOM_STALE_S = 1.0

EXIT_OK = 0
EXIT_UNKNOWN_ROBOT = 1
EXIT_USAGE = 2
EXIT_NO_DAEMON = 3


# --- the pure logic ---------------------------------------------------------------------------


def _clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


def _toward(output: float, target: float, slop: float) -> float:
    """turtlebot3_teleop's ``make_simple_profile``: move by at most ``slop``."""
    if target > output:
        return min(target, output + slop)
    if target < output:
        return max(target, output - slop)
    return target


class TeleopState:
    """Targets, ramped output and clamps; one :meth:`tick` per loop iteration.

    Values are rounded to 1e-9 after each change, so 22 presses of ``w`` are exactly 0.22
    rather than 0.22000000000000006.
    """

    def __init__(self, max_linear: float, max_angular: float) -> None:
        self.max_linear = max_linear
        self.max_angular = max_angular
        self.target_linear = 0.0
        self.target_angular = 0.0
        self.linear = 0.0
        self.angular = 0.0

    def set_limits(self, max_linear: float, max_angular: float) -> None:
        self.max_linear, self.max_angular = max_linear, max_angular
        self.target_linear = _clamp(self.target_linear, max_linear)
        self.target_angular = _clamp(self.target_angular, max_angular)
        self.linear = _clamp(self.linear, max_linear)
        self.angular = _clamp(self.angular, max_angular)

    def change_linear(self, delta: float) -> None:
        self.target_linear = round(_clamp(self.target_linear + delta, self.max_linear), 9)

    def change_angular(self, delta: float) -> None:
        self.target_angular = round(_clamp(self.target_angular + delta, self.max_angular), 9)

    def stop(self) -> None:
        """Force stop: target and output to zero at once, no ramp."""
        self.target_linear = self.target_angular = 0.0
        self.linear = self.angular = 0.0

    def press(self, key: str) -> bool:
        """Apply a key (``w x a d s`` or space, or ``up down left right``); False if ignored."""
        match key:
            case "w" | "up":
                self.change_linear(+LIN_VEL_STEP)
            case "x" | "down":
                self.change_linear(-LIN_VEL_STEP)
            case "a" | "left":
                self.change_angular(+ANG_VEL_STEP)
            case "d" | "right":
                self.change_angular(-ANG_VEL_STEP)
            case "s" | " " | "space":
                self.stop()
            case _:
                return False
        return True

    def tick(self) -> tuple[float, float]:
        """Ramp the output one step toward the target; returns the command to publish."""
        self.linear = round(_toward(self.linear, self.target_linear, LIN_RAMP), 9)
        self.angular = round(_toward(self.angular, self.target_angular, ANG_RAMP), 9)
        return self.linear, self.angular


def nearest_obstacle(scan: LaserScan) -> tuple[float, float] | None:
    """(distance m, bearing rad) of the closest return, bearing 0 ahead and positive left.

    The distance is measured from the lidar (``base_scan``), as the scan is. None when
    nothing is within range.
    """
    ranges = scan.ranges_array()
    valid = np.isfinite(ranges) & (ranges >= scan.range_min)
    if not valid.any():
        return None
    i = int(np.argmin(np.where(valid, ranges, np.inf)))
    bearing = scan.angle_min + i * scan.angle_increment
    bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
    return float(ranges[i]), bearing


def describe_bearing(bearing: float) -> str:
    deg = math.degrees(bearing)
    if abs(deg) <= 10:
        side = "ahead"
    elif abs(deg) >= 170:
        side = "behind"
    else:
        side = "left" if deg > 0 else "right"
    return f"{deg:+.0f}° ({side})"


# --- the live session -------------------------------------------------------------------------


class StartupError(Exception):
    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


@dataclass
class Seen:
    """What the zenoh callbacks and the monitor last saw (written by them, read by the UI)."""

    odom: Odometry | None = None
    odom_at: float = 0.0
    nearest: tuple[float, float] | None = None
    scan_at: float = 0.0
    robot_alive: bool = True
    daemon_up: bool = True
    paused: bool = False
    #: A fresh record after the robot came back (new limits); the loop applies it.
    new_record: RobotRecord | None = None


class Teleop:
    """One robot driven from the keyboard over one client session."""

    def __init__(self, client: FleetClient, record: RobotRecord) -> None:
        self.client = client
        self.record = record
        self.namespace = record.namespace
        limits = record.limits
        if limits is None:
            raise StartupError(EXIT_UNKNOWN_ROBOT, f"the record of {record.name!r} has no limits")
        self.state = TeleopState(limits.max_linear_velocity, limits.max_angular_velocity)
        self.seen = Seen()
        self.published = 0
        self._stop = threading.Event()
        self._refresh_record = threading.Event()
        self._monitor: threading.Thread | None = None
        self.app: Application[int] | None = None

    # -- connection ------------------------------------------------------------------------

    @classmethod
    def connect(cls, args: argparse.Namespace) -> Teleop:
        """Open a session and find the robot; raise StartupError with the exit code."""
        try:
            Keys(args.prefix)
            opts = options_from_args(args, server=False)
            opts.build()
        except ValueError as e:
            raise StartupError(EXIT_USAGE, f"fleet-teleop: error: {e}") from None
        return cls.open(args.namespace, opts, prefix=args.prefix, timeout=args.timeout)

    @classmethod
    def open(cls, key: str, options: ZenohOptions, *, prefix: str = DEFAULT_PREFIX, timeout: float = 3.0) -> Teleop:
        no_daemon = (
            f"fleet-teleop: no fleetsim daemon answered at {options.endpoints()} "
            f"within {timeout:g} s (start one with: simd)"
        )
        try:
            client = FleetClient(options=options, prefix=prefix, timeout=timeout)
        except FleetError:
            raise StartupError(EXIT_NO_DAEMON, no_daemon) from None
        try:
            robots = client.robots()
            record = next((r for r in robots if key in (r.namespace, r.name)), None)
            if record is None:
                live = ", ".join(f"{r.namespace} ({r.name})" for r in robots) or "none"
                raise StartupError(
                    EXIT_UNKNOWN_ROBOT,
                    f"fleet-teleop: no robot with namespace or name {key!r}; live robots: {live}. "
                    f"Spawn one with: fleet spawn {key}",
                )
            tele = cls(client, record)
            tele._start()
            return tele
        except FleetError as e:
            client.close()
            if e.code in (ErrorCode.UNAVAILABLE, ErrorCode.TIMEOUT):
                raise StartupError(EXIT_NO_DAEMON, no_daemon) from None
            raise StartupError(EXIT_UNKNOWN_ROBOT, f"fleet-teleop: {e}") from None
        except BaseException:
            client.close()
            raise

    def _start(self) -> None:
        ns = self.namespace
        self.client.on_odom(ns, self._on_odom)
        self.client.on_scan(ns, self._on_scan)
        self.client.on_presence(self._on_presence)
        self._monitor = threading.Thread(target=self._watch_daemon, name="teleop-monitor", daemon=True)
        self._monitor.start()

    def close(self) -> None:
        """One zero command, then end the session (zenoh callbacks need it to exit)."""
        self._stop.set()
        try:
            self.state.stop()
            self.client.stop(self.namespace)
        finally:
            if self._monitor is not None:
                self._monitor.join(timeout=2.0)
            self.client.close()

    # -- zenoh callbacks and the monitor thread (no UI or state access) ---------------------

    def _on_odom(self, ns: str, msg: Odometry) -> None:
        self.seen.odom = msg
        self.seen.odom_at = time.monotonic()

    def _on_scan(self, ns: str, msg: LaserScan) -> None:
        self.seen.nearest = nearest_obstacle(msg)
        self.seen.scan_at = time.monotonic()

    def _on_presence(self, ns: str, alive: bool) -> None:
        if ns != self.namespace:
            return
        was = self.seen.robot_alive
        self.seen.robot_alive = alive
        if alive and not was:
            self._refresh_record.set()
        self._invalidate()

    def _watch_daemon(self) -> None:
        """Poll the clock: 'no daemon' when nothing answers, paused state; refetch the
        robot's record after it came back (its model, hence its limits, may differ)."""
        while not self._stop.wait(POLL_PERIOD):
            try:
                clock = self.client.clock()
                self.seen.daemon_up = True
                self.seen.paused = clock.paused
                if self._refresh_record.is_set():
                    rec = self.client.robot(self.namespace)
                    if rec is not None:
                        self.seen.new_record = rec
                        self._refresh_record.clear()
            except FleetError:
                if self.seen.daemon_up:
                    self._refresh_record.set()
                self.seen.daemon_up = False
            self._invalidate()

    def _invalidate(self) -> None:
        if self.app is not None and self.app.is_running:
            self.app.invalidate()

    # -- the loop (event-loop thread: the only writer of self.state) ------------------------

    @property
    def connected(self) -> bool:
        return self.seen.robot_alive and self.seen.daemon_up

    def press(self, key: str) -> None:
        if not self.connected and key not in ("s", " ", "space"):
            return  # nothing to drive; targets stay at zero until the robot is back
        if self.state.press(key) and key in ("s", " ", "space"):
            self._publish()  # stop now rather than at the next tick

    def tick(self) -> None:
        rec = self.seen.new_record
        if rec is not None:
            self.seen.new_record = None
            self.record = rec
            if rec.limits is not None:
                self.state.set_limits(rec.limits.max_linear_velocity, rec.limits.max_angular_velocity)
        if not self.connected:
            self.state.stop()
        self.state.tick()
        self._publish()

    def _publish(self) -> None:
        self.client.drive(self.namespace, self.state.linear, self.state.angular)
        self.published += 1

    # -- the screen ----------------------------------------------------------------------------

    def status(self) -> tuple[str, str]:
        """(style class, text) of the connection line."""
        ns = self.namespace
        if not self.seen.daemon_up:
            return "bad", f"no daemon at {self.client.options.endpoints()} - waiting for it"
        if not self.seen.robot_alive:
            return "warn", f"robot gone - waiting for {ns} to be spawned again"
        if self.seen.paused:
            return "warn", "robot alive, simulation paused"
        return "good", "robot alive"

    def render(self) -> StyleAndTextTuples:
        st, seen, rec = self.state, self.seen, self.record
        style, text = self.status()
        topic = self.client.keys.cmd_vel(self.namespace)

        def vel(v: float, w: float) -> str:
            return f"{v:+.3f} m/s   {w:+.3f} rad/s"

        out: StyleAndTextTuples = [
            ("class:title", f"fleet-teleop {rec.name} ({rec.model}) -> {topic}  "),
            (f"class:{style}", f"[{text}]\n"),
            ("class:dim", "          linear       angular\n"),
            ("", f"target    {vel(st.target_linear, st.target_angular)}\n"),
            ("", f"output    {vel(st.linear, st.angular)}   cmd_vel at {RATE_HZ:g} Hz\n"),
        ]
        odom = seen.odom
        if odom is None:
            out.append(("class:dim", "actual    (no odometry yet)\npose      (no odometry yet)\n"))
        else:
            tw, p = odom.twist.twist, odom.pose.pose
            yaw = p.orientation.yaw()
            stale = "   (stale)" if time.monotonic() - seen.odom_at > ODOM_STALE_S else ""
            out.append(("", f"actual    {vel(tw.linear.x, tw.angular.z)}   odom{stale}\n"))
            out.append(
                ("", f"pose      x {p.position.x:+.3f} m   y {p.position.y:+.3f} m   "
                     f"yaw {yaw:+.3f} rad ({math.degrees(yaw):+.1f}°)\n")
            )  # fmt: skip
        if seen.scan_at == 0.0:
            out.append(("class:dim", "nearest   (no scan yet)\n"))
        elif seen.nearest is None:
            out.append(("", "nearest   nothing within range\n"))
        else:
            dist, bearing = seen.nearest
            out.append(("", f"nearest   {dist:.2f} m at {describe_bearing(bearing)}\n"))
        out.append(
            ("class:dim", f"w/x ±{LIN_VEL_STEP:g} m/s  a/d ±{ANG_VEL_STEP:g} rad/s  (or arrows)  "
                          "s/space stop  q/Esc/Ctrl-C quit\n"
                          f"limits ±{st.max_linear:g} m/s  ±{st.max_angular:g} rad/s")
        )  # fmt: skip
        return out

    # -- the application -------------------------------------------------------------------------

    def build_app(self, input: Input | None = None, output: Output | None = None) -> Application[int]:
        kb = KeyBindings()

        def bind(key: str, name: str) -> None:
            @kb.add(key)
            def _(event: KeyPressEvent) -> None:
                self.press(name)
                event.app.invalidate()

        for key in ("w", "x", "a", "d", "s", "up", "down", "left", "right"):
            bind(key, key)
        bind("space", " ")

        @kb.add("q")
        @kb.add("Q")
        @kb.add("escape", eager=True)
        @kb.add("c-c")
        @kb.add("<sigint>")
        def _(event: KeyPressEvent) -> None:
            self.quit()

        @kb.add("<any>")
        def _(event: KeyPressEvent) -> None:
            pass  # any other key is ignored, as in teleop_keyboard

        style = Style.from_dict(
            {
                "title": "bold",
                "good": "ansigreen bold",
                "warn": "ansiyellow bold",
                "bad": "ansired bold",
                "dim": "ansibrightblack",
            }
        )
        window = Window(FormattedTextControl(self.render, show_cursor=False), dont_extend_height=True)
        app: Application[int] = Application(
            layout=Layout(window),
            key_bindings=kb,
            style=style,
            full_screen=False,
            input=input,
            output=output,
        )
        app.ttimeoutlen = 0.05  # a lone Esc quits at once instead of after 0.5 s
        self.app = app
        return app

    def quit(self) -> None:
        """Leave the UI (the last screen shows the stop); :meth:`close` sends the zero command."""
        app = self.app
        if app is not None and app.is_running and not app.is_done:
            self.state.stop()
            app.exit(result=EXIT_OK)

    async def _ticker(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / RATE_HZ
        next_at = loop.time()
        while True:
            self.tick()
            if self.app is not None:
                self.app.invalidate()
            next_at += period
            delay = next_at - loop.time()
            if delay < -period:  # fell behind (suspended terminal?): do not burst
                next_at, delay = loop.time(), 0.0
            await asyncio.sleep(max(0.0, delay))

    def run(self, input: Input | None = None, output: Output | None = None) -> int:
        """Run the UI until q/Esc/Ctrl-C; always ends with a zero command and a closed session."""
        app = self.build_app(input, output)

        def pre_run() -> None:
            app.create_background_task(self._ticker())
            if threading.current_thread() is threading.main_thread():
                loop = asyncio.get_running_loop()
                for sig in (signal.SIGTERM, signal.SIGHUP):
                    loop.add_signal_handler(sig, self.quit)

        try:
            return app.run(pre_run=pre_run)
        finally:
            self.close()


# --- command line -----------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet-teleop",
        description="Drive one fleetsim robot from the keyboard, as turtlebot3_teleop's "
        "teleop_keyboard: w/x linear ±0.01 m/s, a/d angular ±0.1 rad/s (or the arrow keys), "
        "s/space stop, q/Esc/Ctrl-C quit.",
        epilog="Exit codes: 0 quit, 1 no such robot, 2 usage error, 3 no daemon answered.",
    )
    p.add_argument("namespace", metavar="NS", help="the robot's namespace (or name), e.g. TB3_1")
    p.add_argument("--prefix", default=DEFAULT_PREFIX, help="key prefix of the daemon (default: %(default)s)")
    p.add_argument(
        "--timeout",
        type=float,
        default=3.0,
        metavar="S",
        help="seconds to wait for the daemon at start (default: %(default)g)",
    )
    add_zenoh_args(p, server=False)
    return p


def main(argv: Sequence[str] | None = None, *, input: Input | None = None, output: Output | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not (args.timeout > 0 and math.isfinite(args.timeout)):
        parser.error("--timeout must be a positive number of seconds")
    try:
        tele = Teleop.connect(args)
    except StartupError as e:
        print(e.message, file=sys.stderr, flush=True)
        return e.code
    tele.client.timeout = min(args.timeout, 1.0)  # status polls: notice a lost daemon quickly
    rc = tele.run(input=input, output=output)
    print(f"fleet-teleop: sent a zero command to {tele.namespace}; bye", flush=True)
    return rc


if __name__ == "__main__":
    sys.exit(main())
