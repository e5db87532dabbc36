"""Fixtures of the viewer tests: fleet-view processes and a headless Chromium."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.cdp import CHROMIUM, Chromium
from tests.clients.viewer_harness import Viewer, start_viewer
from tests.conftest import Daemon


@pytest.fixture
def viewer_factory() -> Iterator[Callable[..., Viewer]]:
    """Start fleet-view against a daemon (extra arguments passed on); all stop at the end."""
    started: list[Viewer] = []

    def start(daemon: Daemon, *args: str) -> Viewer:
        v = start_viewer(daemon, *args)
        started.append(v)
        return v

    yield start
    for v in started:
        v.stop()


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[Chromium]:
    if CHROMIUM is None:
        pytest.skip("headless Chromium not found (`chromium` is not on PATH; .ci/run installs it)")
    with Chromium(tmp_path / "chromium", 1280, 800) as b:
        yield b
