"""An example that learns: the cross-entropy method trains a small policy on ``fleetsim/Navigate-v0``.

Why: to show the environment is learnable with nothing but numpy, in minutes on a laptop's two
cores, and to watch the result drive on a running daemon. No deep-learning library: the policy is
linear (or, with ``--hidden H``, one tanh layer) with a tanh output, its parameters one vector,
and the cross-entropy method (CEM) searches that vector: draw a population around a mean, run
each candidate on the same few episodes (common random numbers: the generation's episode seeds
are shared, so candidates are compared on equal terms), keep the best fifth, move the mean and
the spread to theirs, repeat. Fitness is the mean return. Each generation the mean policy also
runs a fixed set of held-out episodes, whose success rate (arrived within 0.2 m of the goal) is
the learning curve.

The task: a burger in turtlebot3_world, 24 lidar sectors, episodes of at most 200 steps (40 s of
sim time). Start and goal are Navigate-v0's own for each episode seed (over the free space the
robot can drive to from the world's spawn, at least a metre apart).

The policy sees, per sector, how close the nearest return is within ``--near`` metres (0 beyond,
1 touching), the goal's distance (in units of 3 m), the sine and cosine of its bearing, and the
velocities as fractions of the limits; its two outputs are the action (fractions of the limits).

Train (3½ minutes on two cores; a line a generation; writes cem_out/policy.npz,
cem_out/curve.csv and cem_out/learning_curve.png, the picture needing matplotlib, the ``bench``
extra)::

    python -m learn.cem
    python -m learn.cem --generations 30 --population 48 --episodes 8 --workers 2 --seed 1 --out cem_out

Watch the trained policy drive, live, on a daemon::

    simd --lockstep &                 # the replay steps it; lidar noise on, as in training
    fleet-view &                      # open the URL it prints
    python -m learn.cem --replay cem_out/policy.npz --endpoint tcp/127.0.0.1:7447 --episodes 5

The replay runs the same held-out episodes as the curve (``--seed S`` for others), at 0.2 s of
wall time a step, real time (``--pace 0`` as fast as it goes), and prints each one's outcome.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import signal
import sys
import time
import zipfile
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64

#: held-out episodes are seeds from here on; a generation's training seeds are drawn below it
HELD_OUT_SEED = 1_000_000_000
ELITE_FRACTION = 0.2
STEP_S = 0.2  # sim seconds an env step (learn.navigate: six 30 Hz ticks), the replay's real-time pace


@dataclass(frozen=True)
class Settings:
    """What a policy needs to be rebuilt and to meet the episodes it was trained on."""

    world: str = "turtlebot3_world"
    model: str = "burger"
    beams: int = 24
    max_steps: int = 200
    hidden: int = 0  # 0: linear
    near: float = 1.0  # m: the lidar features see this far
    range_max: float = 3.5  # m: the observation's sectors are ranges divided by this

    def check(self) -> None:
        """ValueError unless these are settings Navigate-v0 and the policy take."""
        from learn.task import check_settings

        ints = (self.beams, self.max_steps, self.hidden)
        if not all(type(v) is int for v in ints) or not all(type(v) is float for v in (self.near, self.range_max)):
            raise ValueError(f"beams, max_steps and hidden are integers, near and range_max floats: {self}")
        check_settings(self.model, self.beams, self.max_steps)
        if self.hidden < 0 or not self.near > 0 or not self.range_max > 0:
            raise ValueError(f"hidden >= 0, near > 0 and range_max > 0, got {self}")

    @property
    def features(self) -> int:
        return self.beams + 5

    @property
    def size(self) -> int:
        n, h = self.features, self.hidden
        return h * (n + 1) + 2 * (h + 1) if h else 2 * (n + 1)


class Policy:
    """obs -> action in -1..1: tanh(W x + b), or tanh(W2 tanh(W1 x + b1) + b2) with a hidden layer."""

    def __init__(self, settings: Settings, params: F64) -> None:
        s = settings
        if params.shape != (s.size,) or not np.all(np.isfinite(params)):
            raise ValueError(f"the parameters are {s.size} finite numbers for these settings, got shape {params.shape}")
        n, h = s.features, s.hidden
        self.settings = s
        self.limits = _limits(s.model)
        self.layers: list[tuple[F64, F64]] = []
        i = 0
        for rows, cols in ((h, n), (2, h)) if h else ((2, n),):
            w = params[i : i + rows * cols].reshape(rows, cols)
            b = params[i + rows * cols : i + rows * cols + rows]
            self.layers.append((w, b))
            i += rows * (cols + 1)

    def features(self, obs: npt.NDArray[Any]) -> F64:
        s = self.settings
        o = np.asarray(obs, dtype=np.float64)
        near = np.clip(1.0 - o[: s.beams] * (s.range_max / s.near), 0.0, 1.0)
        distance, bearing, v, w = o[s.beams :]
        vmax, wmax = self.limits
        tail = [min(distance / 3.0, 2.0), math.sin(bearing), math.cos(bearing), v / vmax, w / wmax]
        return np.concatenate([near, tail])

    def act(self, obs: npt.NDArray[Any]) -> npt.NDArray[np.float32]:
        x = self.features(obs)
        for w, b in self.layers:
            x = np.tanh(w @ x + b)
        return x.astype(np.float32)


def _limits(model: str) -> tuple[float, float]:
    from simd.core.models import MODELS

    m = MODELS[model]
    return m.max_linear_velocity, m.max_angular_velocity


# -- rollouts (in the worker processes) -------------------------------------------------------

_WORKER: dict[str, Any] = {}


def make_env(settings: Settings, endpoint: str | None = None) -> Any:
    import gymnasium

    import learn  # noqa: F401  (registers fleetsim/Navigate-v0)

    kwargs: dict[str, Any] = {
        "world": settings.world,
        "model": settings.model,
        "beams": settings.beams,
        "max_steps": settings.max_steps,
    }
    if endpoint is not None:
        kwargs["endpoint"] = endpoint
    env: Any = gymnasium.make("fleetsim/Navigate-v0", **kwargs)
    if env.unwrapped.range_max != settings.range_max:
        env.close()
        raise ValueError(f"the policy takes a lidar of {settings.range_max} m, the env's has {env.unwrapped.range_max}")
    return env


def _init_worker(settings: Settings, ignore_sigint: bool = True) -> None:
    if ignore_sigint:  # Ctrl-C is the parent's to handle: it saves what there is and stops the pool
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    env = make_env(settings)
    _WORKER.update(settings=settings, env=env)


def episode(
    env: Any, policy: Policy, seed: int, on_step: Callable[[], None] | None = None
) -> tuple[float, dict[str, Any]]:
    """One episode: (return, the last step's info: arrived, collided, steps, distance)."""
    obs, info = env.reset(seed=seed)
    total = 0.0
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs))
        total += float(reward)
        if on_step is not None:
            on_step()
        if terminated or truncated:
            return total, dict(info)


