"""Container healthcheck: ask the running daemon for its clock over zenoh.

``python -m simd.healthcheck`` exits 0 when ``<prefix>/clock`` answers within the timeout
(2 s by default) and 1 otherwise. The clock is answered by the simulation thread, so this
checks the whole daemon (session, queryables and the tick loop), not only its process. In a
shared fleet (``simd --join``) any daemon answers ``<prefix>/clock``: there it asks
``<prefix>/daemons/<id>/clock``, which only daemon ``<id>`` answers (``--id``, or the id the
entrypoint recorded for a ``--join`` daemon).

Where to ask, first match wins:

1. ``-e/--connect ENDPOINT`` and ``--prefix PREFIX`` on the command line;
2. the file the container entrypoint writes (``SIMD_STATE_FILE``, default
   ``/tmp/fleetsim-simd.json``), which holds the daemon's effective listen endpoints
   (wildcard addresses turned into loopback) and prefix, wherever they came from;
3. the variables ``SIMD_LISTEN`` (or ``SIMD_CONNECT`` when ``SIMD_MODE=client``) and
   ``SIMD_PREFIX``;
4. ``tcp/127.0.0.1:7447`` and prefix ``fleet``.

``SIMD_HEALTH_TIMEOUT`` (seconds) changes the default timeout. ``SIMD_HEALTH_CONFIG`` (or
``-c FILE``) is a zenoh client config to ask with: a secured daemon (docs/security.md) answers
only over TLS, to a known user (``fleet-security init`` writes ``health.json5`` for this).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fleetcommon.zenoh_config import ZenohOptions, zenoh_error_text
from protocol.keys import DEFAULT_PREFIX
from simd.container_entry import DEFAULT_LISTEN, DEFAULT_STATE_FILE, local_endpoint

DEFAULT_TIMEOUT = 2.0


@dataclass
class Target:
    connect: list[str]
    prefix: str
    source: str
    #: the daemon's id in a shared fleet: then its own clock is asked, not the fleet's
    daemon: str | None = None


def _split(value: str) -> list[str]:
    return [e for e in re.split(r"[,\s]+", value) if e]


def resolve_target(
    connect: Sequence[str] | None, prefix: str | None, env: Mapping[str, str], daemon: str | None = None
) -> Target:
    """Where the daemon is, by the rules in the module docstring."""
    if connect:
        return Target(list(connect), prefix or env.get("SIMD_PREFIX") or DEFAULT_PREFIX, "command line", daemon)
    state_file = env.get("SIMD_STATE_FILE", DEFAULT_STATE_FILE)
    try:
        state: Any = json.loads(Path(state_file).read_text())
        endpoints = [str(e) for e in state["connect"]]
        if endpoints:
            shared = state.get("id")
            return Target(
                endpoints, prefix or str(state["prefix"]), state_file, daemon or (str(shared) if shared else None)
            )
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass
    if env.get("SIMD_MODE", "").strip() == "client" and env.get("SIMD_CONNECT"):
        endpoints = _split(env["SIMD_CONNECT"])
    else:
        endpoints = [local_endpoint(e) for e in _split(env.get("SIMD_LISTEN", "") or DEFAULT_LISTEN)]
    return Target(endpoints, prefix or env.get("SIMD_PREFIX") or DEFAULT_PREFIX, "environment", daemon)


def check(target: Target, timeout: float, config_file: str | None = None) -> tuple[bool, str]:
    """Query ``<prefix>/clock``; (healthy, message)."""
    import zenoh

    t0 = time.monotonic()
    where = ", ".join(target.connect) or f"the endpoints of {config_file}"
    try:
        conf = ZenohOptions(mode="client", connect=target.connect, config_file=config_file).build()
    except ValueError as e:
        return False, f"cannot connect to {where}: {e}"
    conf.insert_json5("connect/timeout_ms", str(max(1, int(timeout * 1000))))
    try:
        session: Any = zenoh.open(conf)
    except zenoh.ZError as e:
        return False, f"cannot connect to {where}: {zenoh_error_text(e)}"
    try:
        left = max(0.2, timeout - (time.monotonic() - t0))
        key = f"{target.prefix}/daemons/{target.daemon}/clock" if target.daemon else f"{target.prefix}/clock"
        for reply in session.get(f"{key}?format=json", timeout=left):
            if reply.ok is not None:
                body = reply.ok.payload.to_bytes().decode("utf-8", "replace")
                ms = (time.monotonic() - t0) * 1000
                return True, f"{key} answered via {where} in {ms:.0f} ms: {body}"
            err = reply.err
            detail = err.payload.to_bytes().decode("utf-8", "replace") if err is not None else "?"
            return False, f"{key} via {where} answered with an error: {detail}"
        return False, f"no answer on {key} via {where} within {timeout:g} s"
    finally:
        session.close()


def main(argv: Sequence[str] | None = None, env: Mapping[str, str] | None = None) -> int:
    environ = os.environ if env is None else env
    p = argparse.ArgumentParser(
        prog="python -m simd.healthcheck",
        description="Exit 0 if a fleetsim daemon answers its clock query, else 1.",
    )
    p.add_argument(
        "-e",
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="daemon endpoint (default: from the entrypoint's state file or SIMD_LISTEN)",
    )
    p.add_argument("--prefix", help="key prefix (default: the daemon's, or SIMD_PREFIX, or fleet)")
    p.add_argument(
        "--id",
        help="in a shared fleet (simd --join), ask daemon ID's own clock, not the fleet's (default: the id the "
        "entrypoint recorded for a --join daemon)",
    )
    p.add_argument("-c", "--config", metavar="FILE", help="zenoh client config (default: SIMD_HEALTH_CONFIG)")
    p.add_argument(
        "--timeout",
        type=float,
        default=None,
        help=f"seconds (default: SIMD_HEALTH_TIMEOUT or {DEFAULT_TIMEOUT:g})",
    )
    args = p.parse_args(argv)
    timeout = args.timeout
    if timeout is None:
        try:
            timeout = float(environ.get("SIMD_HEALTH_TIMEOUT", "") or DEFAULT_TIMEOUT)
        except ValueError:
            timeout = DEFAULT_TIMEOUT
    target = resolve_target(args.connect, args.prefix, environ, args.id)
    config = args.config or environ.get("SIMD_HEALTH_CONFIG") or None
    if config and target.source == "environment":
        # nothing better known than the defaults: the config's own endpoints (a secured daemon's
        # health.json5 names its TLS port; the entrypoint cannot see inside simd's config file)
        target = Target([], target.prefix, config, target.daemon)
    try:
        ok, message = check(target, timeout, config)
    except Exception as e:  # a healthcheck reports, it does not crash with a traceback
        ok, message = False, f"{type(e).__name__}: {e}"
    print(f"simd {'healthy' if ok else 'UNHEALTHY'}: {message}", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
