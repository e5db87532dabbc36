"""Draw docs/img/architecture.png: the layers of simd and the path of one tick.

    .venv/bin/python scripts/draw_architecture.py        # needs matplotlib (the bench extra)

The picture is derived from nothing at run time: when the layers or the threads change, change
the boxes here and run it again (docs/architecture.md explains each box).
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

OUT = Path(__file__).resolve().parents[1] / "docs" / "img" / "architecture.png"

LAYER = "#eef3fb"
CORE = "#e6f4ea"
WIRE = "#fdf3e1"
ADAPTER = "#fbe9ec"
CLIENT = "#f1f1f1"
THREAD = "#ffffff"


def box(ax: plt.Axes, x: float, y: float, w: float, h: float, title: str, body: str = "", color: str = THREAD,
        size: float = 9.0) -> None:  # fmt: skip
    ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.02,rounding_size=0.08", fc=color, ec="#555"))
    ax.text(x + 0.1, y + h - 0.12, title, ha="left", va="top", fontsize=size, weight="bold")
    if body:
        ax.text(x + 0.1, y + h - 0.42, body, ha="left", va="top", fontsize=size - 1.5, linespacing=1.35)


def arrow(ax: plt.Axes, a: tuple[float, float], b: tuple[float, float], label: str = "", color: str = "#333",
          style: str = "-|>", rad: float = 0.0, dy: float = 0.1) -> None:  # fmt: skip
    ax.add_patch(FancyArrowPatch(a, b, arrowstyle=style, mutation_scale=12, color=color, lw=1.2,
                                 connectionstyle=f"arc3,rad={rad}"))  # fmt: skip
    if label:
        ax.text((a[0] + b[0]) / 2, (a[1] + b[1]) / 2 + dy, label, ha="center", va="bottom", fontsize=7.2,
                color=color)  # fmt: skip


def layers(ax: plt.Axes) -> None:
    ax.set_title("Layers (enforced by lint-imports in ./test): each imports only what is below it", fontsize=11)
    box(ax, 0.2, 7.6, 9.6, 1.0, "entry points   simd.cli · simd.daemon · simd.container_entry · simd.healthcheck",
        "check the flags (cli), open the sessions and wire an engine to its adapters, torn down in one place (daemon)",
        LAYER)
    box(ax, 0.2, 5.9, 9.6, 1.4, "simd.adapters   (independent of each other)",
        "fleet/  the fleet protocol over zenoh: requests decoded at the edge, cmd_vel intake,\n"
        "        publisher (per-robot topics, fleet topics, clock, JSON mirrors, latest-message gets)\n"
        "ros2/   ROS 2 over rmw_zenoh: topics, /tf, liveliness graph, Gazebo's and the standard services", ADAPTER)
    box(ax, 0.2, 3.7, 4.7, 1.9, "simd.engine", "engine.py  the loop: pacing, typed requests\n"
        "stepping   lockstep steps in slices · status: answers\n  without the loop · local: requests on the "
        "caller's thread\nports.py   the seam: Adapter, events, results", LAYER)
    box(ax, 5.1, 3.7, 4.7, 1.9, "simd.wire", "convert     core values -> protocol messages\nodom_codec  "
        "byte templates (+ _odompack.c)\nscan_codec  byte templates\nfleet_codec one message a tick\n"
        "list_codec  the robot list (+ _listpack.c)",
        WIRE)
    box(ax, 0.2, 1.0, 9.6, 2.4, "simd.core   (no zenoh, no wire, no adapters)",
        "sim.py       Simulation: spawn rules, commands, the tick, reset\nrobots.py    the robot table: "
        "one row a robot, columns declared once\nsnapshot.py  TickSnapshot (immutable), RobotState\n"
        "physics.py (pymunk) · drive.py (+ _drive.c) · lidar (+ _raycast.c) · sensor_model.py (+ _scannoise.c)\n"
        "models.py · worldfile.py · native.py (the core's compiled kernels; the layers above register theirs)\n\n"
        "simd.nav (above the core, below the engine): navigator, costmap, cells, traffic, floor, follow", CORE)
    box(ax, 0.2, -0.5, 4.7, 1.2, "protocol/ · fleetcommon/  (below everything)", "protocol: the wire (messages, "
        "keys, errors, codec)\nfleetcommon: zenoh flags, map files, array types", CLIENT)
    box(ax, 5.1, -0.5, 4.7, 1.2, "clients/  (protocol only, never simd)", "FleetClient, fleet CLI, teleop, viewer,\n"
        "fleet-record, fleet-map: separate processes", CLIENT)
    ax.set_xlim(0, 10)
    ax.set_ylim(-0.7, 8.8)


def tick(ax: plt.Axes) -> None:
    ax.set_title("One tick: three threads of simd overlap (both cores at work)", fontsize=11)
    box(ax, 0.2, 6.3, 3.0, 2.2, "simulation thread", "take commands (adapters)\ndrive.advance\n"
        "physics.step  (pymunk,\n  GIL released)\nsnapshot -> adapters", CORE)
    box(ax, 3.6, 6.3, 2.8, 2.2, "lidar thread", "cast (_raycast.c)\nnoise (_scannoise.c)\n"
        "both release the GIL;\njobs in tick order:\nbit-identical scans", CORE)
    box(ax, 6.8, 6.3, 3.0, 2.2, "fleet adapter thread", "encode + put, in order:\n"
        "per-robot topics (only if\n  someone subscribes)\nfleet topics, clock,\nreplies, spawn/delete", ADAPTER)
    box(ax, 0.2, 3.3, 3.0, 2.1, "zenoh threads", "queries -> decoded request\n"
        "  -> engine.submit\ncmd_vel -> ring channel\n  (drained each tick)", LAYER)
    box(ax, 3.6, 3.3, 6.2, 2.1, "TickSnapshot k", "tick, time, namespaces, x, y, yaw,\n"
        "linear_x, linear_y, angular_z (arrays never written again)\nscan_namespaces, scans: a future "
        "the lidar fills", WIRE)
    box(ax, 0.2, 0.4, 9.6, 2.3, "timeline", "", THREAD)
    for name, y in (("sim", 1.95), ("lidar", 1.35), ("adapter", 0.75)):
        ax.text(0.35, y + 0.12, name, fontsize=7.5, va="center")
    for k in range(3):  # tick k+1's physics runs while tick k's scans are cast and its messages sent
        x0 = 1.3 + k * 2.2
        spans = [(x0, 1.95, 2.0, CORE, f"physics {k}"), (x0 + 2.0, 1.35, 1.5, CORE, f"scans {k}"),
                 (x0 + 2.05, 0.75, 1.7, ADAPTER, f"encode + put {k}")]  # fmt: skip
        for x, y, w, color, text in spans:
            ax.add_patch(FancyBboxPatch((x, y), w, 0.28, boxstyle="round,pad=0.01", fc=color, ec="#555"))
            ax.text(x + w / 2, y + 0.14, text, fontsize=7, ha="center", va="center")
    arrow(ax, (3.2, 7.2), (3.6, 7.2))
    arrow(ax, (1.7, 6.3), (4.5, 5.4), "hands out", rad=0.0, dy=-0.35)
    arrow(ax, (5.0, 6.3), (6.6, 5.4), "fills scans", dy=0.05)
    arrow(ax, (8.3, 5.4), (8.3, 6.3), "reads")
    arrow(ax, (1.7, 5.4), (1.7, 6.3), "requests,\ncommands", dy=-0.2)
    ax.set_xlim(0, 10)
    ax.set_ylim(0.2, 8.8)


def main() -> int:
    fig, (a, b) = plt.subplots(1, 2, figsize=(16, 7.6))
    for ax in (a, b):
        ax.axis("off")
    layers(a)
    tick(b)
    fig.tight_layout()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=110)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
