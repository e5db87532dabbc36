"""The README's session with zenoh's own CLI (``zenoh``, from the ``zenoh-cli`` package of the
dev extra), run as written against a real simd: the block after ``<!-- readme-session:
zenoh-cli -->``.

Its conventions are the tutorial's (tests/demo/tutorial_page.py): a ``$ `` line is a command,
the lines up to the next one are what it prints, each of them found in order in its real output,
numbers standing for any number and ``...`` for anything. Two liberties, said next to the block:
the daemon listens on a free port instead of 7447 (the endpoint in ``$Z`` is the only change),
and a command whose output ends with ``^C`` (a subscriber, which runs until stopped) gets a
Ctrl-C once it has printed its lines, and must then end with status 0.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
from pathlib import Path

import pytest

from tests.conftest import ROOT, Daemon
from tests.demo.tutorial_page import VENV_BIN, sample_lines, unmatched, wait_until

README = ROOT / "README.md"
README_ENDPOINT = "tcp/127.0.0.1:7447"
ZENOH = shutil.which("zenoh", path=f"{VENV_BIN}{os.pathsep}{os.environ.get('PATH', '')}")


def session() -> list[tuple[str, str]]:
    """The README block's commands, each with the lines shown after it."""
    m = re.search(r"<!-- readme-session: zenoh-cli -->\s*\n```console\n(.*?)\n```", README.read_text(), re.S)
    assert m, "README.md has no block marked <!-- readme-session: zenoh-cli -->"
    steps: list[tuple[str, list[str]]] = []
    for line in m.group(1).splitlines():
        if line.startswith("$ "):
            steps.append((line[2:], []))
        else:
            assert steps, f"README.md: the zenoh-cli session starts with output, not a command: {line!r}"
            steps[-1][1].append(line)
    return [(cmd, "\n".join(out)) for cmd, out in steps]


def stopped_by_ctrl_c(sample: str) -> bool:
    return bool(sample_lines(sample)) and sample_lines(sample)[-1].strip() == "^C"


def as_in_a_terminal() -> None:
    """A process started in the background inherits SIGINT ignored; a terminal's job has the default."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_until_ctrl_c(script: str, sample: str, env: dict[str, str], log: Path, where: str) -> str:
    """``script`` in a terminal of its own until it has printed ``sample``, then Ctrl-C: what it
    printed (it must end, with status 0)."""
    with log.open("wb") as f:
        proc = subprocess.Popen(
            ["bash", "-e", "-c", script], env=env, stdout=f, stderr=subprocess.STDOUT,
            start_new_session=True, preexec_fn=as_in_a_terminal,
        )  # fmt: skip
    try:
        printed = wait_until(lambda: unmatched(sample, log.read_text()) is None or proc.poll() is not None, 15)
        out = log.read_text()
        assert printed and proc.poll() is None, f"{where}: it did not print {unmatched(sample, out)!r}:\n{out[-2000:]}"
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C
        rc = proc.wait(10)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    out = log.read_text()
    assert rc == 0, f"{where}: Ctrl-C ended it with status {rc}:\n{out[-2000:]}"
    return out


def test_the_session_is_zenoh_commands_on_the_readme_endpoint() -> None:
    steps = session()
    assert steps[0][0].startswith("Z=") and README_ENDPOINT in steps[0][0]
    assert all(cmd.startswith("$Z ") for cmd, _ in steps[1:]), "every command after the first runs $Z"
    assert sum(stopped_by_ctrl_c(sample) for _, sample in steps) == 1  # the subscriber


@pytest.mark.skipif(ZENOH is None, reason="no `zenoh` program (pip install -e '.[dev]' installs zenoh-cli)")
def test_the_readme_zenoh_cli_session_runs_as_shown(daemon: Daemon, tmp_path: Path) -> None:
    assert ZENOH is not None
    env = {
        **os.environ,
        "PATH": f"{Path(ZENOH).parent}{os.pathsep}{os.environ.get('PATH', '')}",
        "PYTHONUNBUFFERED": "1",  # a subscriber's lines reach the pipe as they are printed
    }
    prelude = ""  # the assignments so far (Z=...), as the reader's shell keeps them
    for cmd, sample in session():
        typed = cmd.replace(README_ENDPOINT, daemon.endpoint)
        where = f"README.md: $ {cmd}"
        if re.match(r"^\w+=", typed):
            prelude += typed + "\n"
            continue
        script = prelude + typed
        if stopped_by_ctrl_c(sample):
            sample = "\n".join(line for line in sample.splitlines() if line.strip() != "^C")
            out = run_until_ctrl_c(script, sample, env, tmp_path / "subscriber.out", where)
        else:
            done = subprocess.run(
                ["bash", "-e", "-c", script], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                text=True, timeout=20,
            )  # fmt: skip
            out = done.stdout
            assert done.returncode == 0, f"{where}: exit status {done.returncode}:\n{out}"
        miss = unmatched(sample, out)
        assert miss is None, f"{where}: the line {miss!r} is not in what it printed:\n{out[-3000:]}"
    assert daemon.alive(), daemon.log()
