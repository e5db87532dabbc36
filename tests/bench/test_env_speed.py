"""bench.env_speed: fleetsim's steps a second are measured and printed even without ir-sim, whose
absence is one clear line; the ir-sim world is fleetsim's world, obstacle for obstacle."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bench.env_speed import STEP_S, irsim_available, irsim_world
from simd.core.worldfile import load_world

ROOT = Path(__file__).resolve().parents[2]


def test_without_irsim_it_says_so_and_still_measures_fleetsim(tmp_path: Path) -> None:
    missing = tmp_path / "no-venv" / "bin" / "python"
    proc = subprocess.run(
        [sys.executable, "-m", "bench.env_speed", "--seconds", "0.5", "--runs", "1", "--irsim-python", str(missing)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    out = proc.stdout
    assert proc.returncode == 0, out[-3000:] + proc.stderr[-3000:]
    not_available = [line for line in out.splitlines() if line.startswith("ir-sim: not available")]
    assert len(not_available) == 1, out
    assert str(missing) in not_available[0] and "pip install ir-sim" in not_available[0]
    m = re.search(r"^run 1/1 fleetsim: (\d+) steps/s \((\d+) steps in ([\d.]+) s", out, re.MULTILINE)
    assert m, out
    rate, steps, seconds = int(m.group(1)), int(m.group(2)), float(m.group(3))
    assert rate > 0 and steps > 0 and seconds >= 0.5
    assert rate == pytest.approx(steps / seconds, rel=0.02), out  # the seconds are printed rounded
    summary = re.search(r"^fleetsim: (\d+) steps/s \(median\), (\d+) sim seconds a wall second", out, re.MULTILINE)
    assert summary and int(summary.group(1)) == rate, out
    assert abs(int(summary.group(2)) - rate * STEP_S) <= 1
    assert re.search(r"^run 1/1 fleetsim, 2 envs async: [1-9]\d* steps/s", out, re.MULTILINE), out
    assert "ratio of the medians" not in out  # nothing to compare with
    assert out.startswith("machine: ") and "\ncommit: " in out and "\ncommand: python -m bench.env_speed" in out


def test_an_interpreter_without_irsim_is_named_with_the_import_error() -> None:
    if importlib.util.find_spec("irsim") is not None:
        pytest.skip("irsim is importable here")
    ok, why = irsim_available(sys.executable)
    assert not ok
    assert sys.executable in why and "irsim" in why


def test_the_irsim_world_is_fleetsims_world() -> None:
    cfg = irsim_world()
    world = load_world("turtlebot3_world")
    polygons = [o for o in cfg["obstacle"] if o["shape"]["name"] == "polygon"]
    circles = [o for o in cfg["obstacle"] if o["shape"]["name"] == "circle"]
    assert len(polygons) == len(world.polygons) == 11 and len(circles) == len(world.circles) == 9
    assert all(o["kinematics"] == {"name": "static"} for o in cfg["obstacle"])
    assert polygons[0]["shape"]["vertices"] == world.polygons[0].tolist()
    assert sorted((*o["state"][:2], o["shape"]["radius"]) for o in circles) == sorted(
        tuple(map(float, c)) for c in world.circles
    )
    x0, x1, y0, _ = world.bounds
    assert cfg["world"]["offset"] == [x0, y0] and cfg["world"]["width"] == pytest.approx(x1 - x0)
    assert cfg["world"]["step_time"] == STEP_S == 0.2
    (robot,) = cfg["robot"]
    (lidar,) = robot["sensors"]
    assert robot["kinematics"] == {"name": "diff"} and robot["shape"] == {"name": "circle", "radius": 0.105}
    assert robot["vel_max"] == [0.22, 2.84] and robot["vel_min"] == [-0.22, -2.84]
    assert (lidar["number"], lidar["range_min"], lidar["range_max"]) == (360, 0.12, 3.5)
    assert lidar["angle_range"] == pytest.approx(6.28) and lidar["noise"] and lidar["std"] == 0.01
