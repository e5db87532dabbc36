"""fleet-view's status line shows the daemon's clock: the real-time factor achieved against the
target, a daemon falling behind (amber, with how far behind), and a paused one (issue 33). A
real simd, the real fleet-view server and headless Chromium."""

from __future__ import annotations

import re
from collections.abc import Callable

import pytest

from clients.viewer.state import FleetState
from protocol.control import Clock
from protocol.messages import Time
from tests.cdp import Chromium
from tests.clients.viewer_harness import Viewer
from tests.conftest import Daemon

STATUS = "document.getElementById('status-text').textContent"
PILL = "document.getElementById('status').className"


def _clock(rtf: float, target: float = 1.0, behind: float = 0.0, falling: bool = False) -> Clock:
    return Clock(
        clock=Time.from_seconds(5.0),
        tick=150,
        dt=1 / 30,
        paused=False,
        lockstep=False,
        real_time_factor=rtf,
        target_real_time_factor=target,
        robots=1,
        behind_s=behind,
        falling_behind=falling,
    )


def test_the_clock_goes_to_a_page_once_per_change() -> None:
    state = FleetState()
    assert state.clock_update(-1) == (0, None)
    state.set_clock(_clock(0.98))
    version, shown = state.clock_update(0) or (0, None)
    assert shown == {
        "rtf": 0.98, "target": 1.0, "behind_s": 0.0, "falling_behind": False, "paused": False, "lockstep": False,
    }  # fmt: skip
    assert state.clock_update(version) is None  # the page has it: frames leave it out
    state.set_clock(_clock(0.98))
    assert state.clock_update(version) is None  # the same clock again: no change
    state.set_clock(_clock(0.5, behind=3.04, falling=True))
    assert state.clock_update(version) == (version + 1, {**shown, "rtf": 0.5, "behind_s": 3.0, "falling_behind": True})
    state.set_clock(None)  # the daemon did not answer: the page stops showing a factor
    assert state.clock_update(version + 1) == (version + 2, None)


def _rtf(text: str) -> tuple[float, float]:
    m = re.search(r"RTF ([\d.]+) / ([\d.]+)", text)
    assert m, text
    return float(m.group(1)), float(m.group(2))


@pytest.mark.browser
def test_page_shows_the_real_time_factor_and_paused(
    daemon: Daemon, viewer_factory: Callable[..., Viewer], browser: Chromium
) -> None:
    c = daemon.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("tb3_1", 0.5, -2.0)
    v = viewer_factory(daemon)
    browser.navigate(v.url)
    # a daemon that keeps up: RTF near its target of 1, no warning
    keeps_up = f"/ 2 robots .* RTF (0\\.9\\d|1\\.0\\d) \\/ 1$/.test({STATUS})"
    text = browser.wait_for(f"{keeps_up} && {STATUS}", 20)
    rtf, target = _rtf(text)
    assert target == 1 and 0.9 < rtf < 1.1, text
    assert "falling behind" not in text and "behind" not in browser.evaluate(PILL)
    assert browser.evaluate("getComputedStyle(document.getElementById('status')).borderTopColor") != "rgb(255, 176, 32)"

    # paused: shown as paused, no factor, no warning
    c.pause()
    text = browser.wait_for(f"{STATUS}.includes('paused') && {STATUS}", 10)
    assert "RTF" not in text and browser.evaluate(PILL).split() == ["paused"]

    c.resume()  # and back
    browser.wait_for(f"{keeps_up} && {PILL} === ''", 15)


@pytest.mark.browser
def test_page_shows_a_daemon_falling_behind(
    daemon_factory: Callable[..., Daemon], viewer_factory: Callable[..., Viewer], browser: Chromium
) -> None:
    """--rtf 1000 with 50 robots: far more than 2 cores can keep (30 000 ticks a second)."""
    daemon = daemon_factory("--world", "empty", "--rtf", "1000")
    c = daemon.client()
    for i in range(50):
        c.spawn(f"r{i}", (i % 10) * 1.0, (i // 10) * 1.0)
    v = viewer_factory(daemon)
    browser.navigate(v.url)
    text = browser.wait_for(
        f"viewerStats.robots === 50 && {PILL}.split(' ').includes('behind') && {STATUS}.includes('falling behind')"
        f" && {STATUS}",
        30,
    )
    rtf, target = _rtf(text)
    assert target == 1000 and rtf < 900, text
    m = re.search(r"falling behind ([\d.]+) s", text)
    assert m and float(m.group(1)) > 0, text
    colour = browser.evaluate("getComputedStyle(document.getElementById('status')).borderTopColor")
    assert colour == "rgb(255, 176, 32)"  # amber
    top, right = browser.evaluate(
        "(r => [r.top, innerWidth - r.right])(document.getElementById('status').getBoundingClientRect())"
    )
    assert top < 40 and right < 400  # still the pill at the top right of the map
    # and it keeps growing: the clock goes on falling behind while it cannot keep up
    browser.wait_for(
        f"(m => m && Number(m[1]) > {float(m.group(1))})({STATUS}.match(/falling behind ([\\d.]+) s/))", 15
    )
