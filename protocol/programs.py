"""How to name fleetsim's own programs in a hint so that it runs as printed.

A hint like ``drive it: fleet-teleop tb3_0`` only helps if ``fleet-teleop`` is on ``PATH``,
which it is not when fleetsim lives in a virtual environment nobody activated (``./demo``
sets one up). Then the hint names the script beside the running Python instead.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path


def runnable(program: str) -> str:
    """``program`` when it is on ``PATH``; else the script of that name beside this Python,
    relative to the current directory when it is under it (``.venv/bin/fleet-teleop``)."""
    if shutil.which(program):
        return program
    beside = Path(sys.executable).parent / program
    if not beside.exists():
        return program
    try:
        return str(beside.absolute().relative_to(Path.cwd()))
    except ValueError:
        return str(beside.absolute())
