"""``fleet-teleop NS``: drive one robot from the keyboard, as TurtleBot3's ``teleop_keyboard``.

Same keys and numbers as ``turtlebot3_teleop``: ``w``/``x`` change the linear target by
±0.01 m/s, ``a``/``d`` the angular target by +0.1/−0.1 rad/s, ``s`` or space stop at once
(target and output to zero, no ramp); the arrow keys do the same as w/x/a/d. The output ramps
toward the target by at most 0.005 m/s and 0.05 rad/s per loop iteration, the loop runs at
10 Hz and publishes ``cmd_vel`` on every iteration, so the daemon's 0.5 s watchdog never stops
a robot that is being driven. Targets clamp to the limits in the robot's record (no
``TURTLEBOT3_MODEL`` needed). ``q``, Esc or Ctrl-C quit, after one zero command.

The pure part (keys, ramps, the screen's text) is clients/teleop/model.py; :class:`Teleop`
connects it to a daemon and to a small prompt_toolkit application that also shows odometry,
the nearest obstacle of the latest scan and whether the robot and the daemon are there.
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

from prompt_toolkit.application import Application
from prompt_toolkit.formatted_text import StyleAndTextTuples
from prompt_toolkit.input import Input
from prompt_toolkit.key_binding import KeyBindings, KeyPressEvent
from prompt_toolkit.layout import Layout, Window
from prompt_toolkit.layout.controls import FormattedTextControl
from prompt_toolkit.output import Output
from prompt_toolkit.styles import Style

from clients.api import FleetClient
from clients.fleet_args import add_daemon_args
from clients.teleop.model import RATE_HZ, Seen, TeleopState, nearest_obstacle, screen, status
from fleetcommon.zenoh_config import ZenohOptions, options_from_args
from protocol.control import RobotRecord
from protocol.errors import ErrorCode, FleetError
from protocol.keys import DEFAULT_PREFIX, Keys
from protocol.messages import LaserScan, Odometry

__all__ = ["Teleop", "build_parser", "main"]  # the model: clients/teleop/model.py

#: A status poll of the daemon (clock query) every this many seconds.
POLL_PERIOD = 0.5

EXIT_OK = 0
EXIT_UNKNOWN_ROBOT = 1
EXIT_USAGE = 2
EXIT_NO_DAEMON = 3


# --- the live session -------------------------------------------------------------------------


class StartupError(Exception):
    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


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
            f"within {timeout:g} s ({options.no_answer_hint()})"
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
        robot's record after it came back (its model, hence its limits, may differ) and ask
        for its latest messages, as following it starts again."""
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
                        # following it again: in a big fleet a (restarted) daemon declares the
                        # publishers of robots asked for by name first (FleetClient.on_odom)
                        self.client.latest_odom(self.namespace)
                        self.client.latest_scan(self.namespace)
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
        return status(self.seen, self.client.options.endpoints(), self.namespace)

    def render(self) -> StyleAndTextTuples:
        topic = self.client.keys.cmd_vel(self.namespace)
        endpoints = self.client.options.endpoints()
        return list(screen(self.record, self.state, self.seen, topic, endpoints, time.monotonic()))

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
    add_daemon_args(p, "seconds to wait for the daemon at start")
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
