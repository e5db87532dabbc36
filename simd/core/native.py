"""The compiled fast paths: one registry of them, and the one switch that turns them off.

Six hot loops have a C twin built with the package (when a C compiler is there): the lidar
kernel, the lidar's noise and masking, the diff-drive arithmetic, the odometry packer, the robot
list's packer, and navigation's distance fields on the cell graph (Dijkstra).
Each numpy version stays in the code as the reference that tests compare the C one with, and
as the fallback where nothing was compiled. ``KERNELS`` lists them: every module that has a
twin asks for it here by its label (``load("drive")``), and ``status()`` reports the same
choices without importing those modules, so nothing here depends on them. The core's own
kernels are listed here; a layer above the core registers its own when it is imported
(``simd.wire`` the two packers, ``simd.nav`` the distance fields: their ``__init__``), so
the core never names a module above it.

``FLEETSIM_NATIVE`` chooses: ``auto`` (default) uses what is built, ``numpy`` uses none of
it (to compare, or to rule the C code out when something looks wrong), ``native`` fails at
start-up if a module is missing (for benchmarks and the container image, which must not
silently fall back). A kernel may have a variable of its own that overrides it
(``FLEETSIM_LIDAR`` for the lidar kernel).
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from types import ModuleType

ENV = "FLEETSIM_NATIVE"


@dataclass(frozen=True)
class Kernel:
    """One compiled fast path: where its module lives and what may override the switch."""

    module: str
    source: str
    override: str | None = None


#: label -> the compiled module (built from ``source``, see pyproject.toml's ext-modules): the
#: core's, and those the layers above have registered
KERNELS: dict[str, Kernel] = {
    "raycast": Kernel("simd.core.lidar._raycast", "simd/core/lidar/_raycast.c", override="FLEETSIM_LIDAR"),
    "scannoise": Kernel("simd.core._scannoise", "simd/core/_scannoise.c"),
    "drive": Kernel("simd.core._drive", "simd/core/_drive.c"),
}

CORE_KERNELS = len(KERNELS)


def register(label: str, kernel: Kernel) -> None:
    """Add a layer's compiled fast path under ``label`` (once; the same again is no change)."""
    known = KERNELS.setdefault(label, kernel)
    if known != kernel:
        raise ValueError(f"the compiled fast path {label!r} is {known.module} already, not {kernel.module}")


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


def load(label: str) -> tuple[ModuleType | None, str | None]:
    """The compiled module of ``label`` (a key of ``KERNELS``) and None, or None and why it is
    not used. ImportError when the switch says ``native`` and it is not built."""
    kernel = KERNELS.get(label)
    if kernel is None:
        raise ImportError(f"no compiled fast path is called {label!r}: choose one of {', '.join(KERNELS)}")
    wanted, var = choice(kernel.override)
    if wanted == "numpy":
        return None, f"{var}=numpy"
    try:
        return importlib.import_module(kernel.module), None
    except ImportError as exc:
        if wanted == "native":
            raise ImportError(f"{var}=native but {kernel.module} is not built: {exc}") from exc
        return None, f"{kernel.module} is not built ({exc})"


def status() -> dict[str, str]:
    """Which path each hot loop takes in this environment, for the daemon's start-up line and
    the benchmark's report: label -> 'native', or 'numpy (why)'."""
    out: dict[str, str] = {}
    core = list(KERNELS)[:CORE_KERNELS]  # the core's own first, then those registered, by name (the
    for label in core + sorted(set(KERNELS) - set(core)):  # order of imports decides nothing)
        module, why = load(label)
        out[label] = "native" if module is not None else f"numpy ({why})"
    return out
