"""A malformed endpoint or zenoh config file is one clear line and a usage exit, from every
client: zenoh's own error is a JSON5 wrapper around its message with the Rust source path it
came from, and fleet-teleop, fleet-view and fleet-map let it out as a traceback (fleet-record
said it could not reach a ROS router it had not been asked for)."""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from clients import FleetClient
from clients.fleet.cli import main as fleet_main
from clients.mapping.cli import main as map_main
from clients.record.cli import main as record_main
from clients.teleop.cli import main as teleop_main
from clients.viewer.app import main as view_main
from fleetcommon.zenoh_config import ZenohOptions
from protocol.errors import ErrorCode, FleetError
from simd.healthcheck import Target, check

ZENOH_SAYS = "Endpoints must be of the form <protocol>/<address>"


@pytest.fixture(autouse=True)
def _handlers_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The programs install their SIGINT/SIGTERM handlers in this process: given back after;
    and whatever they might write goes to a temporary directory."""
    monkeypatch.chdir(tmp_path)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    yield
    signal.signal(signal.SIGINT, before[0])
    signal.signal(signal.SIGTERM, before[1])


def _exit_code(main: Callable[[list[str]], int], argv: list[str]) -> object:
    """The program's exit code, returned or exited with (argparse's errors exit)."""
    try:
        return main(argv)
    except SystemExit as e:
        return e.code


CLIENTS: list[tuple[str, Callable[[list[str]], int], list[str]]] = [
    ("fleet list", lambda a: fleet_main(["list", *a]), []),
    ("fleet-teleop", lambda a: teleop_main(a), ["tb3_0"]),
    ("fleet-view", lambda a: view_main(a), []),
    ("fleet-record", lambda a: record_main(a), []),
    ("fleet-map", lambda a: map_main(a), []),
]


BAD = [
    (["-e", "nonsense"], ZENOH_SAYS),
    (["-c", "no-such.json5"], "no-such.json5: No such file"),
]


@pytest.mark.parametrize(("flags", "said"), BAD, ids=["endpoint", "config file"])
@pytest.mark.parametrize(("program", "main", "args"), CLIENTS, ids=[c[0] for c in CLIENTS])
def test_a_bad_endpoint_or_config_file_is_one_clear_line(
    program: str,
    main: Callable[[list[str]], int],
    args: list[str],
    flags: list[str],
    said: str,
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert _exit_code(main, [*args, *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith(program.split()[0]) and said in err[-1], err
    assert all(".rs" not in line and "Json5Err" not in line and "Traceback" not in line for line in err), err


def test_the_python_api_says_it_is_the_configuration() -> None:
    with pytest.raises(FleetError) as refused:
        FleetClient("nonsense")
    assert refused.value.code is ErrorCode.INVALID_VALUE and refused.value.field == "connect"
    assert refused.value.message.startswith("bad zenoh configuration: " + ZENOH_SAYS)
    with pytest.raises(ValueError, match=r"^nonsense\.json5: No such file"):
        ZenohOptions(mode="client", config_file="nonsense.json5").build()


def test_the_container_healthcheck_says_unhealthy_in_one_line() -> None:
    healthy, message = check(Target(connect=["nonsense"], prefix="fleet", source="flag"), 1.0)
    assert not healthy and message == f"cannot connect to nonsense: {ZENOH_SAYS}[?<metadata>][#<config>]: nonsense"