def _rollouts(job: tuple[F64, list[int]]) -> list[tuple[float, bool, bool]]:
    params, seeds = job
    policy = Policy(_WORKER["settings"], params)
    out = []
    for s in seeds:
        ret, info = episode(_WORKER["env"], policy, s)
        out.append((ret, bool(info["arrived"]), bool(info["collided"])))
    return out


# -- training ---------------------------------------------------------------------------------

COLUMNS = (
    "generation",
    "population_mean_return",
    "population_best_return",
    "elite_mean_return",
    "population_success",
    "heldout_return",
    "heldout_success",
    "heldout_collisions",
    "sigma",
    "elapsed_s",
)


def train(args: argparse.Namespace) -> int:
    settings = Settings(max_steps=args.max_steps, hidden=args.hidden, near=args.near)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        return _fail(f"cannot write into {str(out)!r}: {e.strerror}")
    plt = _pyplot()
    if plt is None:
        print(
            "cem: matplotlib is not installed, so no learning_curve.png (pip install -e '.[bench]'); "
            "policy.npz and curve.csv are written",
            file=sys.stderr,
        )
    rng = np.random.default_rng(args.seed)
    n = settings.size
    mean, sigma = np.zeros(n), np.full(n, args.sigma)
    elites = max(2, round(ELITE_FRACTION * args.population))
    held_out = [HELD_OUT_SEED + i for i in range(args.eval_episodes)]
    rows: list[dict[str, float]] = []
    best: tuple[float, float, F64, int] | None = None  # (held-out success, return, params, generation)
    print(
        f"cem: {n} parameters ({'linear' if not settings.hidden else f'{settings.hidden} hidden'}), population "
        f"{args.population}, {args.episodes} episodes each, {elites} elites, {args.eval_episodes} held-out "
        f"episodes, {args.workers} worker(s); {settings.world}, {settings.model}, max_steps {settings.max_steps}",
        flush=True,
    )
    t0 = time.monotonic()
    pool, run_map = _mapper(settings, args.workers)
    try:
        for g in range(args.generations + 1):
            row: dict[str, float] = {"generation": g}
            if g > 0:  # generation 0 is the starting policy, before any search
                seeds = [int(s) for s in rng.integers(0, HELD_OUT_SEED, size=args.episodes)]
                population = mean + sigma * rng.standard_normal((args.population, n))
                results = run_map(_rollouts, [(p, seeds) for p in population])
                fitness = np.array([np.mean([r[0] for r in res]) for res in results])
                order = np.argsort(-fitness, kind="stable")[:elites]
                mean = population[order].mean(axis=0)
                extra = args.extra_noise * max(0.0, 1.0 - g / max(1.0, 0.75 * args.generations))
                sigma = np.sqrt(population[order].var(axis=0) + extra)
                row |= {
                    "population_mean_return": float(fitness.mean()),
                    "population_best_return": float(fitness.max()),
                    "elite_mean_return": float(fitness[order].mean()),
                    "population_success": float(np.mean([r[1] for res in results for r in res])),
                }
            held = [r for res in run_map(_rollouts, [(mean, [s]) for s in held_out]) for r in res]
            success = float(np.mean([r[1] for r in held]))
            ret = float(np.mean([r[0] for r in held]))
            row |= {
                "heldout_return": ret,
                "heldout_success": success,
                "heldout_collisions": float(np.mean([r[2] for r in held])),
                "sigma": float(sigma.mean()),
                "elapsed_s": time.monotonic() - t0,
            }
            rows.append(row)
            if best is None or (success, ret) > best[:2]:
                best = (success, ret, mean.copy(), g)
            _save(out, settings, best, rows, args)
            print(_progress(row, args.generations), flush=True)
    except KeyboardInterrupt:
        print(f"cem: interrupted after generation {len(rows) - 1}; {out} holds what there is", file=sys.stderr)
        if pool is not None:
            pool.terminate()
        _picture(plt, out, rows, settings)
        return 130
    finally:
        if pool is not None:
            pool.close()
            pool.join()
    _picture(plt, out, rows, settings)
    assert best is not None
    first, last = rows[0], rows[-1]
    print(
        f"cem: held-out success {first['heldout_success']:.0%} -> {last['heldout_success']:.0%} "
        f"(best {best[0]:.0%} at generation {best[3]}, saved), return {first['heldout_return']:.1f} -> "
        f"{last['heldout_return']:.1f}, in {last['elapsed_s']:.0f} s; wrote {out / 'policy.npz'}, "
        f"{out / 'curve.csv'}{'' if plt is None else ', ' + str(out / 'learning_curve.png')}"
    )
    return 0


