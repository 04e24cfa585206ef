"""Coarse-to-fine solving on an image pyramid, with the coarser levels solved on demand.

Both trackers solve each frame level by level, from a coarse level down to level 0, each level
starting where the one before ended. Started from a motion prediction, the coarse levels often
have little left to do, so they can be skipped: the solve starts on a finer level, and only
when that level's first step moves a node more than a threshold (the face is farther from the
start than that level reaches) does it start over from the same start: level 0 hands over to
level 1, which reaches twice as far (the same threshold in its own pixels), and any other level
to the coarsest, which has no threshold, so starting over there gives exactly the full
coarse-to-fine solve. The first level's threshold is in pixels of level 0 (the error of a
prediction).
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
    num_levels: int, first_level: int, restart_px: float, start: T, solve: LevelSolver[T]
) -> T:
    """Solve levels ``first_level`` to 0 from ``start``; the coarser ones on demand.

    Args:
        num_levels: pyramid levels (>= 1).
        first_level: the level solved first (clipped to the coarsest).
        restart_px: start over when the first step on ``first_level`` moves a node more than
            this, px of level 0: from level 1 if that was level 0 (its first step limited to
            this in px of level 1), else from the coarsest; 0 always starts from the coarsest.
        start: where the first level starts, and every start-over.
        solve: one level's solver (:data:`LevelSolver`).

    Returns:
        Level 0's solution.
    """
    coarsest = num_levels - 1
    index = min(first_level, coarsest) if restart_px > 0 else coarsest
    limit = restart_px / (1 << index)
    point = start
    while index >= 0:
        solved = solve(index, point, limit if index < coarsest else math.inf)
        if solved is None:  # too far for this level: start over from a coarser one
            index, limit = (1, restart_px) if index == 0 else (coarsest, math.inf)
            continue
        point, index, limit = solved, index - 1, math.inf
    return point
