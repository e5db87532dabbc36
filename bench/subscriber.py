"""The subscriber process, both ends of it: the code it runs and the benchmark's handle on it.

Delivery is measured in a separate process, as a user's subscriber would receive it, so that
counting tens of thousands of messages a second never competes with the benchmark's own driver
and clock for a GIL. The two ends talk over the child's stdin and stdout in one-line messages;
keeping them in one module keeps that line protocol in one place.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from bench.processes import PREEXEC, ROOT, raise_exit, stop_process
from bench.wire import ODOM_MIN_BYTES, PREFIX, SCAN_MIN_BYTES, zenoh_config


def subscriber_main(endpoint: str, probe: str, topics: str = "robots") -> int:
    """A separate process: a zenoh client counting every odom and scan per key.

    ``topics`` is ``robots`` (every robot's own ``P/<ns>/odom`` and ``P/<ns>/scan``),
    ``fleet`` (``P/odometry`` and ``P/scans``, one message a tick for the whole fleet, whose rows
    are counted under the same per-robot keys) or ``ros`` (every robot's ``/<ns>/odom`` and
    ``/<ns>/scan`` and the fleet's ``/tf`` as ROS 2 sees them over rmw_zenoh, on ``endpoint``:
    the daemon's ROS session; counted under the same keys, and ``/tf``'s transforms under
    ``tf``).

    Prints ``READY``; ``COUNT t odom scan bad keys_odom keys_scan`` every second;
    ``TWIST t moving`` when the probe robot's odometry twist turns non-zero or back to zero;
    answers ``SNAP id`` on stdin with the per-key counts as JSON; exits on ``QUIT`` or EOF.
    """
    import msgspec
    import zenoh

    from protocol.messages import FLEET_ODOM_COLUMNS, FleetOdometry, FleetScans, Odometry

    signal.signal(signal.SIGTERM, raise_exit)
    signal.signal(signal.SIGINT, raise_exit)
    out_lock = threading.Lock()

    def emit(line: str) -> None:
        with out_lock:
            sys.stdout.write(line + "\n")
            sys.stdout.flush()

    odom: dict[str, int] = {}
    scan: dict[str, int] = {}
    tf = [0, 0]  # /tf messages, transforms in them
    bad = [0]

    dec = msgspec.msgpack.Decoder(Odometry)
    moving: list[bool | None] = [None]

    def probe_twist(v: float, w: float) -> None:
        t = time.monotonic()  # CLOCK_MONOTONIC is system-wide: comparable with the driver's
        now = abs(v) > 1e-9 or abs(w) > 1e-9
        if now != moving[0]:
            moving[0] = now
            emit(f"TWIST {t:.6f} {int(now)}")

    def on_probe(sample: zenoh.Sample) -> None:
        tw = dec.decode(sample.payload.to_bytes()).twist.twist
        probe_twist(tw.linear.x, tw.angular.z)

    stop = threading.Event()
    session = zenoh.open(zenoh_config(endpoint, 30.0))
    try:
        probe_key = f"{PREFIX}/{probe}/odom"

        def on_sample(sample: zenoh.Sample) -> None:  # only counts: this must never be the bottleneck
            k = str(sample.key_expr)
            if k.endswith("/odom"):
                odom[k] = odom.get(k, 0) + 1
                if len(sample.payload) < ODOM_MIN_BYTES:
                    bad[0] += 1
                if k == probe_key:
                    on_probe(sample)
            elif k.endswith("/scan"):
                scan[k] = scan.get(k, 0) + 1
                if len(sample.payload) < SCAN_MIN_BYTES:
                    bad[0] += 1

        # One callback for both topics and the probe: measured in this benchmark at 20x, ~11 us of
        # CPU a message against ~13.5 with a callback per topic and one more for the probe, the
        # difference between keeping up and not. Not P/*/*, which would also bring every
        # cmd_vel, nor P/**, which would wake the JSON mirrors (P/<ns>/odom/json).
        fleet_odom = msgspec.msgpack.Decoder(FleetOdometry)
        fleet_scan = msgspec.msgpack.Decoder(FleetScans)
        odom_keys: dict[str, str] = {}
        scan_keys: dict[str, str] = {}

        def on_fleet_odom(sample: zenoh.Sample) -> None:
            try:
                msg = fleet_odom.decode(sample.payload.to_bytes())
            except msgspec.DecodeError:
                bad[0] += 1
                return
            n = len(msg.namespaces)
            if not all(len(getattr(msg, c)) == 8 * n for c in FLEET_ODOM_COLUMNS):
                bad[0] += 1
                return  # a malformed message delivers nothing
            for ns in msg.namespaces:
                k = odom_keys.get(ns) or odom_keys.setdefault(ns, f"{PREFIX}/{ns}/odom")
                odom[k] = odom.get(k, 0) + 1
            if probe in msg.namespaces:
                i = msg.namespaces.index(probe)
                t = time.monotonic()
                now = bool(abs(msg.array("linear_x")[i]) > 1e-9 or abs(msg.array("angular_z")[i]) > 1e-9)
                if now != moving[0]:
                    moving[0] = now
                    emit(f"TWIST {t:.6f} {int(now)}")

        def on_fleet_scan(sample: zenoh.Sample) -> None:
            try:
                msg = fleet_scan.decode(sample.payload.to_bytes())
                msg.ranges_array()  # checks the rows' size
            except (msgspec.DecodeError, ValueError):
                bad[0] += 1
                return
            for ns in msg.namespaces:
                k = scan_keys.get(ns) or scan_keys.setdefault(ns, f"{PREFIX}/{ns}/scan")
                scan[k] = scan.get(k, 0) + 1

        if topics == "ros":
            _subscribe_ros(session, probe, odom, scan, tf, bad, on_probe_twist=lambda v, w: probe_twist(v, w))
        elif topics == "fleet":
            session.declare_subscriber(f"{PREFIX}/odometry", on_fleet_odom)
            session.declare_subscriber(f"{PREFIX}/scans", on_fleet_scan)
        else:
            session.declare_subscriber(f"{PREFIX}/*/odom", on_sample)
            session.declare_subscriber(f"{PREFIX}/*/scan", on_sample)

        def report() -> None:
            while not stop.wait(1.0):
                emit(
                    f"COUNT {time.monotonic():.6f} {sum(list(odom.values()))} {sum(list(scan.values()))} "
                    f"{bad[0]} {len(odom)} {len(scan)}"
                )

        threading.Thread(target=report, name="report", daemon=True).start()
        emit("READY")
        for line in sys.stdin:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "SNAP":
                snap = {"t": time.monotonic(), "odom": dict(odom), "scan": dict(scan), "tf": list(tf), "bad": bad[0]}
                emit(f"SNAP {parts[1]} {json.dumps(snap, separators=(',', ':'))}")
            elif parts[0] == "QUIT":
                break
    finally:
        stop.set()
        session.close()
    return 0


def _subscribe_ros(session: Any, probe: str, odom: dict[str, int], scan: dict[str, int], tf: list[int],
                   bad: list[int], on_probe_twist: Any) -> None:  # fmt: skip
    """Subscribe as ROS tools would, with wildcards over the robots (a ROS subscriber per
    robot and topic asks the daemon for exactly the same messages)."""
    import struct

    from simd.adapters.ros2.graph import Topic

    def key(name: str, typename: str) -> str:
        return Topic(name, typename, 0, "jazzy").key

    odom_keys: dict[str, str] = {}
    scan_keys: dict[str, str] = {}
    probe_odom = key(f"/{probe}/odom", "nav_msgs/msg/Odometry")

    def on_odom(sample: Any) -> None:
        k = str(sample.key_expr)
        ns = k.split("/", 2)[1]
        name = odom_keys.get(ns) or odom_keys.setdefault(ns, f"{PREFIX}/{ns}/odom")
        odom[name] = odom.get(name, 0) + 1
        payload = sample.payload.to_bytes()
        if len(payload) < ODOM_MIN_BYTES or sample.attachment is None:
            bad[0] += 1
        elif k == probe_odom:  # twist.linear.x and angular.z: the last 6 doubles before the covariance
            end = len(payload) - 288
            v, *_, w = struct.unpack_from("<6d", payload, end - 48)
            on_probe_twist(v, w)

    def on_scan(sample: Any) -> None:
        ns = str(sample.key_expr).split("/", 2)[1]
        name = scan_keys.get(ns) or scan_keys.setdefault(ns, f"{PREFIX}/{ns}/scan")
        scan[name] = scan.get(name, 0) + 1
        if len(sample.payload) < SCAN_MIN_BYTES or sample.attachment is None:
            bad[0] += 1

    def on_tf(sample: Any) -> None:
        payload = sample.payload.to_bytes()
        if len(payload) < 8 or sample.attachment is None:
            bad[0] += 1
            return
        tf[0] += 1
        tf[1] += struct.unpack_from("<I", payload, 4)[0]  # the transforms in the message

    session.declare_subscriber(key("/*/odom", "nav_msgs/msg/Odometry"), on_odom)
    session.declare_subscriber(key("/*/scan", "sensor_msgs/msg/LaserScan"), on_scan)
    session.declare_subscriber(key("/tf", "tf2_msgs/msg/TFMessage"), on_tf)


class Subscriber:
    """Runs and talks to the subscriber process."""

    def __init__(self, endpoint: str, probe: str, log_path: Path, topics: str = "robots") -> None:
        self.log = log_path.open("w")
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "bench.fleet_bench",
                "--role",
                "subscriber",
                "--endpoint",
                endpoint,
                "--probe",
                probe,
                "--topics",
                topics,
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.log,
            text=True,
            bufsize=1,
            cwd=ROOT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
            start_new_session=True,  # Ctrl-C reaches the benchmark only; it stops everything in order
            preexec_fn=PREEXEC,
        )
        self.ready = threading.Event()
        self.cond = threading.Condition()
        self.twists: list[tuple[float, bool]] = []
        self.counts: list[tuple[float, int, int, int]] = []  # (t, odom, scan, bad), one per second
        self.snaps: queue.Queue[dict[str, Any]] = queue.Queue()
        self._snap_id = 0
        self.reader = threading.Thread(target=self._read, name="subscriber-reader", daemon=True)
        self.reader.start()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            kind, _, rest = line.rstrip("\n").partition(" ")
            try:
                if kind == "READY":
                    self.ready.set()
                elif kind == "COUNT":
                    t, o, s, b = rest.split()[:4]
                    self.counts.append((float(t), int(o), int(s), int(b)))
                elif kind == "TWIST":
                    t, m = rest.split()
                    with self.cond:
                        self.twists.append((float(t), m == "1"))
                        self.cond.notify_all()
                elif kind == "SNAP":
                    _, payload = rest.split(" ", 1)
                    self.snaps.put(json.loads(payload))
            except ValueError:
                continue

    def wait_ready(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not self.ready.wait(0.1):
            if self.proc.poll() is not None:
                raise RuntimeError(f"the subscriber exited with {self.proc.returncode}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the subscriber was not ready within {timeout:g} s")

    def snapshot(self, timeout: float = 10.0) -> dict[str, Any]:
        while not self.snaps.empty():
            self.snaps.get_nowait()
        self._snap_id += 1
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"SNAP {self._snap_id}\n")
        self.proc.stdin.flush()
        try:
            return self.snaps.get(timeout=timeout)
        except queue.Empty:
            raise RuntimeError(f"the subscriber did not answer a snapshot within {timeout:g} s") from None

    def rates(self) -> tuple[float, float]:
        """Messages per second over the last reported second (odom, scan)."""
        c = self.counts[-2:]
        if len(c) < 2 or c[1][0] <= c[0][0]:
            return 0.0, 0.0
        dt = c[1][0] - c[0][0]
        return (c[1][1] - c[0][1]) / dt, (c[1][2] - c[0][2]) / dt

    def moving(self) -> bool | None:
        with self.cond:
            return self.twists[-1][1] if self.twists else None

    def wait_twist(self, moving: bool, after: float, timeout: float) -> float | None:
        """Time (monotonic) of the first probe odometry at or after ``after`` whose twist is
        non-zero (``moving``) or zero; None on timeout."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                for t, m in self.twists:
                    if t >= after and m == moving:
                        return t
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self.cond.wait(left)

    def stop(self) -> None:
        try:
            if self.proc.poll() is None and self.proc.stdin is not None:
                self.proc.stdin.write("QUIT\n")
                self.proc.stdin.flush()
                self.proc.stdin.close()
        except (OSError, ValueError):
            pass
        stop_process(self.proc, 5.0 if self.ready.is_set() else 0.5)
        self.reader.join(2.0)
        self.log.close()
