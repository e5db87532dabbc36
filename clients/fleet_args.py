"""The grammar of the ``fleet`` and ``fleet-spawn`` command lines (argparse only, no daemon)."""

from __future__ import annotations

import argparse

from fleetcommon.zenoh_config import add_zenoh_args
from protocol.keys import DEFAULT_PREFIX

COMMANDS = ("spawn", "delete", "list", "world", "clock", "pause", "resume", "reset", "step", "daemons", "goto")


def add_daemon_args(
    p: argparse.ArgumentParser, waiting: str = "seconds to wait for the daemon", default: float | None = 3.0
) -> None:
    """What every client takes to reach a daemon: its prefix, a deadline, and zenoh's flags."""
    p.add_argument("--prefix", default=DEFAULT_PREFIX, help="key prefix of the daemon (default: %(default)s)")
    shown = " (default: %(default)g)" if default is not None else ""
    p.add_argument("--timeout", type=float, default=default, metavar="S", help=f"{waiting}{shown}")
    add_zenoh_args(p, server=False)


def _common_parser(
    waiting: str = "seconds to wait for the daemon", default: float | None = 3.0
) -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    add_daemon_args(common, waiting, default)
    common.add_argument("--json", action="store_true", help="print machine-readable JSON")
    return common


SPAWN_USAGE = (
    "%(prog)s [options] NAME [NS] [X Y [Z]]\n"
    "       %(prog)s [options] -entity NAME [-robot_namespace NS] [-x X] [-y Y] [-Y YAW]\n"
    "       %(prog)s [options] --file FLEET"
)


def _add_spawn_arguments(p: argparse.ArgumentParser) -> None:
    p.usage = SPAWN_USAGE
    p.add_argument(
        "words",
        nargs="*",
        metavar="NAME [NS] [X Y [Z]]",
        help="robot name, then optionally its namespace and position in metres "
        "(Z is accepted and ignored: the simulation is 2D)",
    )
    p.add_argument(
        "-entity",
        "--entity",
        dest="entity",
        metavar="NAME",
        help="robot name, as spawn_entity.py -entity",
    )
    p.add_argument(
        "--namespace",
        "-robot_namespace",
        dest="namespace",
        metavar="NS",
        help="namespace of its topics (default: the name)",
    )
    p.add_argument("--x", "-x", dest="x", type=float, metavar="M", help="x in metres (default 0)")
    p.add_argument("--y", "-y", dest="y", type=float, metavar="M", help="y in metres (default 0)")
    p.add_argument("--yaw", "-Y", dest="yaw", type=float, metavar="RAD", help="yaw in radians (default 0)")
    p.add_argument("-z", "--z", dest="z", type=float, metavar="M", help="accepted and ignored (2D)")
    p.add_argument(
        "--model",
        metavar="MODEL",
        help="burger, waffle or waffle_pi (default: $TURTLEBOT3_MODEL, else burger)",
    )
    p.add_argument(
        "-f",
        "--file",
        metavar="FLEET",
        help="spawn every robot of a fleet file: a path, or a shipped fleet by name (tb3_multi)",
    )


def build_parser(
    prog: str = "fleet",
) -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The top-level parser (for help) and one parser per command (for parsing)."""
    common = _common_parser()
    top = argparse.ArgumentParser(
        prog=prog,
        description="Spawn, delete and list the robots of a running fleetsim daemon (simd).",
        epilog="Exit codes: 0 ok, 1 refused by the daemon, 2 usage error, 3 no daemon answered. "
        "Run 'fleet COMMAND --help' for a command's options.",
    )
    sub = top.add_subparsers(dest="command", metavar="COMMAND")
    cmds: dict[str, argparse.ArgumentParser] = {}

    def add(name: str, help_: str, parent: argparse.ArgumentParser = common) -> argparse.ArgumentParser:
        cmds[name] = sub.add_parser(name, parents=[parent], help=help_, description=help_)
        return cmds[name]

    _add_spawn_arguments(add("spawn", "spawn a robot, or a fleet file"))
    add("delete", "delete robots by name or namespace").add_argument("names", nargs="+", metavar="NAME")
    listing = add("list", "list the live robots with model, pose and velocity, in name order (burger_2 then burger_10)")
    listing.add_argument(
        "names", nargs="*", metavar="NAME", help="only these robots (names or namespaces); exit 1 if one is not there"
    )
    add("world", "describe the loaded world")
    add("daemons", "list the daemons that serve the fleet (id, world, host, pid, up since)").add_argument(
        "--watch", action="store_true", help="then print a line as each daemon joins or leaves, until Ctrl-C"
    )
    add("clock", "show the simulation clock")
    add("pause", "pause the simulation")
    add("resume", "resume a paused simulation")
    add("reset", "time to zero, robots back to their spawn poses").add_argument(
        "--seed", type=int, help="new noise seed"
    )
    add("step", "advance a paused simulation by N ticks of 1/30 s").add_argument(
        "ticks", nargs="?", type=int, default=1, metavar="N"
    )
    # for goto, --timeout S is the goal's time limit (it fails with "timeout" after S s of sim time);
    # the daemon is still given the usual few seconds to answer
    goal_limit = _common_parser("the goal's time limit: it fails with 'timeout' after S s of sim time", None)
    _add_goto_arguments(add("goto", "send a robot to a place (or many, from a file), follow it, cancel it", goal_limit))
    return top, cmds


GOTO_USAGE = (
    "%(prog)s [options] NS X Y [--yaw RAD] [--tolerance M] [--wait] [--timeout S]\n"
    "       %(prog)s [options] --cancel NS\n"
    "       %(prog)s [options] --file GOALS [--wait]"
)


def _add_goto_arguments(p: argparse.ArgumentParser) -> None:
    p.usage = GOTO_USAGE
    p.add_argument("words", nargs="*", metavar="NS X Y", help="the robot (name or namespace) and where to, in metres")
    p.add_argument("--yaw", type=float, metavar="RAD", help="heading to arrive with (default: any)")
    p.add_argument(
        "--tolerance",
        type=float,
        default=0.25,
        metavar="M",
        help="how near is there (default: %(default)g, as Nav2's goal checker)",
    )
    p.add_argument(
        "--yaw-tolerance", type=float, default=0.25, metavar="RAD", help="how near the heading (default: %(default)g)"
    )
    p.add_argument(
        "--wait",
        action="store_true",
        help="follow the goal until it ends: exit 0 when reached, 4 with the reason when it fails",
    )
    p.add_argument("--cancel", metavar="NS", help="cancel the goal of robot NS")
    p.add_argument(
        "-f", "--file", metavar="GOALS", help="a YAML list of goals: - {robot: tb3_0, x: 1.0, y: 0.5, yaw: 0.0}"
    )
    p.set_defaults(goal_timeout=None)


def spawn_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=prog,
        parents=[_common_parser()],
        description="Spawn a TurtleBot3 into a running fleetsim daemon (same as 'fleet spawn').",
        epilog="Exit codes: 0 ok, 1 refused by the daemon, 2 usage error, 3 no daemon answered.",
    )
    _add_spawn_arguments(p)
    return p


_VALUE_FLAGS = frozenset(
    {"-e", "--connect", "-l", "--listen", "-m", "--mode", "-c", "--config", "--cfg", "--prefix", "--timeout"}
)


def takes_value(arg: str) -> bool:
    """Whether ``arg`` is a global flag whose value follows it (so the next word is no command)."""
    return arg in _VALUE_FLAGS
