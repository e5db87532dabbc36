"""Fleet-scale benchmark of ``simd`` against the targets of issue 5.

For each fleet size N it generates an arena, starts ``simd`` and a separate subscriber process,
spawns N burgers over Zenoh, drives all of them (a wander at 10 Hz from this process), and
measures for ``--duration`` seconds: the achieved real-time factor, the odometry and scans
delivered to the subscriber against the count the daemon should have sent, the daemon's CPU and
memory, spawn latency, and the cmd_vel → odometry latency. Three more runs at ``--rtf 0``
measure how fast the daemon can go (judged on the median one: the machine's speed swings between
runs). Every number is a ratio against a baseline printed beside it.

    python -m bench.fleet_bench                              # sizes 1 10 100 1000 2000
    python -m bench.fleet_bench --sizes 1 10 100 --duration 5
    python -m bench.fleet_bench --quick --sizes 1 10         # smoke run, ~30 s

Writes ``bench-out/results.md``, ``bench-out/results.json`` and ``bench-out/scaling.png``
(``--out`` to choose). Run from the repository root. See docs/benchmark.md.

This module is the command line and the order of the runs; the pieces are beside it:
``arena`` (the generated world), ``processes`` and ``subscriber`` (the child processes),
``client`` (the benchmark's zenoh session), ``driver`` (the wander), ``measure`` (what one size
measures) and ``report`` (the tables, the JSON and the plot).
"""

from __future__ import annotations

import argparse
import contextlib
import shlex
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.arena import PROBE, SPACING, make_arena, write_world
from bench.client import Fleet, spawn_request
from bench.driver import DRIVE_HZ, Driver
from bench.measure import (
    Context,
    Settings,
    measure_latency,
    measure_window,
    proc_status_kb,
    settle,
    spawn_fleet,
    spawn_single,
)
from bench.numbers import fmt_f, fmt_ms, fmt_pct
from bench.processes import DaemonProc, free_port, raise_exit, start_daemon
from bench.progress import Progress
from bench.report import TOPIC_LABELS, machine_info, machine_line, results_markdown, write_outputs
from bench.subscriber import Subscriber, subscriber_main
from bench.wire import PREFIX


