"""The compiled fast paths (simd/core/_drive.c, simd/wire/_odompack.c, simd/core/_scannoise.c through
simd/core/sensor_model.py) against their numpy references, their input checks, and the
FLEETSIM_NATIVE switch. The lidar kernel and the noise generator have their own files."""

from __future__ import annotations

import functools
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass, fields

import msgspec
import numpy as np
import numpy.typing as npt
import pytest

from fleetcommon.arrays import F64
from protocol import Odometry, SpawnRequest
from simd.core import drive, native, sensor_model
from simd.core.lidar import LidarSpec
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import load_world
from simd.wire import list_codec, odom_codec
from simd.wire.odom_codec import OdometryEncoder

needs_drive = pytest.mark.skipif(drive._native is None, reason="simd.core._drive is not built")
needs_pack = pytest.mark.skipif(odom_codec._native is None, reason="simd.wire._odompack is not built")
needs_noise = pytest.mark.skipif(sensor_model._native is None, reason="simd._scannoise is not built")
DT = 1.0 / 30.0


@dataclass
class Columns:
    """The robot table's drive columns (drive.DriveColumns), made up for a test."""

    last_cmd: npt.NDArray[np.int64]
    target_v: F64
    target_w: F64
    max_v: F64
    max_w: F64
    sep: F64
    acc: F64
    wheel_l: F64
    wheel_r: F64
    yaw: F64

    def copy(self) -> Columns:
        return Columns(**{f.name: getattr(self, f.name).copy() for f in fields(self)})


TICK, TIMEOUT = 200, 3.0


