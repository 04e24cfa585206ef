"""MonoSolver's condition number of level 0's normal matrix (mono_solve._condition)."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.tracking.mono_solve import _condition

# Unit diagonal, eigenvalues 0.5, 1 and 1.5 (by hand: [[1, .5], [.5, 1]] has 1 -+ 0.5).
CORRELATED = np.array([[1.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]])


def test_the_condition_is_the_largest_over_the_smallest_eigenvalue_after_jacobi_scaling() -> None:
    scale = np.diag([2.0, 30.0, 0.1])  # parameters of very different units
    assert _condition(scale @ CORRELATED @ scale) == pytest.approx(1.5 / 0.5, rel=1e-12)
    assert _condition(np.diag([4.0, 900.0, 0.01])) == pytest.approx(1.0, rel=1e-12)


def test_a_singular_normal_matrix_has_an_infinite_condition() -> None:
    """So is one that rounding left slightly indefinite (inf, not negative).

    A negative condition would pass the loss check's ``condition > max_condition``.
    """
    singular = np.array([[1.0, 1.0], [1.0, 1.0]])
    assert _condition(singular) == float('inf')
    assert _condition(singular - 1e-9 * np.eye(2)) == float('inf')
    assert _condition(np.zeros((2, 2))) == float('inf')
