"""fleet-view: frame building and decimation, the PNG snapshot, and the live page in a real
headless Chromium against a real daemon (spawn, delete, select, pixels, frame rate)."""

from __future__ import annotations

import io
import json
import math
import subprocess
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import numpy.typing as npt
import pytest
from PIL import Image

from clients.viewer import snapshot
from clients.viewer.decimate import SCAN_POINT_BUDGET, TRAIL_POINT_BUDGET, View
from clients.viewer.robot import LIDAR_OFFSET
from clients.viewer.state import FleetState, color_index, color_rgb
from protocol.control import Pose2D, RobotRecord
from protocol.messages import FleetOdometry, FleetScans, Header, LaserScan, Odometry, Quaternion, Time
from tests.cdp import Chromium
from tests.clients.viewer_harness import Viewer, colour_count, fleet_view
from tests.conftest import ROOT, Daemon

#: The four robots of turtlebot3_simulations' multi_robot.launch.py.
MULTI_ROBOT_POSES = [(-2.0, -0.5, 0.0), (0.5, -2.0, math.pi / 2), (2.0, 0.5, math.pi), (-0.5, 2.0, -math.pi / 2)]
BURGER_FOOTPRINT = [(0.038, -0.07), (0.038, 0.07), (-0.102, 0.07), (-0.102, -0.07)]


# -- frames, decoded the way the page does ------------------------------------------------


@dataclass
class Frame:
    header: dict[str, Any]
    poses: npt.NDArray[np.float32]  # (n, 5)
    scan_idx: npt.NDArray[np.uint32]
    scan_cnt: npt.NDArray[np.uint32]
    scan_pts: npt.NDArray[np.float32]  # (S, 2)
    trail_idx: npt.NDArray[np.uint32]
    trail_cnt: npt.NDArray[np.uint32]
    trail_pts: npt.NDArray[np.float32]  # (T, 2)


def decode_frame(data: bytes) -> Frame:
    """A binary frame, decoded the way the page does it."""
    hlen = int.from_bytes(data[:4], "little")
    h = json.loads(data[4 : 4 + hlen])
    off = 4 + hlen

    def take(dtype: str, n: int) -> Any:
        nonlocal off
        a = np.frombuffer(data, dtype, n, off)
        off += a.nbytes
        return a

    n, s, t = h["n"], h["scans"], h["trails"]
    f = Frame(
        h,
        take("<f4", 5 * n).reshape(n, 5),
        take("<u4", s),
        take("<u4", s),
        take("<f4", 2 * h["scan_points"]).reshape(-1, 2),
        take("<u4", t),
        take("<u4", t),
        take("<f4", 2 * h["trail_points"]).reshape(-1, 2),
    )
    assert off == len(data)
    return f


def record(ns: str, x: float = 0.0, y: float = 0.0) -> RobotRecord:
    return RobotRecord(name=ns, namespace=ns, model="burger", pose=Pose2D(x=x, y=y), footprint=BURGER_FOOTPRINT)


def odom(t: float, x: float, y: float, yaw: float, v: float = 0.0, w: float = 0.0) -> Odometry:
    msg = Odometry(header=Header(stamp=Time.from_seconds(t)))
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation = Quaternion.from_yaw(yaw)
    msg.twist.twist.linear.x, msg.twist.twist.angular.z = v, w
    return msg


def scan(t: float, ranges: list[float]) -> LaserScan:
    n = len(ranges)
    return LaserScan(
        header=Header(stamp=Time.from_seconds(t)),
        angle_min=0.0,
        angle_max=2 * math.pi * (n - 1) / n,
        angle_increment=2 * math.pi / n,
        range_min=0.12,
        range_max=3.5,
        ranges=np.asarray(ranges, "<f4").tobytes(),
    )


