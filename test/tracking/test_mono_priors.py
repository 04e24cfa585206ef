"""The alpha and sigma priors of the mono solve (tracking/mono_priors.py), by hand."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from face_tracking_ros.tracking.mono_kernels import prior_terms
from face_tracking_ros.tracking.mono_priors import Priors
from face_tracking_ros.tracking.projection import POSE_DIM


def test_costs_gradients_and_hessians_of_the_priors(model_factory) -> None:
    """Weight 2 on variances (a: 4, 1; s: 0.25): precisions 0.5, 2 and 8.

    At alpha (2, 1), sigma 0.5: cost 4 * 0.5 + 1 * 2 = 4, plus 0.25 * 8 = 2 while sigma is
    free; gradients (halved) (1, 2) and 4 (:func:`prior_terms` of the padded Hessians).
    """
    model = replace(
        model_factory(p=1, q=2),
        alpha_prior_covariance=np.diag([4.0, 1.0]),
        sigma_prior_covariance=np.array([[0.25]]),
    )
    priors = Priors.of(model, 2.0)
    alpha, sigma = np.array([2.0, 1.0]), np.array([0.5])
    cost, gradient = prior_terms(priors.hessian(False), alpha)
    assert cost == 4.0
    np.testing.assert_array_equal(gradient, [1.0, 2.0])
    cost, gradient = prior_terms(priors.hessian(True), np.concatenate((alpha, sigma)))
    assert cost == 6.0
    np.testing.assert_array_equal(gradient, [1.0, 2.0, 4.0])
    hessian = np.zeros((POSE_DIM + 3, POSE_DIM + 3))
    hessian[POSE_DIM:, POSE_DIM:] = np.diag([0.5, 2.0, 8.0])
    np.testing.assert_array_equal(priors.hessian(True), hessian)
    np.testing.assert_array_equal(priors.hessian(False), hessian[:-1, :-1])
