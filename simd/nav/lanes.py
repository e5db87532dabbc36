"""Keep right: one-way lanes in the corridors two cells wide of a grid map.

In a warehouse, the corridors around the blocks of shelves are two robots wide. With traffic
both ways in both lanes, robots meet head-on and, once a corridor fills, nobody can move: a
gridlock that priorities cannot undo (two robots facing each other in a full corridor have
nowhere to go). Road traffic solved it long ago: each direction has its lane. Here, in a
corridor two cells wide, the robots drive on the right: in a vertical one, the east lane
goes north and the west lane south; in a horizontal one, the south lane goes east and the
north lane west. Changing lanes (a step across) is always allowed, so is entering or leaving
a corridor in any direction, and the crossings of corridors stay free; only a step along a
lane against its direction is removed (and a diagonal across the corridor into the other lane
against it).

Every cell stays reachable from every cell it was reachable from: a step removed has a way
around through the other lane (across, along, across), which is why a cell counts as a lane
only when its partner across the corridor is there too.

The grid: ``stand`` is (rows, cols), row 0 at the smallest y (north is +row), as
simd/nav/cells.py lays cells out; moves are over its :data:`~simd.nav.cells.MOVES`.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

B2 = npt.NDArray[np.bool_]
I8 = npt.NDArray[np.int8]


def _shifted(a: B2, dr: int, dc: int) -> B2:
    """``a`` at (r + dr, c + dc) for every (r, c); False off the grid."""
    h, w = a.shape
    p = np.zeros((h + 4, w + 4), dtype=bool)
    p[2:-2, 2:-2] = a
    return p[2 + dr : 2 + dr + h, 2 + dc : 2 + dc + w]


def lane_directions(stand: B2) -> tuple[I8, I8]:
    """Per cell: the direction of its vertical lane (+1 north, -1 south, 0 none) and of its
    horizontal lane (+1 east, -1 west, 0 none)."""

    def pairs(s: B2, along_r: int, along_c: int) -> tuple[B2, B2]:
        # a two-wide run across (dr, dc) = (along_r, along_c) rotated: first / second of the pair
        ar, ac = along_c, along_r  # the across direction
        first = s & _shifted(s, ar, ac) & ~_shifted(s, 2 * ar, 2 * ac) & ~_shifted(s, -ar, -ac)
        second = _shifted(first, -ar, -ac)
        # a one-cell gap in the corridor (an aisle crossing it) carries the lanes on, if both sides do
        gap = ~first & s & _shifted(s, ar, ac) & ~_shifted(first, ar, ac)
        inherited = (
            gap
            & _shifted(first, along_r, along_c) & _shifted(first, -along_r, -along_c)
            & _shifted(second, along_r + ar, along_c + ac) & _shifted(second, -along_r + ar, -along_c + ac)
        )  # fmt: skip
        first = first | inherited
        second = second | _shifted(inherited, -ar, -ac)
        return first, second

    # vertical corridors: pairs across columns; west (first) goes south, east goes north
    west, east = pairs(stand, 1, 0)
    vertical = np.zeros(stand.shape, dtype=np.int8)
    vertical[west] = -1
    vertical[east] = 1
    vertical[west & east] = 0  # a cell in two pairs is a crossing
    # horizontal corridors: pairs across rows; south (first) goes east, north goes west
    south, north = pairs(stand, 0, 1)
    horizontal = np.zeros(stand.shape, dtype=np.int8)
    horizontal[south] = 1
    horizontal[north] = -1
    horizontal[south & north] = 0
    return vertical, horizontal


def keep_right(stand: B2, moves: npt.NDArray[np.bool_], steps: tuple[tuple[int, int], ...]) -> npt.NDArray[np.bool_]:
    """``moves`` (cells, len(steps)) without the steps against a lane: from a lane cell into a
    lane cell of the same kind, with a part along it opposite to the destination's direction."""
    vertical, horizontal = lane_directions(stand)
    h, w = stand.shape
    v, hz = vertical.ravel(), horizontal.ravel()
    out = moves.copy()
    idx = np.arange(h * w)
    for k, (dr, dc) in enumerate(steps):
        can = np.flatnonzero(out[:, k])
        if not len(can):
            continue
        n = idx[can] + dr * w + dc
        against = np.zeros(len(can), dtype=bool)
        # only within one corridor: along its lane (the same lane at both ends), or a diagonal
        # across it (into the partner's lane); two corridors' lanes that touch are not one road
        if dr:  # vertical lanes: a west lane's partner is the next column east, and back
            same = (v[n] == v[can]) if dc == 0 else (v[n] == -v[can]) & (v[can] == -dc)
            against |= (v[can] != 0) & (v[n] == -dr) & same
        if dc:  # horizontal lanes: a south lane's partner is the next row north, and back
            same = (hz[n] == hz[can]) if dr == 0 else (hz[n] == -hz[can]) & (hz[can] == dr)
            against |= (hz[can] != 0) & (hz[n] == -dc) & same
        out[can[against], k] = False
    return out


def reversed_moves(
    moves: npt.NDArray[np.bool_], width: int, steps: tuple[tuple[int, int], ...]
) -> npt.NDArray[np.bool_]:
    """The moves turned around: (cells, len(steps)), True at [c, k] when a robot at c + step k
    may step to c (by the opposite step). A distance field *to* a goal over one-way moves is a
    search from the goal over these."""
    n = len(moves)
    out = np.zeros_like(moves)
    opposite = [steps.index((-dr, -dc)) for dr, dc in steps]
    idx = np.arange(n)
    for k, (dr, dc) in enumerate(steps):
        src = idx + dr * width + dc  # the cell a robot comes from
        rows, cols = np.divmod(idx, width)
        inside = (rows + dr >= 0) & (rows + dr < n // width) & (cols + dc >= 0) & (cols + dc < width)
        ok = np.zeros(n, dtype=bool)
        ok[inside] = moves[src[inside], opposite[k]]
        out[:, k] = ok
    return out
