"""The suite's own way to start a daemon never hands back another process's: a free port is
free only when asked, and another xdist worker's daemon once took it first, so a test talked to
that daemon (its tb3_0 in the way of a spawn) while its own had exited on "address in use"."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tests.conftest import Daemon, start_daemon


def test_a_daemon_on_a_port_another_holds_is_refused_not_confused(
    daemon_factory: Callable[..., Daemon], tmp_path: Path
) -> None:
    squatter = daemon_factory("--lockstep")
    with pytest.raises(RuntimeError, match="port taken"):
        start_daemon(tmp_path, "--lockstep", port=squatter.port, wait=10.0)
    assert squatter.alive()
