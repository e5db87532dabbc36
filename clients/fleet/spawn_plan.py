"""What ``fleet spawn`` was asked to spawn: the positional, ``spawn_entity.py`` and fleet-file
forms of the command line turned into robots, without talking to anybody.

    fleet spawn tb3_0 -2 -0.5                  # name, x, y
    fleet spawn burger_1 TB3_1 -2 -0.5 0.01    # name, namespace, x, y, z (z ignored: 2D)
    fleet-spawn -entity burger_1 -robot_namespace TB3_1 -x -2 -y -0.5 -Y 0
    fleet spawn --file tb3_multi               # the four-robot launch
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass

import msgspec

from clients.fleetfile import FleetFileError, FleetRobot, load_fleet


class UsageError(Exception):
    """A command line that cannot be run; reported through argparse (exit 2)."""


@dataclass
class SpawnPlan:
    robots: list[FleetRobot]
    from_file: bool
    model_from_env: bool


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def plan_spawn(
    args: argparse.Namespace, env_model: str = "", load: Callable[[str], list[FleetRobot]] = load_fleet
) -> SpawnPlan:
    """Turn the positional and flag forms into robots to spawn; raise UsageError.

    ``env_model`` is ``$TURTLEBOT3_MODEL`` (the default model when ``--model`` is not given),
    ``load`` reads a fleet file."""
    env_model = env_model.strip()
    default_model = args.model or env_model or "burger"
    model_from_env = args.model is None and bool(env_model)
    if args.file is not None:
        extra = [
            flag
            for flag, value in (
                ("NAME/NS/X/Y", args.words),
                ("-entity", args.entity),
                ("--namespace", args.namespace),
                ("--x", args.x),
                ("--y", args.y),
                ("--yaw", args.yaw),
            )
            if value not in (None, [])
        ]
        if extra:
            raise UsageError(f"--file cannot be combined with {', '.join(extra)} (only --model, as a default)")
        try:
            entries = load(args.file)
        except FleetFileError as e:
            raise UsageError(str(e)) from None
        robots = [r if r.model else msgspec.structs.replace(r, model=default_model) for r in entries]
        return SpawnPlan(robots=robots, from_file=True, model_from_env=model_from_env)

    words = list(args.words)
    name = args.entity
    if name is None:
        if not words:
            raise UsageError("a robot NAME is required (or -entity NAME, or --file FLEET)")
        name = words.pop(0)
    namespace = args.namespace
    if words and _number(words[0]) is None:
        if namespace is not None:
            raise UsageError(f"namespace given twice: {words[0]!r} and --namespace {namespace!r}")
        namespace = words.pop(0)
    numbers = [_number(w) for w in words]
    if any(n is None for n in numbers) or len(numbers) not in (0, 2, 3):
        raise UsageError(
            f"after NAME [NS] expected X Y [Z] (metres), got {' '.join(words)!r} (a namespace starts with a letter)"
        )
    x, y = args.x, args.y
    if numbers:
        if x is not None or y is not None:
            raise UsageError("position given twice: positional X Y and --x/--y")
        x, y = numbers[0], numbers[1]
    robot = FleetRobot(
        name=name,
        namespace=namespace,
        model=default_model,
        x=x if x is not None else 0.0,
        y=y if y is not None else 0.0,
        yaw=args.yaw if args.yaw is not None else 0.0,
    )
    return SpawnPlan(robots=[robot], from_file=False, model_from_env=model_from_env)
