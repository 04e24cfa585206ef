"""Coarse-to-fine solving on an image pyramid, with the coarsest level solved on demand.

Both trackers solve each frame level by level, from a coarse level down to level 0, each level
starting where the one before ended. Started from a motion prediction, the coarsest level
seldom has anything left to do, so it can be skipped: the solve starts one level finer, and
only when that level's first step moves a node more than a threshold (the face is farther from
the start than that level reaches) does it start over from the coarsest level, from the same
start, which then gives exactly the full coarse-to-fine solve.
"""

from __future__ import annotations

from collections.abc import Callable
import math
from typing import TypeVar

T = TypeVar('T')

LevelSolver = Callable[[int, T, float], T | None]
"""``solve(index, start, first_step_limit)``: level ``index`` solved from ``start``, or None
when its first step would move a node more than ``first_step_limit`` px of that level."""


def coarse_to_fine(
    num_levels: int, coarsest_level_px: float, start: T, solve: LevelSolver[T]
) -> T:
    """Solve levels ``num_levels - 1`` to 0 from ``start``, the coarsest one on demand.

    Args:
        num_levels: pyramid levels (>= 1).
        coarsest_level_px: the coarsest level is solved only when the first step on the next
            one moves a node more than this, level px; 0 always solves it.
        start: where the first level starts.
        solve: one level's solver (:data:`LevelSolver`).

    Returns:
        Level 0's solution.
    """
    coarsest = num_levels - 1
    trigger = coarsest_level_px or math.inf
    index = coarsest - 1 if coarsest > 0 and trigger < math.inf else coarsest
    point = start
    while index >= 0:
        solved = solve(index, point, trigger if index == coarsest - 1 else math.inf)
        if solved is None:  # too far for this level: start over from the coarsest
            index, trigger = coarsest, math.inf
            continue
        point, index = solved, index - 1
    return point
