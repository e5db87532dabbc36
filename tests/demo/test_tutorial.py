"""docs/tutorial.md, run as a reader runs it: every command block in order, real processes
(tmux for the teleops, headless Chromium for the viewer), each command's output checked
against the page's sample (the conventions: tests/demo/tutorial_page.py). The README's
``./demo`` output and teleop screen are checked against the same run."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.cdp import CHROMIUM
from tests.conftest import ROOT
from tests.demo.tutorial_page import PAGE, TMUX, VENV_BIN, parse, run_page, sample_pattern, unmatched

README = ROOT / "README.md"


def readme_samples() -> dict[str, str]:
    """The README's blocks marked ``<!-- tutorial-sample: TERMINAL -->``: what the tutorial's
    terminal of that name printed (or showed) in the same run."""
    found = {}
    for m in re.finditer(r"<!-- tutorial-sample: (\w+) -->\s*\n\s*```\w*\n(.*?)\n\s*```", README.read_text(), re.S):
        found[m.group(1)] = m.group(2)
    return found


def test_samples_match_numbers_and_ellipses_but_not_words() -> None:
    sample = "fleet-map: wrote a.yaml: 186x164 cells, ... scans\n\n...\nTB3_2: reached (-1.29, 1.46)"
    out = "noise\nfleet-map: wrote a.yaml: 190x160 cells, 12 scans from 1 robot\nx\nTB3_2: reached (0.5, -2.00)\n"
    assert unmatched(sample, out) is None
    assert unmatched(sample, out.replace("reached", "failed")) == "TB3_2: reached (-1.29, 1.46)"
    assert unmatched("b\na", "a\nb") == "a"  # in order
    assert sample_pattern("x  -1.8 m").pattern == r"x\s+[-+]?\d+(?:\.\d+)?\s+m"


def test_the_page_uses_only_known_steps_and_every_command_has_a_terminal_to_stop() -> None:
    steps = parse(PAGE.read_text())
    kinds = {s.kind for s in steps}
    assert kinds <= {"run", "background", "tmux", "file", "keys", "stop", "wait", "browser", "picture", "shown"}
    assert sum(s.kind == "run" for s in steps) >= 8 and "tmux" in kinds and "browser" in kinds
    assert set(readme_samples()) == {"demo", "teleop"}


@pytest.mark.slow
@pytest.mark.browser
@pytest.mark.skipif(TMUX is None, reason="tmux is not installed (./test installs it when run as root)")
@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (./test installs it when run as root)")
@pytest.mark.skipif(not (VENV_BIN / "fleet-view").exists(), reason="no fleet-view beside this python")
def test_the_tutorial_runs_as_written(tmp_path: Path) -> None:
    checkout = tmp_path / "checkout"
    checkout.mkdir()
    run = run_page(checkout)
    printed = {s.args[0]: out for s, out in run.outputs if s.kind in ("background", "tmux")}
    for name, sample in readme_samples().items():
        miss = unmatched(sample, printed[name])
        assert miss is None, (
            f"README.md: the {name} sample line {miss!r} is not in the tutorial's run:\n{printed[name]}"
        )
