"""Every program a user runs prints its help: the console scripts of pyproject.toml, each
``fleet`` command and each benchmark. argparse formats a help text with ``%``, so a help
string holding a bare percent sign (``90% of the fleet``) crashed ``--help`` with a TypeError
(bench.overload did)."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from importlib.metadata import distribution
from pathlib import Path
from typing import Any

import pytest

from clients.fleet.cli import main as fleet_main
from clients.fleet_args import build_parser

ROOT = Path(__file__).resolve().parents[1]
#: A benchmark's helper that other processes start, with an argument of its own, not flags.
NOT_PROGRAMS = {"bench.sleeper"}


def _scripts() -> dict[str, str]:
    """The console scripts the installed project declares (pyproject.toml's ``[project.scripts]``)."""
    return {e.name: e.value for e in distribution("fleetsim").entry_points if e.group == "console_scripts"}


def _benchmarks() -> list[str]:
    found = []
    for path in sorted((ROOT / "bench").glob("*.py")):
        module = f"bench.{path.stem}"
        if "\ndef main(argv" in path.read_text() and module not in NOT_PROGRAMS:
            found.append(module)
    return found


def _help_of(main: Callable[..., Any], argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as ended:
        main(argv)
    out = capsys.readouterr().out
    assert ended.value.code == 0, out
    return out


@pytest.mark.parametrize("script", sorted(_scripts()))
def test_each_console_script_prints_its_help(script: str, capsys: pytest.CaptureFixture[str]) -> None:
    module, func = _scripts()[script].split(":")
    out = _help_of(getattr(importlib.import_module(module), func), ["--help"], capsys)
    assert "usage:" in out and "--help" in out


def test_each_fleet_command_prints_its_help(capsys: pytest.CaptureFixture[str]) -> None:
    _, commands = build_parser()
    assert {"list", "spawn", "goto", "clock"} <= set(commands)
    for command in commands:
        out = _help_of(fleet_main, [command, "--help"], capsys)
        assert "usage:" in out and command in out.splitlines()[0], command


def test_each_benchmark_prints_its_help(capsys: pytest.CaptureFixture[str]) -> None:
    modules = _benchmarks()
    assert {"bench.overload", "bench.soak", "bench.fleet_bench", "bench.scale_bench"} <= set(modules)
    for module in modules:
        out = _help_of(importlib.import_module(module).main, ["--help"], capsys)
        assert "usage:" in out, module