def drive_inputs(rng: np.random.Generator, n: int) -> Columns:
    """Targets that are stale, clamped, snapped, ramped; straight and turning robots."""
    last = rng.integers(0, 200, n).astype(np.int64)
    tv = rng.normal(0, 0.4, n)
    tw = rng.normal(0, 3.0, n)
    tw[: n // 8] = 0.0  # straight: the small-turn branch
    wl = rng.normal(0, 0.2, n)
    wr = wl + rng.normal(0, 0.005, n)  # within the snap tolerance
    wr[n // 2 :] = rng.normal(0, 0.2, n - n // 2)
    sep = rng.choice([0.16, 0.287], n)
    return Columns(last, tv, tw, np.full(n, 0.22), np.full(n, 2.84), sep, np.full(n, 1.0), wl, wr,
                   rng.uniform(-4, 4, n))  # fmt: skip


def advance(cols: Columns, use_native: bool) -> tuple[F64, F64, F64, F64]:
    return drive.advance(TICK, TIMEOUT, DT, cols, use_native=use_native)


@needs_drive
def test_compiled_drive_update_equals_numpy_bit_for_bit() -> None:
    rng = np.random.default_rng(7)
    for _ in range(20):
        ref = drive_inputs(rng, 257)
        fast = ref.copy()
        out_ref = advance(ref, use_native=False)
        out_fast = advance(fast, use_native=True)
        for a, b in zip(out_ref, out_fast, strict=True):
            assert np.array_equal(a, b)
        for name in ("target_v", "target_w", "wheel_l", "wheel_r"):  # zeroed by the watchdog, ramped in place
            assert np.array_equal(getattr(ref, name), getattr(fast, name))


@needs_drive
def test_compiled_twist_report_matches_numpy() -> None:
    rng = np.random.default_rng(8)
    n = 300
    v, w, dx, dy = advance(drive_inputs(rng, n), use_native=False)
    x0, y0, yaw0 = rng.normal(size=(3, n))
    x, y = x0 + dx, y0 + dy
    yaw = yaw0 + w * DT + 2 * np.pi * rng.integers(-1, 2, n)  # wrapped or not
    blocked = rng.random(n) < 0.3
    x[blocked] -= 0.5 * dx[blocked]  # pushed: the achieved motion is reported
    args = (DT, 1e-6, x0, y0, yaw0, x, y, yaw, v, w, dx, dy)
    ref = drive.report_twist(*args, use_native=False)
    fast = drive.report_twist(*args, use_native=True)
    for a, b in zip(ref, fast, strict=True):
        # libm's atan2/sin/cos against numpy's may differ in the last bit, nothing more
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)
    assert np.array_equal(ref[1] == 0.0, fast[1] == 0.0)  # the same robots count as moving freely


@needs_drive
@pytest.mark.parametrize(
    ("column", "bad", "error"),
    [
        ("target_v", np.zeros(3), ValueError),  # wrong length
        ("target_v", np.zeros(8, dtype=np.float32), TypeError),  # the targets too (the watchdog zeroes them)
        ("wheel_l", np.zeros(8, dtype=np.float32), TypeError),  # the wheels are written in place: float64 only
        ("wheel_l", np.zeros(16)[::2], TypeError),  # not contiguous
        ("wheel_r", np.zeros(8).tobytes(), TypeError),  # read-only where the wheels are written
    ],
)
def test_compiled_drive_rejects_bad_buffers(column: str, bad: object, error: type[Exception]) -> None:
    cols = drive_inputs(np.random.default_rng(1), 8)
    setattr(cols, column, bad)
    with pytest.raises(error):
        advance(cols, use_native=True)


@needs_drive
def test_a_fleet_drives_the_same_with_either_path() -> None:
    def run(use_native: bool) -> list[float]:
        sim = Simulation(load_world("empty"), SimConfig(noise=False, cmd_timeout=0))
        robots = [sim.spawn(SpawnRequest(name=f"r{i}", x=-2.0 + i, y=0.5 * i, model="burger")) for i in range(4)]
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(drive, "advance", functools.partial(drive.advance, use_native=use_native))
            mp.setattr(drive, "report_twist", functools.partial(drive.report_twist, use_native=use_native))
            for k, r in enumerate(robots):
                sim.command(r, 0.2, 0.5 * (k - 1.5))
            for _ in range(90):
                sim.step()
        return [v for r in robots for v in (sim.state(r).x, sim.state(r).y, sim.state(r).yaw)]

    np.testing.assert_allclose(run(True), run(False), rtol=0, atol=1e-9)


@needs_pack
def test_compiled_odometry_bytes_equal_numpy() -> None:
    rng = np.random.default_rng(2)
    fast, ref = OdometryEncoder(native=True), OdometryEncoder(native=False)
    names = [f"robot_{i}" for i in range(37)]
    for t in (0.0, 0.5, 1e6):
        cols = [rng.normal(size=len(names)) for _ in range(6)]
        cols[0][0] = np.inf  # any float64 passes through unchanged
        assert fast.encode(names, t, *cols) == ref.encode(names, t, *cols)
    out = fast.encode(names[:3], 2.0, *(np.arange(3.0) for _ in range(6)))
    assert msgspec.msgpack.decode(out[2], type=Odometry).pose.pose.position.x == 2.0


@needs_pack
def test_compiled_packer_checks_its_layout() -> None:
    pack = odom_codec._native.pack  # type: ignore[union-attr]
    tails = np.zeros(64, dtype=np.uint8)
    bounds = np.array([[0, 64]], dtype=np.int64)
    good = np.arange(7, dtype=np.int64) * 8
    values = np.zeros((1, 7))
    assert len(pack([b"h"], b"s", tails, bounds, good.reshape(1, 7), values)[0]) == 66
    with pytest.raises(ValueError, match="outside its tail"):
        pack([b"h"], b"s", tails, bounds, (good + 9).reshape(1, 7), values)
    with pytest.raises(ValueError, match="outside tails"):
        pack([b"h"], b"s", tails, np.array([[0, 65]], dtype=np.int64), good.reshape(1, 7), values)
    with pytest.raises(TypeError):
        pack([b"h"], b"s", tails, bounds, good.reshape(1, 7), values.astype(np.float32))
    with pytest.raises(TypeError):
        pack(["h"], b"s", tails, bounds, good.reshape(1, 7), values)
    with pytest.raises(ValueError, match="holds"):
        pack([b"h", b"i"], b"s", tails, bounds, good.reshape(1, 7), values)
    huge = good.reshape(1, 7).copy()
    huge[0, 0] = 2**63 - 4  # o + 8 would overflow int64: must be refused, not written
    with pytest.raises(ValueError, match="outside its tail"):
        pack([b"h"], b"s", tails, bounds, huge, values)
    no_rows = np.zeros((0, 7), dtype=np.int64)
    assert pack([], b"s", tails, np.zeros((0, 2), dtype=np.int64), no_rows, np.zeros((0, 7))) == []


def test_the_core_names_only_its_own_kernels_and_the_layers_above_register_theirs() -> None:
    """The core's registry names no module above the core (import-linter cannot read a module
    name in a string); the wire and navigation add theirs when imported."""
    code = (
        "import json; from simd.core import native; core = dict(native.KERNELS); import simd.wire, simd.nav; "
        "print(json.dumps([{k: v.module for k, v in core.items()}, {k: v.module for k, v in native.KERNELS.items()}]))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    core, everything = json.loads(done.stdout)
    assert core and all(module.startswith("simd.core.") for module in core.values()), core
    assert everything == {
        **core,
        "odompack": "simd.wire._odompack",
        "listpack": "simd.wire._listpack",
        "cellpaths": "simd.nav._cellpaths",
    }
    native.register("odompack", native.KERNELS["odompack"])  # the same again: no change
    with pytest.raises(ValueError, match=re.escape("'drive' is simd.core._drive already")):
        native.register("drive", native.Kernel("elsewhere._drive", "elsewhere/_drive.c"))


def test_the_switch_turns_the_compiled_paths_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(native.ENV, "numpy")
    module, why = native.load("drive")
    assert module is None and why is not None and "numpy" in why
    monkeypatch.setenv(native.ENV, "fast please")
    with pytest.raises(ValueError, match="FLEETSIM_NATIVE"):
        native.choice()
    monkeypatch.setenv(native.ENV, "native")
    with pytest.raises(ImportError, match="no compiled fast path"):
        native.load("no_such_module")


def paths_in_a_fresh_process(**env: str) -> dict[str, str]:
    """native.status() as a daemon started with this environment would report it."""
    clean = {k: v for k, v in os.environ.items() if k not in ("FLEETSIM_NATIVE", "FLEETSIM_LIDAR")}
    code = "import json, simd.wire, simd.nav; from simd.core import native; print(json.dumps(native.status()))"
    done = subprocess.run(
        [sys.executable, "-c", code], env={**clean, **env}, capture_output=True, text=True, check=True
    )
    result: dict[str, str] = json.loads(done.stdout)
    return result


@needs_drive
@needs_pack
def test_status_reports_the_path_each_loop_took() -> None:
    off = paths_in_a_fresh_process(FLEETSIM_NATIVE="numpy")
    assert all(v.startswith("numpy (FLEETSIM_NATIVE=numpy") for v in off.values()), off
    lidar_only = paths_in_a_fresh_process(FLEETSIM_LIDAR="numpy")
    assert lidar_only["raycast"].startswith("numpy") and lidar_only["drive"] == lidar_only["odompack"] == "native"
    if list_codec._native is not None:
        assert lidar_only["listpack"] == "native" and off["listpack"].startswith("numpy (FLEETSIM_NATIVE")
    if sensor_model._native is not None:
        assert lidar_only["scannoise"] == "native" and off["scannoise"].startswith("numpy (FLEETSIM_NATIVE")


@needs_drive
def test_compiled_paths_take_what_numpy_takes() -> None:
    """float32 positions or an int32 watchdog column work on either path (converted)."""
    cols = drive_inputs(np.random.default_rng(4), 16)
    ref = cols.copy()
    cols.last_cmd = cols.last_cmd.astype(np.int32)
    cols.yaw = cols.yaw.astype(np.float32)
    ref.yaw = ref.yaw.astype(np.float32).astype(np.float64)
    for a, b in zip(advance(cols, use_native=True), advance(ref, use_native=False), strict=True):
        assert np.array_equal(a, b)
    f32 = np.zeros(3, dtype=np.float32)
    out = drive.report_twist(DT, 1e-6, *([f32] * 10), use_native=True)  # type: ignore[arg-type]  # float32 on purpose
    assert all(np.array_equal(o, np.zeros(3)) for o in out)


@needs_drive
def test_compiled_twist_report_rejects_bad_outputs_and_handles_empty() -> None:
    z = np.zeros(4)
    with pytest.raises(TypeError):  # outputs must be writable
        drive._native.report(DT, 1e-6, *([z] * 10), z, z, z, z.tobytes())  # type: ignore[union-attr]
    with pytest.raises(ValueError):
        drive._native.report(DT, 1e-6, *([z] * 10), z, z, z, np.zeros(3))  # type: ignore[union-attr]
    empty = [np.zeros(0)] * 10
    assert all(len(o) == 0 for o in drive.report_twist(DT, 1e-6, *empty, use_native=True))
    none = drive_inputs(np.random.default_rng(0), 0)
    assert all(len(o) == 0 for o in advance(none, use_native=True))


@needs_drive
def test_compiled_clamp_propagates_nan_as_numpy_does() -> None:
    cols = drive_inputs(np.random.default_rng(5), 8)
    cols.max_v = np.full(8, np.nan)  # a NaN limit gives NaN speeds in numpy
    ref = cols.copy()
    fast = advance(cols, use_native=True)
    slow = advance(ref, use_native=False)
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_array_equal(a, b)


def raw_scans(rng: np.random.Generator, rows: int = 40) -> np.ndarray:
    """Ranges as the kernel returns them: hits, misses (inf), and the awkward values."""
    raw = rng.uniform(0.05, 4.0, (rows, 360)).astype(np.float32)
    raw[rng.random(raw.shape) < 0.3] = np.inf
    raw[0, :6] = [np.nan, 3.5, 0.12, 0.11999, 3.49999, -0.0]
    return raw


@needs_noise
def test_sensor_model_paths_mask_and_clamp_alike() -> None:
    spec = LidarSpec()
    raw = raw_scans(np.random.default_rng(8))
    rng = np.random.default_rng(0)
    quiet = [sensor_model.apply(raw, spec, 0.0, rng, use_native=p) for p in (True, False)]
    assert quiet[0].tobytes() == quiet[1].tobytes()  # no noise: the same to the bit
    noisy = [sensor_model.apply(raw, spec, 0.01, np.random.default_rng(3), use_native=p) for p in (True, False)]
    for out in noisy:
        assert np.array_equal(np.isinf(out), ~(raw < spec.range_max))  # +inf exactly where nothing hit
        hit = np.isfinite(out)
        assert out[hit].min() >= spec.range_min and out[hit].max() <= spec.range_max
        inner = hit & (raw > 0.2) & (raw < 3.3)  # away from the clamps: the noise itself
        err = (out[inner] - raw[inner]).astype(np.float64)
        assert abs(err.mean()) < 0.0005 and 0.0095 < err.std() < 0.0105
    assert not np.array_equal(noisy[0], noisy[1])  # different generators: documented


@needs_noise
def test_sensor_model_compiled_path_is_deterministic_and_leaves_its_input_alone() -> None:
    spec = LidarSpec()
    raw = raw_scans(np.random.default_rng(9))
    before = raw.copy()
    a = sensor_model.apply(raw, spec, 0.01, np.random.default_rng(5), use_native=True)
    b = sensor_model.apply(raw, spec, 0.01, np.random.default_rng(5), use_native=True)
    c = sensor_model.apply(raw, spec, 0.01, np.random.default_rng(6), use_native=True)
    assert a.tobytes() == b.tobytes() and a.tobytes() != c.tobytes()
    assert np.array_equal(raw, before, equal_nan=True)
    empty = sensor_model.apply(np.zeros((0, 360), dtype=np.float32), spec, 0.01, np.random.default_rng(1))
    assert empty.shape == (0, 360)
