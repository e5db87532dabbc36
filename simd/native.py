"""The compiled fast paths, and the one switch that turns them off.

Four hot loops of the tick have a C twin built with the package (when a C compiler is
there): the lidar kernel (``simd._raycast``), the lidar's noise and masking
(``simd._scannoise``), the diff-drive arithmetic (``simd._drive``) and the odometry packer
(``simd._odompack``). Each numpy version stays in the code as the
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


def choice(override: str | None = None) -> tuple[str, str]:
    """("auto" | "native" | "numpy", the variable that says so): ``override`` (a variable for
    one loop, e.g. FLEETSIM_LIDAR) when it is set, else FLEETSIM_NATIVE, else auto."""
    for var in (override, ENV) if override else (ENV,):
        value = os.environ.get(var, "").strip().lower()
        if value not in ("", "auto", "native", "numpy"):
            raise ValueError(f"{var}={value!r}: expected 'auto', 'native' or 'numpy'")
        if value:
            return value, var
    return "auto", ""


def load(name: str, override: str | None = None) -> tuple[ModuleType | None, str | None]:
    """The compiled module ``simd.<name>`` and None, or None and why it is not used."""
    wanted, var = choice(override)
    if wanted == "numpy":
        return None, f"{var}=numpy"
    try:
        return importlib.import_module(f"simd.{name}"), None
    except ImportError as exc:
        if wanted == "native":
            raise ImportError(f"{var}=native but simd.{name} is not built: {exc}") from exc
        return None, f"simd.{name} is not built ({exc})"


def status() -> dict[str, str]:
    """Which path each hot loop took, for the daemon's start-up line and the benchmark's
    report: name -> 'native', or 'numpy (why)'. Read from the modules' own choices, so that
    FLEETSIM_LIDAR (which overrides this switch for the lidar alone) is reported right."""
    from simd import drive, lidar, odom_codec, sensor_model

    def path(module: ModuleType | None, why: str | None) -> str:
        return "native" if module is not None else f"numpy ({why})"

    return {
        "raycast": "native" if lidar.KERNEL == "native" else f"numpy ({lidar.NATIVE_UNAVAILABLE})",
        "scannoise": path(sensor_model._native, sensor_model._why),
        "drive": path(drive._native, drive._why),
        "odompack": path(odom_codec._native, odom_codec._why),
    }
