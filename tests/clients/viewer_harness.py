"""fleet-view as the viewer tests run it: a real process on a free port, talking to a real
daemon (fixtures in tests/clients/conftest.py)."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

import numpy as np
from PIL import Image

from tests.conftest import ROOT, Daemon, stop_process


@dataclass
class Viewer:
    proc: subprocess.Popen[str]
    url: str

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 5.0) -> tuple[int, float]:
        t0 = time.monotonic()
        status = stop_process(self.proc, sig, timeout)
        if self.proc.stdout:
            self.proc.stdout.close()
        return status, time.monotonic() - t0


def fleet_view(daemon: Daemon, *args: str) -> list[str]:
    return [sys.executable, "-m", "clients.viewer.app", "-e", daemon.endpoint, "--prefix", daemon.prefix, *args]


def start_viewer(daemon: Daemon, *args: str) -> Viewer:
    """``fleet-view --port 0`` against ``daemon``, once it printed its address."""
    proc = subprocess.Popen(
        fleet_view(daemon, "--port", "0", *args),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    line = proc.stdout.readline() if sel.select(timeout=15) else ""
    sel.close()
    if "http://" not in line:
        proc.kill()
        raise RuntimeError(f"fleet-view did not start: {line}{proc.communicate()[0]}")
    return Viewer(proc, line.split()[1])


def colour_count(
    img: Image.Image, centre: tuple[float, float], half: float, rgb: tuple[int, ...], within: int = 8
) -> int:
    """Pixels within ``half`` px of ``centre`` that are ``rgb`` (within ``within`` per channel:
    a thin line resampled down comes out a little off its colour)."""
    a = np.asarray(img.convert("RGB"), dtype=np.int16)
    x0, y0 = max(0, round(centre[0] - half)), max(0, round(centre[1] - half))
    box = a[y0 : round(centre[1] + half) + 1, x0 : round(centre[0] + half) + 1]
    return int(np.sum(np.all(np.abs(box - np.asarray(rgb[:3])) <= within, axis=-1)))
