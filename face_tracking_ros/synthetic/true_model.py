"""The synthetic population's own face model: what a perfect learner would give (eq. 3).

Trackers and recognisers are tested and benchmarked against it, so that their errors are not
mixed with the learner's.
"""

from __future__ import annotations

import numpy as np

from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.synthetic.faces import FacePopulation

EXPRESSION_STD = 0.5  # standard deviation of expression intensities assumed for the alpha prior


def true_face_model(population: FacePopulation, num_nodes: int = 34, p: int = 4) -> FaceModel:
    """The population's true model as a FaceModel.

    Shape basis: the top-p principal identity axes; action basis: the orthonormalised span of the
    expression displacements; priors (§4.1): the true identity covariance and that of
    expressions with intensities of standard deviation 0.5, both expressed in these bases.

    Args:
        population: the synthetic population.
        num_nodes: 19 or 34.
        p: identity dimension.
    """
    truth = population.truth(num_nodes)
    identity = truth.identity_basis * np.sqrt(truth.identity_variances)
    shape_basis = np.linalg.svd(identity, full_matrices=False)[0][:, :p]
    expressions = EXPRESSION_STD * truth.expression_basis
    action_basis = np.linalg.svd(expressions, full_matrices=False)[0]
    sigma_covariance = shape_basis.T @ identity @ identity.T @ shape_basis
    alpha_covariance = action_basis.T @ expressions @ expressions.T @ action_basis
    return FaceModel.from_prior_covariances(
        node_names=truth.node_names,
        mean_shape=truth.mean_shape.copy(),
        shape_basis=shape_basis,
        action_basis=action_basis,
        sigma_prior_covariance=sigma_covariance,
        alpha_prior_covariance=alpha_covariance,
        method='truth',
    )
