"""The container image's entrypoint: ``simd`` with its flags also taken from ``SIMD_*``
environment variables.

Every long flag of ``simd`` has a variable: ``--world`` is ``SIMD_WORLD``, ``--cmd-timeout``
is ``SIMD_CMD_TIMEOUT``, ``--listen`` is ``SIMD_LISTEN`` and so on (the table is built from
simd's own parser, so new flags get a variable without changes here). Values:

* a flag without a value (``--lockstep``): ``1``/``true``/``yes``/``on`` sets it,
  ``0``/``false``/``no``/``off`` or empty leaves it off;
* a repeatable flag (``--listen``, ``--connect``): endpoints separated by commas or
  spaces; ``SIMD_CFG`` (``--cfg KEY:VALUE``, whose JSON5 values may hold commas) takes one
  item per line;
* anything else: the value as it is.

An empty variable counts as unset.

A flag given on the command line wins over its variable (the variable is then ignored,
also for repeatable flags). With neither ``--listen``/``SIMD_LISTEN`` nor a zenoh config file
the daemon listens on ``tcp/0.0.0.0:7447``, every interface of the container, instead of
simd's loopback default, which nothing outside a container could reach.

The daemon runs in this process (``simd.cli.main``), so with this module as the image's
exec-form ENTRYPOINT simd is PID 1 and gets SIGTERM itself. simd starts no child
processes, so there are no zombies to reap and no init process is needed.

The effective endpoints and prefix are written to a small JSON file (``SIMD_STATE_FILE``,
default ``/tmp/fleetsim-simd.json``) for ``python -m simd.healthcheck``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import signal
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import FrameType

ENV_PREFIX = "SIMD_"
#: Where the daemon listens in a container when nothing else is said.
DEFAULT_LISTEN = "tcp/0.0.0.0:7447"
DEFAULT_STATE_FILE = "/tmp/fleetsim-simd.json"
#: SIMD_* variables that are not simd flags.
OWN_VARIABLES = frozenset({"SIMD_STATE_FILE", "SIMD_HEALTH_TIMEOUT", "SIMD_HEALTH_CONFIG"})

_TRUE = frozenset({"1", "true", "yes", "on"})
_FALSE = frozenset({"", "0", "false", "no", "off"})


class EnvError(ValueError):
    """A SIMD_* variable that cannot be turned into a flag."""


def env_name(option: str) -> str:
    """``--cmd-timeout`` -> ``SIMD_CMD_TIMEOUT``."""
    return ENV_PREFIX + option.lstrip("-").replace("-", "_").upper()


def _long_option(action: argparse.Action) -> str | None:
    return next((o for o in action.option_strings if o.startswith("--")), None)


def _flag_actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The parser's options that take part in the mapping (all but --help)."""
    return [
        a for a in parser._actions if a.option_strings and not isinstance(a, argparse._HelpAction) and _long_option(a)
    ]


def dests_on_command_line(parser: argparse.ArgumentParser, args: Sequence[str]) -> set[str]:
    """The ``dest`` of every option spelled in ``args`` (long, ``--x=v``, unique long
    prefixes as argparse accepts them, short and ``-lVALUE``)."""
    by_option = parser._option_string_actions
    longs = [o for o in by_option if o.startswith("--")]
    found: set[str] = set()
    for tok in args:
        if tok == "--":
            break
        if tok.startswith("--"):
            name = tok.split("=", 1)[0]
            action = by_option.get(name)
            if action is None:
                matches = {by_option[o].dest for o in longs if o.startswith(name)}
                if len(matches) == 1:
                    found |= matches
                continue
            found.add(action.dest)
        elif tok.startswith("-") and len(tok) > 1 and not _is_number(tok):
            action = by_option.get(tok[:2])
            if action is not None:
                found.add(action.dest)
    return found


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def args_from_env(
    parser: argparse.ArgumentParser,
    env: Mapping[str, str],
    skip: set[str] | frozenset[str] = frozenset(),
) -> list[str]:
    """Command-line arguments for the ``SIMD_*`` variables in ``env``, except for the
    options whose ``dest`` is in ``skip``. Raises ``EnvError`` on a value that does not fit."""
    out: list[str] = []
    for action in _flag_actions(parser):
        option = _long_option(action)
        assert option is not None
        name = env_name(option)
        if name not in env or action.dest in skip:
            continue
        value = env[name]
        if action.nargs == 0:  # store_true and friends
            word = value.strip().lower()
            if word in _TRUE:
                out.append(option)
            elif word not in _FALSE:
                raise EnvError(f"{name}={value!r}: expected 1/0, true/false, yes/no or on/off")
        elif isinstance(action, argparse._AppendAction):
            items = value.splitlines() if name == "SIMD_CFG" else re.split(r"[,\s]+", value)
            for item in items:
                if item.strip():
                    out += [option, item.strip()]
        else:
            if value.strip():  # empty means unset, as in compose's ${VAR:-}
                out += [option, value]
    return out


