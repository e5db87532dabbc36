"""simd/nav/lanes.py: keep right in the corridors two cells wide, and nothing becomes unreachable."""

from __future__ import annotations

import os
from collections import deque

import numpy as np
import numpy.typing as npt
from hypothesis import event, given, settings
from hypothesis import strategies as st

from simd.core.mapworld import world_from_movingai
from simd.core.models import MODELS
from simd.core.movingai import parse_movingai
from simd.nav.cells import MOVES, CellGraph
from simd.nav.lanes import keep_right, lane_directions, reversed_moves

BURGER = MODELS["burger"]


def graph(rows: list[str], one_way: bool) -> CellGraph:
    text = f"type octile\nheight {len(rows)}\nwidth {len(rows[0])}\nmap\n" + "\n".join(rows).replace("#", "@")
    return CellGraph(world_from_movingai(parse_movingai(text, "t.map"), "t.map", 0.5), 0.5, one_way=one_way)


def arrows(rows: list[str]) -> list[str]:
    """The lanes drawn as the map is written (top row first): ^ v > < a lane, . none, # wall."""
    g = graph(rows, True)
    stand = g.standable(BURGER).reshape(g.height, g.width)
    v, h = lane_directions(stand)
    out = []
    for r in range(g.height - 1, -1, -1):
        out.append("".join(
            "#" if not stand[r, c] else "^" if v[r, c] > 0 else "v" if v[r, c] < 0 else
            ">" if h[r, c] > 0 else "<" if h[r, c] < 0 else "." for c in range(g.width)))  # fmt: skip
    return out


def test_the_lanes_of_a_warehouse_corner() -> None:
    rows = [
        "..........",
        "..........",
        "..####..##",
        "..........",
        "..####..##",
        "..####..##",
    ]
    assert arrows(rows) == [
        "..<<<<..<<",  # a corridor two wide along the top: the north lane goes west,
        "..>>>>..>>",  # the south lane east; where a corridor crosses, no lane
        "v^####v^##",  # two wide going down: the west lane south, the east lane north
        "v^....v^..",  # an aisle crossing a corridor: its lanes carry on across it
        "v^####v^##",
        "v^####v^##",
    ]


def test_one_cell_wide_and_open_floors_have_no_lanes() -> None:
    assert arrows(["#.#", "#.#", "#.#"]) == ["#.#", "#.#", "#.#"]
    assert arrows(["...", "...", "..."]) == ["...", "...", "..."]


def test_a_step_against_a_lane_is_gone_and_across_stays() -> None:
    g = graph(["####", "....", "....", "####"], True)  # a corridor two wide, west-east
    moves = g.moves(BURGER)
    east, west, north, south = MOVES.index((0, 1)), MOVES.index((0, -1)), MOVES.index((1, 0)), MOVES.index((-1, 0))
    south_lane, north_lane = 1 * g.width + 1, 2 * g.width + 1  # rows from the bottom: 1 south, 2 north
    assert moves[south_lane, east] and not moves[south_lane, west]
    assert moves[north_lane, west] and not moves[north_lane, east]
    assert moves[south_lane, north] and moves[north_lane, south]
    # the distance field to a goal behind a robot in the south lane goes round by the north lane
    goal = 1 * g.width + 0
    dist = g.distances(BURGER, goal)
    two_way = graph(["####", "....", "....", "####"], False).distances(BURGER, goal)
    assert dist[south_lane] > two_way[south_lane]
    assert np.isfinite(dist[g.standable(BURGER)]).all()


def test_moves_turned_around_twice_are_the_moves() -> None:
    g = graph(["......", "..##..", "......", "......"], True)
    moves = g.moves(BURGER)
    back = reversed_moves(moves, g.width, MOVES)
    np.testing.assert_array_equal(reversed_moves(back, g.width, MOVES), moves)
    for c, k in zip(*np.nonzero(back), strict=True):  # c + step k steps back to c
        dr, dc = MOVES[k]
        assert moves[c + dr * g.width + dc, MOVES.index((-dr, -dc))]


def reached(moves: npt.NDArray[np.bool_], width: int, start: int) -> set[int]:
    seen, todo = {start}, deque([start])
    while todo:
        c = todo.popleft()
        for k, (dr, dc) in enumerate(MOVES):
            if moves[c, k]:
                n = c + dr * width + dc
                if n not in seen:
                    seen.add(n)
                    todo.append(n)
    return seen


@st.composite
def floors(draw: st.DrawFn) -> list[str]:
    """Open floors with walls of random boxes: corridors of every width, two wide among them."""
    h, w = draw(st.integers(4, 12)), draw(st.integers(4, 12))
    grid = [["."] * w for _ in range(h)]
    for _ in range(draw(st.integers(0, 8))):
        r0, c0 = draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))
        r1, c1 = draw(st.integers(r0, min(h - 1, r0 + 5))), draw(st.integers(c0, min(w - 1, c0 + 5)))
        for r in range(r0, r1 + 1):
            for c in range(c0, c1 + 1):
                grid[r][c] = "@"
    grid[0][0] = "."  # a map needs a free cell
    return ["".join(row) for row in grid]


@settings(max_examples=int(os.environ.get("LANE_EXAMPLES", "150")), deadline=None)
@given(floors(), st.data())
def test_keeping_right_makes_nothing_unreachable(rows: list[str], data: st.DataObject) -> None:
    """From any cell, the one-way moves reach exactly the cells the two-way moves reach, and
    every one of them has a way back."""
    two = graph(rows, False)
    one = graph(rows, True)
    stand = np.flatnonzero(two.standable(BURGER))
    if not len(stand):
        return
    start = int(data.draw(st.sampled_from(stand.tolist())))
    vertical, horizontal = lane_directions(one.standable(BURGER).reshape(one.height, one.width))
    event("with lanes" if vertical.any() or horizontal.any() else "no lanes")
    both = reached(two.moves(BURGER), two.width, start)
    assert reached(one.moves(BURGER), one.width, start) == both
    back = reversed_moves(one.moves(BURGER), one.width, MOVES)
    assert reached(back, one.width, start) == both  # every cell reached reaches the start again
    dist = one.distances(BURGER, start)
    assert set(np.flatnonzero(np.isfinite(dist)).tolist()) == both


def test_keep_right_leaves_moves_without_lanes_alone() -> None:
    g = graph(["...", "...", "..."], False)  # an open floor: no corridor, no lane
    moves = g.moves(BURGER)
    np.testing.assert_array_equal(keep_right(g.standable(BURGER).reshape(3, 3), moves, MOVES), moves)