def _mapper(settings: Settings, workers: int) -> tuple[Any, Callable[[Callable[[Any], Any], Iterable[Any]], list[Any]]]:
    """A process pool of ``workers`` (each with its own env), or this process for one."""
    if workers <= 1:
        _init_worker(settings, ignore_sigint=False)
        return None, lambda f, jobs: [f(j) for j in jobs]
    import multiprocessing

    pool = multiprocessing.get_context("spawn").Pool(workers, _init_worker, (settings,))
    return pool, lambda f, jobs: pool.map(f, jobs, chunksize=1)


def _progress(row: dict[str, float], generations: int) -> str:
    head = f"gen {int(row['generation']):3d}/{generations}"
    pop = (
        f"return mean {row['population_mean_return']:6.1f} best {row['population_best_return']:6.1f}"
        if "population_mean_return" in row
        else f"{'(the starting policy)':<29}"
    )
    return (
        f"{head}  {pop}  held-out: success {row['heldout_success']:4.0%} return {row['heldout_return']:6.1f} "
        f"collisions {row['heldout_collisions']:4.0%}  sigma {row['sigma']:.3f}  {row['elapsed_s']:5.0f} s"
    )


def _save(
    out: Path,
    settings: Settings,
    best: tuple[float, float, F64, int],
    rows: list[dict[str, float]],
    args: argparse.Namespace,
) -> None:
    """policy.npz (the best mean policy on the held-out episodes) and curve.csv, rewritten every generation."""
    tmp = out / "policy.tmp.npz"
    np.savez(
        tmp,
        params=best[2],
        settings=np.array(json.dumps(asdict(settings))),
        generation=np.array(best[3]),
        heldout_success=np.array(best[0]),
        seed=np.array(args.seed),
    )
    tmp.replace(out / "policy.npz")
    with (out / "curve.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, restval="")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.4f}" if k != "generation" else int(v)) for k, v in r.items()})


