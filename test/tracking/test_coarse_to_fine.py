"""coarse_to_fine: the order of the levels, and the start each one gets."""

from __future__ import annotations

import pytest

from face_tracking_ros.tracking.coarse_to_fine import coarse_to_fine


def _solver(too_far: set[int]):
    """A level solver that adds 10^index to its start, or refuses the levels in ``too_far``."""
    calls: list[tuple[int, int, float]] = []

    def solve(index: int, start: int, first_step_limit: float) -> int | None:
        calls.append((index, start, first_step_limit))
        if index in too_far and first_step_limit < float('inf'):
            return None
        return start + 10**index

    return solve, calls


@pytest.mark.parametrize(
    ('levels', 'limit', 'too_far', 'expected'),
    [
        # 0 always solves the coarsest level: 2, 1, 0, each from the one before.
        (3, 0.0, set(), [(2, 0, float('inf')), (1, 100, float('inf')), (0, 110, float('inf'))]),
        # On demand: level 1 first, with the limit; the coarsest never runs.
        (3, 0.5, set(), [(1, 0, 0.5), (0, 10, float('inf'))]),
        # Level 1 refuses: start over from the coarsest, from the same start, without a limit.
        (
            3,
            0.5,
            {1},
            [(1, 0, 0.5), (2, 0, float('inf')), (1, 100, float('inf')), (0, 110, float('inf'))],
        ),
        # One level: nothing to skip.
        (1, 0.5, set(), [(0, 0, float('inf'))]),
    ],
)
def test_levels_run_coarse_to_fine_with_the_coarsest_on_demand(
    levels, limit, too_far, expected
) -> None:
    solve, calls = _solver(too_far)
    result = coarse_to_fine(levels, limit, 0, solve)
    assert calls == expected
    assert result == expected[-1][1] + 1  # level 0 adds 10^0 to its start