def fleet(n: int, spacing: float = 1.0) -> FleetState:
    state = FleetState()
    side = math.ceil(math.sqrt(n))
    for i in range(n):
        ns = f"r{i}"
        x, y = (i % side) * spacing, (i // side) * spacing
        state.on_presence(ns, True)
        state.apply_records([record(ns, x, y)])
        for k in range(10):
            state.on_odom(ns, odom(k / 30, x + 0.1 * k, y, 0.0, 0.2))
        state.on_scan(ns, scan(9 / 30, [1.0] * 360))
    return state


def test_frame_carries_poses_and_world_frame_scan_points() -> None:
    state = FleetState()
    state.on_presence("tb3_0", True)
    state.apply_records([record("tb3_0", 1.0, 2.0)])
    state.on_odom("tb3_0", odom(1.0, 1.0, 2.0, math.pi / 2, 0.1, 0.2))
    ranges = [math.inf] * 360
    ranges[0], ranges[90], ranges[180] = 1.0, 2.0, 0.05  # 0.05 is below range_min
    state.on_scan("tb3_0", scan(1.0, ranges))
    version, meta, data, stats = state.frame(View(), seq=7)
    assert meta is not None and json.loads(meta)["robots"][0][:3] == ["tb3_0", "tb3_0", "burger"]
    f = decode_frame(data)
    assert (f.header["seq"], f.header["meta"], f.header["n"], f.header["scans"]) == (7, version, 1, 1)
    np.testing.assert_allclose(f.poses[0], [1.0, 2.0, math.pi / 2, 0.1, 0.2], atol=1e-6)
    # beam 0 (straight ahead = +y in the world) and beam 90 (left = -x), from base_scan
    ox = LIDAR_OFFSET["burger"][0]
    expected = [[1.0, 2.0 + ox + 1.0], [1.0 - 2.0, 2.0 + ox]]
    np.testing.assert_allclose(f.scan_pts, expected, atol=1e-3)
    assert stats.nbytes == len(data)
    # the meta goes out only when it changed
    assert state.frame(View(), 8, known_meta=version)[1] is None


def test_the_fleet_topics_make_the_same_frame_as_the_per_robot_topics() -> None:
    """The viewer follows P/odometry and P/scans; a tick of those must draw what the robots' own
    messages of that tick draw."""
    from simd.core.lidar import LidarSpec
    from simd.wire.fleet_codec import encode_fleet_odometry, encode_fleet_scans

    names = ["a", "b", "c"]
    rng = np.random.default_rng(4)
    x, y, yaw = rng.uniform(0, 3, 3), rng.uniform(0, 3, 3), rng.uniform(-3, 3, 3)
    v, w = rng.uniform(0, 0.2, 3), rng.uniform(-1, 1, 3)
    rows = rng.uniform(0.2, 3.4, size=(3, 360)).astype(np.float32)
    rows[:, ::7] = np.inf
    per_robot, batched = FleetState(), FleetState()
    for st in (per_robot, batched):
        for ns in names:
            st.on_presence(ns, True)
        st.apply_records([record(ns) for ns in names])
    for i, ns in enumerate(names):
        per_robot.on_odom(ns, odom(2.0, x[i], y[i], yaw[i], v[i], w[i]))
        per_robot.on_scan(ns, scan(2.0, rows[i].tolist()))
    spec = LidarSpec(samples=360, angle_max=2 * math.pi * 359 / 360)
    batched.on_fleet_odom(
        msgspec.msgpack.decode(encode_fleet_odometry(names, 2.0, x, y, yaw, v, np.zeros(3), w), type=FleetOdometry)
    )
    batched.on_fleet_scans(msgspec.msgpack.decode(encode_fleet_scans(spec, names, 2.0, rows), type=FleetScans))
    a, b = decode_frame(per_robot.frame(View())[2]), decode_frame(batched.frame(View())[2])
    assert a.header["n"] == b.header["n"] == 3 and a.header["scans"] == b.header["scans"] == 3
    np.testing.assert_allclose(b.poses, a.poses, atol=1e-6)  # f32 on the wire; yaw via quaternion in one
    np.testing.assert_allclose(b.scan_pts, a.scan_pts, atol=1e-5)
    assert batched.odom_count == per_robot.odom_count == 3 and batched.scan_count == 3


def test_scan_is_placed_with_the_pose_of_its_own_stamp() -> None:
    state = FleetState()
    state.on_presence("a", True)
    state.apply_records([record("a")])
    state.on_odom("a", odom(1.0, 0.0, 0.0, 0.0))
    state.on_odom("a", odom(1.0 + 1 / 30, 0.5, 0.0, math.pi))  # moved after the scan was taken
    state.on_scan("a", scan(1.0, [1.0] + [math.inf] * 359))
    pts = decode_frame(state.frame(View())[2]).scan_pts
    np.testing.assert_allclose(pts, [[1.0 + LIDAR_OFFSET["burger"][0], 0.0]], atol=1e-3)


def test_presence_is_the_truth() -> None:
    state = FleetState()
    state.on_odom("ghost", odom(1.0, 0, 0, 0))  # before presence: ignored
    state.on_presence("a", True)
    state.apply_records([record("a"), record("late")])  # "late" is not present: ignored
    assert state.counts()["robots"] == 1
    v = state.version
    state.on_presence("a", False)
    state.apply_records([record("a")])  # a stale list reply cannot resurrect it
    state.on_odom("a", odom(2.0, 0, 0, 0))
    assert state.counts() == {"present": 0, "robots": 0, "with_odom": 0, "with_scan": 0}
    assert state.version > v


def test_decimation_keeps_frames_small() -> None:
    state = fleet(400)
    _, _, data, stats = state.frame(View())
    f = decode_frame(data)
    assert stats.beam_step > 1
    assert 360 // stats.beam_step * stats.scans <= SCAN_POINT_BUDGET + 360
    assert stats.trail_points <= TRAIL_POINT_BUDGET
    assert len(data) < 200_000, len(data)
    # the selected robot's scan is first and at full density
    sel = state.frame(View(selected="r399"))[2]
    fs = decode_frame(sel)
    assert (int(fs.scan_idx[0]), int(fs.scan_cnt[0])) == (399, 360)
    # a view of one corner gets only the scans that can reach into it
    corner = decode_frame(state.frame(View(-1.0, -1.0, 0.5, 0.5))[2])
    assert 0 < len(corner.scan_idx) < len(f.scan_idx)
    assert all(int(i) % 20 < 6 and int(i) // 20 < 6 for i in corner.scan_idx)
    # toggles off: poses only
    off = state.frame(View(scans=False, trails=False))[3]
    assert off.scans == off.trails == 0
    assert off.nbytes < 400 * 20 + 400


def test_trail_is_decimated_and_ages_out() -> None:
    state = FleetState()
    state.on_presence("a", True)
    state.apply_records([record("a")])
    for k in range(300):  # 10 s at 30 Hz, 0.2 m/s
        state.on_odom("a", odom(k / 30, 0.2 * k / 30, 0.0, 0.0))
    xs = decode_frame(state.frame(View())[2]).trail_pts[:, 0]
    assert np.all(np.diff(xs) > 0.02)  # stored every ~3 cm, not every tick
    assert xs[0] > 0.2 * (299 / 30 - 5.0) - 0.05  # only the last 5 s
    assert 0 <= 0.2 * 299 / 30 - xs[-1] < 0.03  # the newest point is near the robot


# -- processes ------------------------------------------------------------------------------


def spawn_multi_robot(daemon: Daemon) -> list[tuple[str, float, float, float]]:
    c = daemon.client()
    robots = []
    for i, (x, y, yaw) in enumerate(MULTI_ROBOT_POSES):
        c.spawn(f"tb3_{i}", x, y, yaw, model="waffle" if i == 1 else "burger")
        robots.append((f"tb3_{i}", x, y, yaw))
    return robots


# -- snapshot ---------------------------------------------------------------------------------


def take_snapshot(daemon: Daemon, out: Path, size: int) -> tuple[Image.Image, str]:
    """``fleet-view --snapshot``: the picture, and what it said."""
    res = subprocess.run(
        fleet_view(daemon, "--snapshot", str(out), "--size", str(size)),
        capture_output=True, text=True, timeout=30, cwd=ROOT,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    img = Image.open(out)
    assert img.size == (size, size)
    return img, res.stdout


def test_snapshot_png_shows_robots_at_their_poses(daemon: Daemon, tmp_path: Path) -> None:
    robots = spawn_multi_robot(daemon)
    size = 800
    img, said = take_snapshot(daemon, tmp_path / "snap.png", size)
    assert "4 robots" in said
    assert img.size == (size, size)
    tf = snapshot.fit(daemon.client().world(), [(x, y) for _, x, y, _ in robots], size)
    palette = [color_rgb(color_index(ns)) for ns, *_ in robots]
    for (ns, x, y, _), rgb in zip(robots, palette, strict=True):
        assert colour_count(img, tf.to_pixel(x, y), 0.09 * tf.scale, rgb) >= 20, ns
    # an empty stretch of floor between the pillars: no robot colour at all
    for rgb in palette:
        assert colour_count(img, tf.to_pixel(0.55, -0.55), 0.3 * tf.scale, rgb) == 0


def test_snapshot_draws_a_goal_and_its_path(daemon: Daemon, tmp_path: Path) -> None:
    c = daemon.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("tb3_1", 0.5, -2.0, math.pi / 2)
    goal = c.navigate("tb3_0", 1.5, 0.5, yaw=1.0, tolerance=0.3)
    deadline = time.monotonic() + 10
    while "tb3_0" not in c.plans() and time.monotonic() < deadline:
        time.sleep(0.05)
    plan = c.plans()["tb3_0"].points
    size = 800
    img, _ = take_snapshot(daemon, tmp_path / "nav.png", size)
    assert not goal.done
    tf = snapshot.fit(c.world(), [], size)
    rgb = snapshot.goal_rgb(color_index("tb3_0"))
    assert colour_count(img, tf.to_pixel(1.5, 0.5), 4, rgb) >= 6  # the cross at the goal
    assert colour_count(img, tf.to_pixel(1.5, 0.2), 3, rgb, 30) >= 3  # the tolerance circle, 0.3 m below
    heading = tf.to_pixel(1.5 + 0.2 * math.cos(1.0), 0.5 + 0.2 * math.sin(1.0))
    assert colour_count(img, heading, 3, rgb, 30) >= 3  # the arrow of the heading asked for
    (ax, ay), (bx, by) = plan[-2], plan[-1]  # the path's last stretch (the robot is far from it)
    assert colour_count(img, tf.to_pixel((ax + bx) / 2, (ay + by) / 2), 3, rgb, 30) >= 3


# -- the live page ------------------------------------------------------------------------------


@pytest.mark.browser
def test_page_follows_the_fleet(daemon: Daemon, viewer_factory: Callable[..., Viewer], browser: Chromium) -> None:
    robots = spawn_multi_robot(daemon)
    v = viewer_factory(daemon)
    browser.navigate(v.url)
    browser.wait_for("viewerStats.robots === 4 && viewerStats.frames > 2 && viewerStats.scans === 4", 15)
    assert browser.evaluate("document.querySelectorAll('#robot-list li').length") == 4
    assert browser.evaluate("document.getElementById('robot-count').textContent") == "4"
    assert browser.evaluate("viewerStats.world") == "turtlebot3_world"
    with urllib.request.urlopen(v.url + "api/counts", timeout=5) as r:
        assert json.load(r)["robots"] == 4
    with urllib.request.urlopen(v.url + "snapshot.png?size=256", timeout=10) as r:
        assert Image.open(io.BytesIO(r.read())).size == (256, 256)

    # spawned and deleted robots appear and vanish (liveliness)
    c = daemon.client()
    c.spawn("late_1", 0.55, 0.55, model="waffle_pi")
    browser.wait_for("viewerStats.names().includes('late_1') && viewerStats.robot('late_1').model === 'waffle_pi'")
    assert browser.evaluate("document.querySelectorAll('#robot-list li').length") == 5
    c.delete("late_1")
    browser.wait_for("viewerStats.robots === 4 && !viewerStats.names().includes('late_1')")

    # click a robot: the side panel shows it
    browser.wait_for("viewerStats.robot('tb3_2') && Number.isFinite(viewerStats.robot('tb3_2').v)")
    x, y = browser.evaluate("viewerStats.toScreen(2.0, 0.5)")
    browser.click(x, y)
    browser.wait_for("document.getElementById('sel-ns').textContent === 'tb3_2'")
    assert not browser.evaluate("document.getElementById('selected').hidden")
    assert browser.evaluate("document.getElementById('sel-x').textContent").startswith("2.0")

    # robot pixels where the page's own transform puts each robot
    browser.evaluate("viewerStats.select(null)")
    drawn = browser.evaluate("viewerStats.frames")
    browser.wait_for(f"viewerStats.frames > {drawn} + 2")  # the page drew without the selection
    img = Image.open(io.BytesIO(browser.screenshot()))
    dpr = browser.evaluate("window.devicePixelRatio")
    scale = browser.evaluate("viewerStats.view().scale")
    for ns, rx, ry, _ in robots:
        px, py = browser.evaluate(f"viewerStats.toScreen({rx}, {ry})")
        rgb = browser.evaluate(f"viewerStats.colorOf('{ns}')")
        assert colour_count(img, (px * dpr, py * dpr), 0.09 * scale * dpr, rgb) >= 15, ns
    ex, ey = browser.evaluate("viewerStats.toScreen(0.55, -0.55)")
    for ns, *_ in robots:
        rgb = browser.evaluate(f"viewerStats.colorOf('{ns}')")
        assert colour_count(img, (ex * dpr, ey * dpr), 0.3 * scale * dpr, rgb) == 0

    # the scans toggle reaches the server: frames stop carrying scans
    browser.evaluate("document.getElementById('show-scans').click()")
    browser.wait_for("viewerStats.scans === 0 && viewerStats.frames > 0")

    rc, took = v.stop()  # SIGTERM with the page still connected
    assert (rc, took < 5) == (0, True)


@pytest.mark.browser
@pytest.mark.slow
def test_page_frame_rate_with_100_robots(
    daemon_factory: Callable[..., Daemon], viewer_factory: Callable[..., Viewer], browser: Chromium
) -> None:
    daemon = daemon_factory("--world", "empty")
    c = daemon.client()
    names = [f"r{i}" for i in range(100)]
    for i, ns in enumerate(names):
        c.spawn(ns, (i % 10) * 1.0, (i // 10) * 1.0, yaw=0.7 * i)
    stop = threading.Event()

    def drive() -> None:  # every robot circles, so there are trails and changing scans
        while not stop.is_set():
            for ns in names:
                c.drive(ns, 0.15, 0.6)
            stop.wait(0.2)

    driver = threading.Thread(target=drive, daemon=True)
    driver.start()
    try:
        v = viewer_factory(daemon)
        browser.navigate(v.url)
        browser.wait_for("viewerStats.robots === 100 && viewerStats.frames > 5", 20)
        f0, t0 = browser.evaluate("[viewerStats.frames, performance.now()]")
        time.sleep(4.0)
        f1, t1 = browser.evaluate("[viewerStats.frames, performance.now()]")
        st = browser.evaluate("JSON.parse(JSON.stringify(viewerStats))")
    finally:
        stop.set()
        driver.join()
    fps = (f1 - f0) / ((t1 - t0) / 1000)
    print(
        f"\nfleet-view, 100 robots: {fps:.1f} frames/s drawn in the browser (page says {st['fps']:.1f}); "
        f"draw {st['drawMs']:.1f} ms, frame {st['bytes'] / 1024:.1f} KB, scans {st['scans']} "
        f"({st['scanPoints']} points, every {st['beamStep']}. beam), trails {st['trails']}"
    )
    assert st["robots"] == 100 and st["trails"] > 0 and st["scans"] > 0
    assert fps > 2  # a loose sanity bound (shared CI machines vary); the number is reported above


def test_the_map_layer_grows_under_the_robots(
    daemon_factory: Callable[..., Daemon], viewer_factory: Callable[..., Viewer], browser: Chromium
) -> None:
    """fleet-view --map: /map.png is the grid the scans build, placed by its headers, drawn by the page."""
    d = daemon_factory("--lockstep")
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    v = viewer_factory(d, "--map")
    browser.navigate(v.url)
    browser.wait_for("viewerStats.robots === 1", 15)
    deadline = time.monotonic() + 20
    scans = 0
    while scans < 10 and time.monotonic() < deadline:  # the viewer's subscription needs a moment
        c.step(30)
        with urllib.request.urlopen(v.url + "map.png", timeout=5) as r:
            scans = int(r.headers["X-Map-Scans"])
    assert scans >= 10
    with urllib.request.urlopen(v.url + "map.png", timeout=5) as r:
        x0, _ = (float(t) for t in r.headers["X-Map-Origin"].split(","))
        res = float(r.headers["X-Map-Resolution"])
        layer = np.asarray(Image.open(io.BytesIO(r.read())))
    walls = np.argwhere(layer[:, :, 3] == 235)
    assert len(walls) > 50 and (layer[:, :, 3] == 110).sum() > 1000  # walls and free space
    # a wall cell is where a wall is: the hexagon's left corner, (-2.93, 0), lies at the left edge of the walls
    xs = x0 + (walls[:, 1] + 0.5) * res
    assert abs(xs.min() - (-2.93)) < 0.1
    assert (layer.shape[0] * res, layer.shape[1] * res) == pytest.approx((8.2, 9.3), abs=0.06)  # bounds + 0.5 m
    browser.wait_for("viewerStats.mapScans >= 10", 10)  # the page fetched it too, and draws it


def _wait_serving(url: str, timeout: float = 15.0) -> None:
    """Until the viewer's server answers: it listens a moment after it prints its address."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            urllib.request.urlopen(url + "api/counts", timeout=5).close()
            return
        except urllib.error.URLError:
            assert time.monotonic() < deadline, f"{url} did not answer within {timeout:g} s"
            time.sleep(0.1)


def test_without_map_there_is_no_layer(daemon: Daemon, viewer_factory: Callable[..., Viewer]) -> None:
    v = viewer_factory(daemon)
    _wait_serving(v.url)
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(v.url + "map.png", timeout=5)
    assert e.value.code == 404
    e.value.close()


def _world_names(url: str, want: str, timeout: float = 15.0) -> list[str]:
    """The world messages a page receives on ``/ws`` until one names ``want`` (or the time is up)."""
    from websockets.sync.client import connect

    names: list[str] = []
    deadline = time.monotonic() + timeout
    with connect(url.replace("http://", "ws://") + "ws") as ws:
        while want not in names and time.monotonic() < deadline:
            try:
                msg = ws.recv(timeout=max(0.01, deadline - time.monotonic()))
            except TimeoutError:
                break
            if isinstance(msg, str) and (m := json.loads(msg)).get("type") == "world":
                names.append(m["name"])
    return names


def test_a_daemon_restarted_in_another_world_is_drawn_in_it(
    tmp_path: Path, viewer_factory: Callable[..., Viewer]
) -> None:
    """simd stopped and started again on its port with another --world: a running fleet-view
    (and a page open meanwhile) shows the new world, as the tutorial's map step needs."""
    from tests.conftest import start_daemon

    first = start_daemon(tmp_path)
    v = viewer_factory(first)
    _wait_serving(v.url)
    try:
        assert _world_names(v.url, "turtlebot3_world")[:1] == ["turtlebot3_world"]
    finally:
        first.stop()
    second = start_daemon(tmp_path, "--world", "empty", port=first.port)
    try:
        names = _world_names(v.url, "empty")  # a page opened now may first get the old one
        assert names[-1:] == ["empty"], names
    finally:
        second.stop()
    assert v.proc.poll() is None