def _pyplot() -> Any:
    try:
        import matplotlib
    except ImportError:
        return None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _picture(plt: Any, out: Path, rows: list[dict[str, float]], settings: Settings) -> None:
    """learning_curve.png: the held-out success rate and the returns per generation."""
    if plt is None or not rows:
        return
    g = [r["generation"] for r in rows]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(8.0, 3.0), dpi=100)
    ax1.plot(g, [100 * r["heldout_success"] for r in rows], "o-", ms=3, label="held-out (mean policy)")
    trained = [r for r in rows if "population_success" in r]
    ax1.plot(
        [r["generation"] for r in trained],
        [100 * r["population_success"] for r in trained],
        ".--",
        ms=3,
        color="gray",
        label="population (training episodes)",
    )
    ax1.set(xlabel="generation", ylabel="success rate (%)", ylim=(-3, 103), title="arrived at the goal")
    ax1.legend(fontsize=8, loc="lower right")
    ax2.plot(g, [r["heldout_return"] for r in rows], "o-", ms=3, label="held-out (mean policy)")
    ax2.plot(
        [r["generation"] for r in trained],
        [r["population_mean_return"] for r in trained],
        ".--",
        ms=3,
        color="gray",
        label="population mean",
    )
    ax2.set(xlabel="generation", ylabel="return", title="mean return")
    ax2.legend(fontsize=8, loc="lower right")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    fig.suptitle(f"CEM on fleetsim/Navigate-v0 ({settings.model}, {settings.world})", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "learning_curve.png")
    plt.close(fig)


# -- replay on a daemon -----------------------------------------------------------------------


