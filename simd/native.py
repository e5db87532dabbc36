"""The compiled fast paths, and the one switch that turns them off.

Three hot loops of the tick have a C twin built with the package (when a C compiler is
there): the lidar kernel (``simd._raycast``), the diff-drive arithmetic (``simd._drive``) and
the odometry packer (``simd._odompack``). Each numpy version stays in the code as the
reference that tests compare the C one with, and as the fallback where nothing was compiled.

``FLEETSIM_NATIVE`` chooses: ``auto`` (default) uses what is built, ``numpy`` uses none of
it (to compare, or to rule the C code out when something looks wrong), ``native`` fails at
start-up if a module is missing (for benchmarks and the container image, which must not
silently fall back).
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType

ENV = "FLEETSIM_NATIVE"
MODULES = ("_raycast", "_drive", "_odompack")


def choice() -> str:
    value = os.environ.get(ENV, "auto").strip().lower() or "auto"
    if value not in ("auto", "native", "numpy"):
        raise ValueError(f"{ENV}={value!r}: expected 'auto', 'native' or 'numpy'")
    return value


def load(name: str) -> tuple[ModuleType | None, str]:
    """The compiled module ``simd.<name>``, or None and why it is not used."""
    wanted = choice()
    if wanted == "numpy":
        return None, f"{ENV}=numpy"
    try:
        return importlib.import_module(f"simd.{name}"), "built"
    except ImportError as exc:
        if wanted == "native":
            raise ImportError(f"{ENV}=native but simd.{name} is not built: {exc}") from exc
        return None, f"simd.{name} is not built ({exc})"


def status() -> dict[str, str]:
    """Which path each hot loop took, for the daemon's start-up line and the benchmark's
    report: name -> 'native', or 'numpy (why)'. Read from the modules' own choices, so that
    FLEETSIM_LIDAR (which overrides this switch for the lidar alone) is reported right."""
    from simd import drive, lidar, odom_codec

    def path(module: ModuleType | None, why: str | None) -> str:
        return "native" if module is not None else f"numpy ({why})"

    return {
        "raycast": "native" if lidar.KERNEL == "native" else f"numpy ({lidar.NATIVE_UNAVAILABLE})",
        "drive": path(drive._native, drive._why),
        "odompack": path(odom_codec._native, odom_codec._why),
    }
