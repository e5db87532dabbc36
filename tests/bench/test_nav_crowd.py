"""bench/nav_crowd.py runs, pools and repeats itself: a small crowd, a few seconds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import nav_crowd


def test_a_small_crowd_reaches_goals_and_a_seed_repeats(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "crowd.json"
    assert nav_crowd.main(["--robots", "3", "--seeds", "2", "--seconds", "60", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "3 robots, turtlebot3_world, seeds 1-2 x 60 s:" in printed and "p50" in printed
    runs = json.loads(out.read_text())
    assert [r["seed"] for r in runs] == [1, 2]
    assert all(len(r["ratios"]) >= 3 for r in runs)  # each burger reaches goals in a minute
    assert all(ratio >= 1.0 for r in runs for ratio in r["ratios"])  # never under the straight line
    assert min(r["closest_m"] for r in runs) > 0.2  # no two burgers' bodies meet
    for r in runs:  # where each goal's time went: states that add up to the goal's time
        for ratio, parts in zip(r["ratios"], r["parts"], strict=True):
            spent = {k: v for k, v in parts.items() if k != "bound"}
            assert set(spent) <= {"planning", "moving", "turning", "standing", "waiting", "yielding", "blocked"}
            assert sum(spent.values()) == pytest.approx(ratio * parts["bound"], abs=0.07)
    assert "goals within 0.1 of the median" in printed and "all reached goals" in printed
    for r in runs:  # the waiting, by what the robot did and whom it waited for
        assert set(r["waits"]) <= {
            "drives meanwhile", "stands behind one with no goal", "stands behind one driving out of its cell",
            "stands behind one driving through", "stands behind one making way", "stands behind one waiting itself",
            "stands behind one turning", "stands behind one standing",
        }  # fmt: skip
        waited = sum(parts.get("waiting", 0.0) for parts in r["parts"])  # (reached goals' part of it)
        assert sum(r["waits"].values()) >= waited - 1e-6
    assert "waiting (" in printed
    for r in runs:  # the time lost against the bound, by what the robot did (waiting: whom for)
        causes = {"planning", "moving at top speed", "moving slower", "turning", "standing", "yielding", "blocked"}
        assert set(r["lost"]) <= causes | {f"waiting: {why}" for why in r["waits"]}
        # summed: what each goal reached took over its bound (less up to its tolerance at top
        # speed, 0.1 m / 0.22 m/s: reached short of the point), and for the three goals under
        # way at the end, at most their time so far and at least that less their length (5 m)
        over = sum((ratio - 1.0) * parts["bound"] for ratio, parts in zip(r["ratios"], r["parts"], strict=True))
        reached = len(r["ratios"])
        assert over - reached * 0.1 / 0.22 - 3 * 5.0 / 0.22 - 0.5 <= sum(r["lost"].values()) <= over + 3 * 60.0
    assert "time lost against the bound" in printed
    again = nav_crowd.run_seed("turtlebot3_world", 3, 60.0, 1)
    assert again.ratios == runs[0]["ratios"]  # lockstep, seeded: the same goals in the same times


def test_seeds_from_a_first_one_in_two_processes_are_the_seeds_run_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "crowd.json"
    args = ["--robots", "2", "--seconds", "30", "--first-seed", "25", "--seeds", "2", "--jobs", "2", "--out", str(out)]
    assert nav_crowd.main(args) == 0
    assert "2 robots, turtlebot3_world, seeds 25-26 x 30 s:" in capsys.readouterr().out
    runs = json.loads(out.read_text())
    assert [r["seed"] for r in runs] == [25, 26]
    assert runs[1]["ratios"] == nav_crowd.run_seed("turtlebot3_world", 2, 30.0, 26).ratios


@pytest.mark.parametrize("bad", [["--robots", "0"], ["--jobs", "0"], ["--seeds", "0"]])
def test_bad_arguments_are_one_line(bad: list[str]) -> None:
    with pytest.raises(SystemExit) as e:
        nav_crowd.main(bad)
    assert e.value.code == 2