def run_size(
    n: int,
    rtf: float,
    s: Settings,
    tmp: Path,
    progress: Progress,
    sink: list[dict[str, Any]],
    topics: str = "robots",
) -> dict[str, Any]:
    """One fleet size, start to finish. The run's record is appended to ``sink`` first, so that
    whatever was measured before a failure or a Ctrl-C is reported. ``topics`` is what the
    subscriber process follows: every robot's own topics, or the fleet topics."""
    mode = ("rtf0" if rtf == 0 else "rtf1") + ("" if topics == "robots" else f"-{topics}")
    label = f"[N={n}{' rtf 0' if rtf == 0 else ''}{TOPIC_LABELS[topics].replace(',', '')}]"
    run: dict[str, Any] = {
        "n": n, "mode": mode, "target_rtf": rtf, "topics": topics, "status": "ok", "error": None,
    }  # fmt: skip
    sink.append(run)
    t_run = time.monotonic()
    with contextlib.ExitStack() as stack:
        daemon: DaemonProc | None = None
        try:
            progress.update(f"{label} world", force=True)
            arena = make_arena(n, s.seed)
            world_path = tmp / f"arena_{n}.yaml"
            write_world(arena, world_path)
            run["world"] = {
                "bounds_m": [arena.world["bounds"]["x_max"], arena.world["bounds"]["y_max"]],
                "obstacles": len(arena.world["obstacles"]),
                "spacing_m": SPACING,
            }
            # at 20x, 10 Hz commands are 2 s of sim time apart: keep the last command (no watchdog)
            extra = (["--cmd-timeout", "0"] if rtf == 0 else []) + s.simd_args
            ros_endpoint = f"tcp/127.0.0.1:{free_port()}"
            if topics in ("ros", "fleet-ros2"):  # the daemon serves ROS 2 as its own router
                extra += ["--ros2", "--ros-serve-router", "--ros-router", ros_endpoint]
            daemon = start_daemon(world_path, rtf, n + s.extra_spawns + 16, tmp, extra)
            stack.callback(daemon.stop)
            sub_endpoint = ros_endpoint if topics == "ros" else daemon.endpoint
            sub_topics = "fleet" if topics == "fleet-ros2" else topics
            sub = Subscriber(sub_endpoint, PROBE, tmp / f"subscriber-{n}-{mode}.log", sub_topics)
            stack.callback(sub.stop)
            progress.update(f"{label} starting simd and the subscriber", force=True)
            t0 = time.monotonic()
            fleet = _connect(daemon, 30.0)
            stack.callback(fleet.close)
            ctx = Context(n, label, daemon, sub, fleet)
            _wait_daemon(ctx, 30.0)
            sub.wait_ready(30.0)
            run["startup_s"] = time.monotonic() - t0
            time.sleep(0.3)
            rss_empty = proc_status_kb(daemon.pid, "VmRSS")
            run["spawn"] = spawn_fleet(ctx, arena, s, progress)
            spawned = run["spawn"]["spawned"]
            if spawned < n:
                run["status"] = "partial" if spawned else "failed"
                run["error"] = f"spawned {spawned}/{n}: {run['spawn']['first_error']}"
                if not spawned:
                    return run
            probe_ok, probe_err, _ = fleet.query(
                f"{PREFIX}/spawn", spawn_request(PROBE, *arena.probe, 0.0), timeout=10.0
            )
            driver = Driver(fleet, ctx.names, s.seed)
            driver.start()
            stack.callback(driver.stop)
            settle(ctx, s.settle, progress)
            run["measure"] = measure_window(ctx, s.duration, progress)
            # a fleet the driver's commands never reached costs the daemon less than a driven one
            run["moving"] = fleet.moving(30.0)
            rss = proc_status_kb(daemon.pid, "VmRSS")
            live = spawned + (1 if probe_ok else 0)
            run["memory"] = {
                "rss_empty_mb": (rss_empty or 0) / 1024,
                "rss_mb": (rss or 0) / 1024,
                "peak_rss_mb": (proc_status_kb(daemon.pid, "VmHWM") or 0) / 1024,
                "robots_live": live,
                "mb_per_robot": ((rss or 0) - (rss_empty or 0)) / 1024 / live if live else None,
            }
            if rtf > 0:
                if probe_ok:
                    run["latency"] = measure_latency(ctx, s.latency_reps, progress)
                else:
                    run["latency"] = {"error": f"probe spawn refused: {probe_err}"}
                run["spawn_single"] = spawn_single(ctx, arena, s.extra_spawns, progress)
            run["driver"] = driver.stats()
            if not daemon.alive():
                raise RuntimeError("simd died during the run")
        except Exception as e:
            run["status"] = "failed"
            tail = daemon.log_tail() if daemon is not None else ""
            run["error"] = f"{type(e).__name__}: {_short(e)}" + (f"\n--- simd log tail ---\n{tail}" if tail else "")
            progress.note(f"{label} FAILED: {type(e).__name__}: {_short(e)}")
        except BaseException:
            run["status"] = "interrupted"
            raise
        finally:
            run["elapsed_s"] = time.monotonic() - t_run
            progress.update(f"{label} stopping", force=True)
    progress.done(_summary_line(run, label))
    return run


def _summary_line(run: dict[str, Any], label: str) -> str:
    m = run.get("measure") or {}
    lat = run.get("latency") or {}
    return (
        f"{label} {run['status']}: rtf {fmt_f(m.get('rtf_median'))}, odom {fmt_f(m.get('odom_fraction'), 3)}, "
        f"scan {fmt_f(m.get('scan_fraction'), 3)} delivered, daemon cpu {fmt_pct(m.get('daemon_cpu_pct'))}, "
        f"spawn total {fmt_f((run.get('spawn') or {}).get('total_s'))} s, "
        f"{run.get('moving', '?')}/{run['n']} moving, "
        f"cmd→odom p50 {fmt_ms(lat.get('p50_s'))} ms ({run.get('elapsed_s', 0):.0f} s)"
    )