def unknown_variables(parser: argparse.ArgumentParser, env: Mapping[str, str]) -> list[str]:
    """``SIMD_*`` variables that match no flag (typos, most likely)."""
    known = {env_name(o) for a in _flag_actions(parser) if (o := _long_option(a))} | OWN_VARIABLES
    return sorted(k for k in env if k.startswith(ENV_PREFIX) and k not in known)


def build_argv(argv: Sequence[str], env: Mapping[str, str]) -> list[str]:
    """simd's argv: the flags from the environment, then the command line (which wins)."""
    from simd.cli import build_parser

    parser = build_parser()
    for name in unknown_variables(parser, env):
        print(
            f"simd-entry: warning: ignoring {name}: no simd flag --{_flag_of(name)}",
            file=sys.stderr,
        )
    given = dests_on_command_line(parser, argv)
    out = args_from_env(parser, env, skip=given)
    has_listen = "listen" in given or "--listen" in out
    has_config = "config" in given or "--config" in out
    if not has_listen and not has_config and _mode(parser, [*out, *argv]) != "client":
        out = ["--listen", DEFAULT_LISTEN, *out]  # a client of a router listens on nothing
    return [*out, *argv]


def _mode(parser: argparse.ArgumentParser, argv: list[str]) -> str | None:
    """The zenoh mode these flags ask for (None when they do not parse: simd says why)."""
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            args, _ = parser.parse_known_args(argv)
    except SystemExit:
        return None
    mode: str | None = args.mode
    return mode


def _flag_of(name: str) -> str:
    return name[len(ENV_PREFIX) :].lower().replace("_", "-")


def local_endpoint(endpoint: str) -> str:
    """The endpoint a process in the same container connects to for a listen endpoint:
    the wildcard addresses become loopback."""
    proto, sep, rest = endpoint.partition("/")
    if not sep:
        return endpoint
    for wildcard, loopback in (("0.0.0.0:", "127.0.0.1:"), ("[::]:", "[::1]:")):
        if rest.startswith(wildcard):
            return f"{proto}/{loopback}{rest[len(wildcard) :]}"
    return endpoint


def write_state(argv: Sequence[str], path: str) -> None:
    """Record where the daemon can be asked for its clock, for the healthcheck."""
    from simd.cli import build_parser

    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            args, _ = build_parser().parse_known_args(list(argv))
    except SystemExit:  # --help or a bad flag: simd itself reports it next
        return
    listen = [local_endpoint(e) for e in (args.listen or [])]
    # a daemon in client mode is reached through the router it connects to
    connect = listen if listen and args.mode != "client" else list(args.connect or [])
    # a daemon sharing a fleet is asked for its own clock (any daemon answers the fleet's)
    state = {"connect": connect, "prefix": args.prefix, "pid": os.getpid(), "id": args.id if args.join else None}
    try:
        tmp = Path(f"{path}.{os.getpid()}")
        tmp.write_text(json.dumps(state) + "\n")
        tmp.replace(path)
    except OSError as e:  # read-only file system: the healthcheck falls back to SIMD_* vars
        print(f"simd-entry: warning: cannot write {path}: {e}", file=sys.stderr)


def _early_stop(signum: int, frame: FrameType | None) -> None:
    # PID 1 ignores signals it has no handler for: until simd installs its own handler
    # (after the zenoh session is open), a SIGTERM ends startup here.
    raise SystemExit(0)


def main(argv: Sequence[str] | None = None, env: Mapping[str, str] | None = None) -> int:
    signal.signal(signal.SIGTERM, _early_stop)
    args = list(sys.argv[1:] if argv is None else argv)
    environ = os.environ if env is None else env
    try:
        full = build_argv(args, environ)
    except EnvError as e:
        print(f"simd: error: {e}", file=sys.stderr, flush=True)
        return 2
    write_state(full, environ.get("SIMD_STATE_FILE", DEFAULT_STATE_FILE))

    from simd.cli import main as simd_main

    return simd_main(full)


if __name__ == "__main__":
    sys.exit(main())
