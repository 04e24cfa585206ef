"""MonoSolver's condition number of level 0's normal matrix (mono_kernels.condition_number)."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.tracking.mono_kernels import condition_number

# Unit diagonal, eigenvalues 0.5, 1 and 1.5 (by hand: [[1, .5], [.5, 1]] has 1 -+ 0.5).
CORRELATED = np.array([[1.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]])


def test_the_condition_is_the_largest_over_the_smallest_eigenvalue_after_jacobi_scaling() -> None:
    scale = np.diag([2.0, 30.0, 0.1])  # parameters of very different units
    assert condition_number(scale @ CORRELATED @ scale) == pytest.approx(1.5 / 0.5, rel=1e-12)
    assert condition_number(np.diag([4.0, 900.0, 0.01])) == pytest.approx(1.0, rel=1e-12)


def test_a_singular_normal_matrix_has_an_infinitecondition_number() -> None:
    """So is one that rounding left slightly indefinite (inf, not negative).

    A negative condition would pass the loss check's ``condition > max_condition``.
    """
    singular = np.array([[1.0, 1.0], [1.0, 1.0]])
    assert condition_number(singular) == float('inf')
    assert condition_number(singular - 1e-9 * np.eye(2)) == float('inf')
    assert condition_number(np.zeros((2, 2))) == float('inf')