def _short(e: BaseException) -> str:
    """zenoh errors end with ' at <path of a Rust source file>:NN'; keep the message."""
    msg = str(e).strip()
    cut = msg.rfind(" at ")
    return msg[:cut] if cut > 0 and ".rs:" in msg[cut:] else msg


def _connect(daemon: DaemonProc, timeout: float) -> Fleet:
    """The benchmark's session, as soon as the daemon listens; fails fast if it exits."""
    deadline = time.monotonic() + timeout
    while True:
        if not daemon.alive():
            raise RuntimeError(f"simd exited with {daemon.proc.returncode}: {daemon.log_tail(1)}")
        try:
            return Fleet(daemon.endpoint, connect_timeout=1.0)
        except Exception as e:
            if time.monotonic() > deadline:
                raise RuntimeError(f"cannot connect to simd within {timeout:g} s: {_short(e)}") from None
            time.sleep(0.1)


def _wait_daemon(ctx: Context, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while True:
        if not ctx.daemon.alive():
            raise RuntimeError(f"simd exited with {ctx.daemon.proc.returncode}:\n{ctx.daemon.log_tail()}")
        try:
            ctx.fleet.clock(timeout=2.0)
            return
        except RuntimeError:
            if time.monotonic() > deadline:
                raise RuntimeError(f"simd did not answer within {timeout:g} s") from None
            time.sleep(0.1)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m bench.fleet_bench",
        description="Fleet-scale benchmark of simd (issue 5): RTF, delivered messages, CPU, memory, latencies.",
    )
    p.add_argument(
        "--sizes", type=int, nargs="+", default=[1, 10, 100, 1000, 2000], help="fleet sizes N (default: %(default)s)"
    )
    p.add_argument("--duration", type=float, default=None, help="seconds measured per size (default 10; quick 3)")
    p.add_argument(
        "--settle", type=float, default=None, help="seconds of driving before measuring (default 3; quick 1)"
    )
    p.add_argument("--quick", action="store_true", help="a short smoke run: shorter windows, fewer repetitions")
    p.add_argument("--fast-size", type=int, default=100, help="N of the --rtf 0 run (default 100; quick: ≤ max size)")
    p.add_argument("--no-fast", action="store_true", help="skip the --rtf 0 run")
    p.add_argument(
        "--fast-runs",
        type=int,
        default=None,
        help="--rtf 0 runs, judged on the median one: the machine's speed swings between runs (default 3; quick 1)",
    )
    p.add_argument(
        "--fast-topics",
        nargs="+",
        choices=("robots", "fleet"),
        default=["robots", "fleet"],
        help="what the subscriber follows in the --rtf 0 runs, each kind run --fast-runs times: every robot's own "
        "topics, or the fleet topics P/odometry and P/scans (default: both)",
    )
    p.add_argument(
        "--paced-topics",
        nargs="+",
        choices=tuple(TOPIC_LABELS),
        default=["robots"],
        help="what the subscriber follows in the real-time runs of --sizes, each size run once per kind, "
        "interleaved: robots (every robot's fleet topics), fleet (the fleet topics), ros (simd --ros2; every "
        "robot's ROS odom and scan, and /tf), fleet-ros2 (the fleet topics of a daemon with --ros2 that no ROS "
        "tool reads) (default: robots)",
    )
    p.add_argument("--spawn-concurrency", type=int, default=16, help="spawn requests in flight (default 16)")
    p.add_argument("--latency-reps", type=int, default=None, help="cmd_vel→odom repetitions (default 20; quick 5)")
    p.add_argument("--extra-spawns", type=int, default=None, help="one-at-a-time spawn/deletes (default 500; quick 10)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", default="bench-out", help="output directory (default: %(default)s)")
    p.add_argument("--no-plot", action="store_true", help="do not draw scaling.png")
    p.add_argument(
        "--simd-args",
        default="",
        metavar="ARGS",
        help='extra simd flags for every run, one string after "=": --simd-args="--no-noise --cfg KEY:VALUE"',
    )
    p.add_argument("--role", default="bench", choices=("bench", "subscriber"), help=argparse.SUPPRESS)
    p.add_argument("--endpoint", help=argparse.SUPPRESS)
    p.add_argument("--probe", default=PROBE, help=argparse.SUPPRESS)
    p.add_argument("--topics", default="robots", choices=("robots", "fleet", "ros"), help=argparse.SUPPRESS)
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.role == "subscriber":
        return subscriber_main(args.endpoint, args.probe, args.topics)
    if any(n < 1 for n in args.sizes):
        print("fleet_bench: sizes must be >= 1", file=sys.stderr)
        return 2
    s = Settings(
        duration=args.duration if args.duration is not None else (3.0 if args.quick else 10.0),
        settle=args.settle if args.settle is not None else (1.0 if args.quick else 3.0),
        spawn_concurrency=max(1, args.spawn_concurrency),
        latency_reps=args.latency_reps if args.latency_reps is not None else (5 if args.quick else 20),
        extra_spawns=args.extra_spawns if args.extra_spawns is not None else (10 if args.quick else 500),
        seed=args.seed,
        simd_args=shlex.split(args.simd_args),
    )
    plan: list[tuple[int, float, str]] = [(n, 1.0, t) for n in args.sizes for t in dict.fromkeys(args.paced_topics)]
    if not args.no_fast:
        fast_n = min(args.fast_size, max(args.sizes)) if args.quick else args.fast_size
        repeats = args.fast_runs if args.fast_runs is not None else (1 if args.quick else 3)
        for _ in range(max(1, repeats)):  # interleaved, so that a slow spell of the machine hits both kinds
            plan.extend((fast_n, 0.0, topics) for topics in dict.fromkeys(args.fast_topics))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    previous = signal.signal(signal.SIGTERM, raise_exit)
    machine = machine_info()
    command = "python -m bench.fleet_bench " + shlex.join(argv)
    res: dict[str, Any] = {
        "started": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "command": command.strip(),
        "machine": machine,
        "settings": vars(s) | {"drive_hz": DRIVE_HZ, "spacing_m": SPACING, "plan": plan},
        "runs": [],
    }
    print(f"machine: {machine_line(machine)}")
    print(f"command: {res['command']}")
    steps = [f"N={n}" + (" rtf 0" if r == 0 else "") + TOPIC_LABELS[t].replace(",", "") for n, r, t in plan]
    print(f"plan: {', '.join(steps)}; {s.duration:g} s measured per size", flush=True)
    progress = Progress()
    code = 0
    try:
        with tempfile.TemporaryDirectory(prefix="fleet-bench-") as tmpdir:
            for n, rtf, topics in plan:
                run_size(n, rtf, s, Path(tmpdir), progress, res["runs"], topics)
                write_outputs(res, out, with_plot=False)
    except (KeyboardInterrupt, SystemExit) as e:
        res["interrupted"] = True
        progress.note("interrupted: cleaning up and writing what was measured")
        code = 130 if isinstance(e, KeyboardInterrupt) else int(e.code or 1)
    finally:
        signal.signal(signal.SIGTERM, previous)
        write_outputs(res, out, with_plot=not args.no_plot)
    print()
    print(results_markdown(res))
    print(f"wrote {out / 'results.md'}, {out / 'results.json'}" + ("" if args.no_plot else f", {out / 'scaling.png'}"))
    return code


if __name__ == "__main__":
    sys.exit(main())
