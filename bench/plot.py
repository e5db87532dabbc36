"""The benchmark's picture, ``scaling.png``: the real-time factor and the delivered fraction
against the number of robots, from the recorded runs (``python -m bench.fleet_bench``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def plot(res: dict[str, Any], path: Path) -> bool:
    """RTF vs N (log-log, with the RTF = 1 line) and delivered fraction vs N (log x)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.ticker import FuncFormatter, NullFormatter
    except ImportError:
        return False
    runs = [r for r in res["runs"] if (r.get("measure") or {}).get("rtf") is not None]
    if not runs:
        return False
    paced = [r for r in runs if r["mode"] == "rtf1"]
    fast = [r for r in runs if r["mode"] == "rtf0"]
    fast_fleet = [r for r in runs if r["mode"] == "rtf0-fleet"]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    if paced:
        ns = [r["n"] for r in paced]
        mid = [r["measure"]["rtf"] for r in paced]
        lo = [max(0.0, v - (r["measure"]["rtf_min"] or v)) for v, r in zip(mid, paced, strict=True)]
        hi = [max(0.0, (r["measure"]["rtf_max"] or v) - v) for v, r in zip(mid, paced, strict=True)]
        ax1.errorbar(
            ns,
            mid,
            yerr=[lo, hi],
            fmt="o-",
            color="C0",
            ecolor="C0",
            capsize=3,
            label="--rtf 1: window mean, bars = slowest/fastest 1 s",
        )
        for x, y in zip(ns, mid, strict=True):
            ax1.annotate(f"{y:.2f}", (x, y), textcoords="offset points", xytext=(6, -12), fontsize=8, color="C0")
        odom = [r["measure"]["odom_fraction"] for r in paced]
        scan = [r["measure"]["scan_fraction"] for r in paced]
        ax2.plot(ns, odom, "o-", color="C0", label="odometry (30 Hz per robot)")
        ax2.plot(ns, scan, "s--", color="C1", label="scans (5 Hz per robot)")
        for x, y in zip(ns, odom, strict=True):
            ax2.annotate(f"{y:.3f}", (x, y), textcoords="offset points", xytext=(6, 6), fontsize=8, color="C0")
    groups = (
        (fast, "D", "C3", "full", "--rtf 0, subscriber on every robot's topics", "odometry at --rtf 0, per robot", 8),
        (
            fast_fleet,
            "s",
            "C4",
            "none",
            "--rtf 0, subscriber on the fleet topics",
            "odometry at --rtf 0 via P/odometry",
            -8,
        ),
    )
    for group, marker, color, fill, label, label2, dx in groups:
        if not group:
            continue
        for k, r in enumerate(group):
            first = k == 0  # one legend entry per kind of run
            v = r["measure"]["rtf"]
            ax1.plot([r["n"]], [v], marker, color=color, mfc=None if fill == "full" else "none",
                     label=f"{label}, N={r['n']}" if first else None)  # fmt: skip
            ax2.plot([r["n"]], [r["measure"]["odom_fraction"]], marker, color=color,
                     mfc=None if fill == "full" else "none", label=label2 if first else None)  # fmt: skip
        values = sorted(r["measure"]["rtf"] for r in group)
        mid = values[(len(values) - 1) // 2]
        text = f"{mid:.1f}" if len(values) == 1 else f"{mid:.1f} (median of {len(values)})"
        ax1.annotate(text, (group[0]["n"], mid), textcoords="offset points", xytext=(dx, 0), va="center",
                     ha="left" if dx > 0 else "right", color=color, fontsize=8)  # fmt: skip
    ax1.axhline(1.0, color="k", lw=1, ls=":", label="RTF = 1 (real time; target at N = 1000)")
    if fast or fast_fleet:
        ax1.axhline(20.0, color="C3", lw=1, ls=":", label="RTF = 20 (target at --rtf 0, N = 100)")
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    sizes = sorted({r["n"] for r in runs})
    for ax in (ax1, ax2):
        ax.set_xscale("log")
        ax.set_xticks(sizes)
        ax.xaxis.set_major_formatter(plain)
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlim(sizes[0] / 1.6, sizes[-1] * 1.8)
        ax.set_xlabel("robots (N)")
        ax.grid(True, which="major", alpha=0.3)
    ax1.set_yscale("log")
    highest = max((v for r in runs for v in [((r.get("measure") or {}).get("rtf_max"))] if v), default=50.0)
    top = max(80.0, highest * 1.6)  # room above the fastest run (--rtf 0 reaches past 100)
    ax1.set_ylim(0.1, top)
    ax1.set_yticks([t for t in (0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100, 200, 500, 1000) if t <= top])
    ax1.yaxis.set_major_formatter(plain)
    ax1.yaxis.set_minor_formatter(NullFormatter())
    ax1.set_ylabel("real-time factor (sim s / wall s)")
    ax1.set_title("Achieved real-time factor")
    ax1.legend(fontsize=8, loc="lower left")
    ax2.axhline(1.0, color="k", lw=1, ls=":")
    ax2.axhline(0.99, color="C2", lw=1, ls=":", label="0.99 (counted as all delivered)")
    fractions = [v for r in runs for v in (r["measure"]["odom_fraction"], r["measure"]["scan_fraction"]) if v]
    ax2.set_ylim(max(0.0, min([0.9, *fractions]) - 0.05), 1.04)
    ax2.set_ylabel("delivered / expected (30·N·RTF, 5·N·RTF per s)")
    ax2.set_title("Messages received by a separate subscriber process")
    ax2.legend(fontsize=8, loc="lower left")
    m = res["machine"]
    load = m.get("loadavg_at_start") or [float("nan")]
    fig.suptitle(
        f"fleetsim scaling, {res['started'][:10]}: {m['cpu']}, {m['cores']} cores (load {load[0]:.1f} at start), "
        f"Python {m['python']}, zenoh {m['zenoh']}, commit {m['commit'] or '?'}",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