def load(path: str | Path) -> tuple[Settings, F64]:
    """The settings and parameters of a policy.npz, or ValueError saying what is wrong with it."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"no policy file {str(path)!r}")
    if not zipfile.is_zipfile(p):
        raise ValueError(f"{str(path)!r} is not a policy written by learn.cem: not an .npz file")
    try:
        with np.load(p, allow_pickle=False) as z:
            params = np.asarray(z["params"], dtype=np.float64)
            raw = json.loads(str(z["settings"]))
        settings = Settings(**raw)
        settings.check()
        Policy(settings, params)
    except Exception as e:  # no such keys, not JSON, other settings, the wrong parameters: all the same to the user
        raise ValueError(f"{str(path)!r} is not a policy written by learn.cem ({type(e).__name__}: {e})") from None
    return settings, params


def replay(args: argparse.Namespace) -> int:
    try:
        settings, params = load(args.replay)
    except ValueError as e:
        return _fail(str(e))
    policy = Policy(settings, params)
    from clients.api import FleetClient
    from protocol.errors import FleetError

    try:  # a quick look first, which also tells a malformed endpoint from an unreachable one
        with FleetClient(args.endpoint, timeout=args.timeout) as c:
            c.clock()
    except FleetError as e:
        if e.field == "connect":  # zenoh's refusal of a malformed endpoint
            return _fail(f"cannot connect to {args.endpoint!r}: {e.message.split(': ', 1)[-1]}")
        return _fail(e.message)
    try:
        env = make_env(settings, endpoint=args.endpoint)
    except (ValueError, ConnectionError, FleetError) as e:
        return _fail(e.message if isinstance(e, FleetError) else str(e))
    seeds = [(HELD_OUT_SEED if args.seed is None else args.seed) + i for i in range(args.episodes)]
    last = [time.monotonic()]

    def pace() -> None:
        wait = last[0] + args.pace - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        last[0] = time.monotonic()

    print(
        f"cem: replaying {args.replay} on {args.endpoint} ({settings.world}, {settings.model}), "
        f"{args.episodes} episode(s), {args.pace:g} s a step",
        flush=True,
    )
    arrived = 0
    try:
        for k, s in enumerate(seeds, 1):
            ret, info = episode(env, policy, s, on_step=pace)
            outcome = (
                "arrived"
                if info["arrived"]
                else "collided"
                if info["collided"]
                else f"out of time, {info['distance']:.2f} m from the goal"
            )
            arrived += bool(info["arrived"])
            print(
                f"episode {k} (seed {s}): {outcome} after {info['steps']} steps "
                f"({info['steps'] * STEP_S:.1f} s of sim time), return {ret:.1f}",
                flush=True,
            )
    except FleetError as e:
        return _fail(f"the daemon stopped answering: {e.message}", code=1)
    except KeyboardInterrupt:
        return 130
    finally:
        env.close()
    print(f"cem: arrived in {arrived} of {len(seeds)}")
    return 0


def _fail(message: str, code: int = 2) -> int:
    print(f"cem: {message}", file=sys.stderr)
    return code


# -- command line -----------------------------------------------------------------------------


def _positive(kind: type[int] | type[float], allow_zero: bool = False) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
            raise argparse.ArgumentTypeError(f"expected {'>= 0' if allow_zero else '> 0'}, got {text!r}")
        return v

    return parse


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m learn.cem",
        description="Train a small policy on fleetsim/Navigate-v0 with the cross-entropy method, or replay one "
        "on a running simd --lockstep (see the module's docstring).",
    )
    t = p.add_argument_group("training")
    t.add_argument("--generations", type=_positive(int), default=20, help="CEM generations (default 20)")
    t.add_argument("--population", type=_positive(int), default=40, help="candidates a generation (default 40)")
    t.add_argument(
        "--episodes",
        type=_positive(int),
        default=None,
        help="training: episodes a candidate, the same for all in a generation (default 6); "
        "replay: episodes to run (default 3)",
    )
    t.add_argument(
        "--eval-episodes",
        type=_positive(int),
        default=40,
        help="held-out episodes the mean policy runs each generation (default 40)",
    )
    t.add_argument(
        "--seed",
        type=int,
        default=None,
        help="training: the search's seed (default 0); replay: the first episode seed (default: the held-out episodes)",
    )
    t.add_argument("--out", default="cem_out", help="output directory (default cem_out/)")
    t.add_argument("--workers", type=_positive(int), default=2, help="processes (default 2)")
    t.add_argument(
        "--max-steps",
        type=_positive(int),
        default=Settings.max_steps,
        help=f"steps an episode, 0.2 s each (default {Settings.max_steps})",
    )
    t.add_argument(
        "--hidden",
        type=_positive(int, allow_zero=True),
        default=Settings.hidden,
        help="hidden tanh units (default 0: a linear policy)",
    )
    t.add_argument(
        "--near",
        type=_positive(float),
        default=Settings.near,
        help=f"m: how far the lidar features see (default {Settings.near:g})",
    )
    t.add_argument("--sigma", type=_positive(float), default=0.5, help="the first spread (default 0.5)")
    t.add_argument(
        "--extra-noise",
        type=_positive(float, allow_zero=True),
        default=0.02,
        help="variance added to the spread, down to 0 at 3/4 of the run (default 0.02)",
    )
    r = p.add_argument_group("replay")
    r.add_argument("--replay", metavar="POLICY.npz", help="run this policy on the daemon at --endpoint")
    r.add_argument("--endpoint", "-e", default="tcp/127.0.0.1:7447", help="the daemon (default tcp/127.0.0.1:7447)")
    r.add_argument(
        "--pace",
        type=_positive(float, allow_zero=True),
        default=None,
        help="wall seconds a step when replaying (default 0.2, real time; 0: as fast as it goes)",
    )
    r.add_argument(
        "--timeout", type=_positive(float), default=3.0, help="seconds to wait for the daemon to answer (default 3)"
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.replay is not None:
        args.pace = STEP_S if args.pace is None else args.pace
        args.episodes = 3 if args.episodes is None else args.episodes
        return replay(args)
    args.seed = 0 if args.seed is None else args.seed
    args.episodes = 6 if args.episodes is None else args.episodes
    return train(args)


if __name__ == "__main__":
    sys.exit(main())
