"""Summary statistics and the short number formats of the progress lines and the tables.

One place for them so that the console, ``results.md`` and the measurement records round and
mark missing values ("–") the same way.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence


def percentile(values: Sequence[float], p: float) -> float | None:
    """Nearest-rank percentile (p in 0..100); None for no values."""
    if not values:
        return None
    s = sorted(values)
    k = max(0, min(len(s) - 1, math.ceil(p / 100.0 * len(s)) - 1))
    return s[k]


def median(values: Sequence[float]) -> float | None:
    return statistics.median(values) if values else None


def fmt_rate(x: float | None) -> str:
    if x is None:
        return "–"
    if x >= 10_000:
        return f"{x / 1000:.0f}k"
    if x >= 1000:
        return f"{x / 1000:.1f}k"
    return f"{x:.0f}"


def fmt_ms(x: object) -> str:
    """Seconds as milliseconds; anything that is not a number (a missing value) as a dash."""
    if not isinstance(x, int | float):
        return "–"
    return f"{x * 1000:.1f}" if x < 0.1 else f"{x * 1000:.0f}"


def fmt_pct(x: float | None) -> str:
    return "–" if x is None else f"{x:.0f}%"


def fmt_f(x: float | None, digits: int = 2) -> str:
    return "–" if x is None else f"{x:.{digits}f}"
