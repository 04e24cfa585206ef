"""coarse_to_fine: the order of the levels, and the start each one gets."""

from __future__ import annotations

import pytest

from face_tracking_ros.tracking.coarse_to_fine import coarse_to_fine

INF = float('inf')


def _solver(too_far: set[int]):
    """A level solver that adds 10^index to its start, or refuses the levels in ``too_far``."""
    calls: list[tuple[int, int, float]] = []

    def solve(index: int, start: int, first_step_limit: float) -> int | None:
        calls.append((index, start, first_step_limit))
        if index in too_far and first_step_limit < INF:
            return None
        return start + 10**index

    return solve, calls


@pytest.mark.parametrize(
    ('levels', 'first', 'restart_px', 'too_far', 'expected'),
    [
        # 0 always solves the coarsest level: 2, 1, 0, each from the one before.
        (3, 1, 0.0, set(), [(2, 0, INF), (1, 100, INF), (0, 110, INF)]),
        # On demand: level 1 first, with the limit in its own px; the coarsest never runs.
        (3, 1, 1.0, set(), [(1, 0, 0.5), (0, 10, INF)]),
        # Level 0 first: the limit as given.
        (3, 0, 1.0, set(), [(0, 0, 1.0)]),
        # The first level refuses: start over from the same start, level 0 from level 1 (the
        # limit in its own px), any other level from the coarsest, which is unlimited.
        (3, 1, 1.0, {1}, [(1, 0, 0.5), (2, 0, INF), (1, 100, INF), (0, 110, INF)]),
        (3, 0, 1.0, {0}, [(0, 0, 1.0), (1, 0, 1.0), (0, 10, INF)]),
        (
            4,
            0,
            1.0,
            {0, 1},
            [
                (0, 0, 1.0),
                (1, 0, 1.0),
                (3, 0, INF),
                (2, 1000, INF),
                (1, 1100, INF),
                (0, 1110, INF),
            ],
        ),
        (2, 0, 1.0, {0}, [(0, 0, 1.0), (1, 0, INF), (0, 10, INF)]),
        # A first level at or beyond the coarsest: the full solve.
        (2, 1, 1.0, set(), [(1, 0, INF), (0, 10, INF)]),
        (1, 1, 1.0, set(), [(0, 0, INF)]),
    ],
)
def test_levels_run_coarse_to_fine_with_the_coarser_ones_on_demand(
    levels, first, restart_px, too_far, expected
) -> None:
    solve, calls = _solver(too_far)
    result = coarse_to_fine(levels, first, restart_px, 0, solve)
    assert calls == expected
    assert result == expected[-1][1] + 1  # level 0 adds 10^0 to its start
