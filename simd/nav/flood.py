"""Which cells a robot can reach at all: a flood fill on a grid of traversable cells.

A robot moves to its 4 orthogonal neighbours and, with ``diagonal``, to the 4 diagonal ones,
but only when both orthogonal cells the diagonal passes are traversable (no cutting a blocked
corner). A breadth-first front in numpy, written apart from the planners, so that tests can
use it as the oracle of whether a path exists, and callers (the benchmark) to draw goals a
robot can reach.
"""

from __future__ import annotations

import operator

import numpy as np
import numpy.typing as npt

__all__ = ["reachable"]

Mask = npt.NDArray[np.bool_]
#: (row step, col step) of the diagonal moves
DIAGONAL_MOVES = ((-1, -1), (-1, 1), (1, -1), (1, 1))


def reachable(traversable: Mask, start: tuple[int, int], *, diagonal: bool = True) -> Mask:
    """The cells a robot at ``start`` can reach under the move rules above (start included),
    as a mask of ``traversable``'s shape; all False when ``start`` itself is blocked."""
    grid = checked_mask(traversable)
    rows, cols = grid.shape
    r, c = cell("start", start, grid.shape)
    width: int = cols + 2
    padded = np.zeros((rows + 2, width), dtype=bool)
    padded[1:-1, 1:-1] = grid
    free = padded.ravel()
    seen = np.zeros_like(free)
    first = (r + 1) * width + c + 1
    front = np.array([first] if free[first] else [], dtype=np.intp)
    seen[front] = True
    while front.size:  # one breadth-first layer a turn
        found = [front + step for step in (-width, width, -1, 1)]
        if diagonal:
            for dr, dc in DIAGONAL_MOVES:
                past_corner = front[free[front + dr * width] & free[front + dc]]
                found.append(past_corner + dr * width + dc)
        near = np.concatenate(found)
        near = np.unique(near[free[near] & ~seen[near]])
        seen[near] = True
        front = near
    reached: Mask = seen.reshape(rows + 2, width)[1:-1, 1:-1].copy()
    return reached


def checked_mask(traversable: Mask) -> Mask:
    """``traversable`` if it is a 2-D bool array, else ValueError."""
    if not isinstance(traversable, np.ndarray) or traversable.dtype != np.bool_ or traversable.ndim != 2:
        raise ValueError("traversable must be a 2-D bool array")
    return traversable


def cell(name: str, where: tuple[int, int], shape: tuple[int, ...]) -> tuple[int, int]:
    """(row, col) of ``where`` as ints, or ValueError when it lies outside a grid of ``shape``."""
    r, c = (operator.index(v) for v in where)
    if not (0 <= r < shape[0] and 0 <= c < shape[1]):
        raise ValueError(f"{name} {(r, c)} lies outside the {shape[0]}x{shape[1]} grid")
    return r, c
