"""Fixtures of the tracking tests: small face models and textured images with known truth."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import pytest

from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.synthetic.true_model import true_face_model

ModelFactory = Callable[..., FaceModel]


def make_model(
    num_nodes: int = 34, p: int = 3, q: int = 4, planar: bool = False, seed: int = 0
) -> FaceModel:
    """A face model on the reference mesh with smooth random orthonormal bases.

    Identity modes move nodes by about 5 mm RMS at one standard deviation, expression modes by
    about 3 mm. ``planar`` flattens the mean shape to z = 0 (a fronto-parallel face).
    """
    rng = np.random.default_rng(seed)
    reference = mesh_topology(num_nodes).reference_shape.copy()
    if planar:
        reference[:, 2] = 0.0
    # Smooth fields: random low-order polynomials of the reference (x, y).
    xy = reference[:, :2] / 0.1
    features = np.column_stack([np.ones(num_nodes), xy, xy**2, xy[:, :1] * xy[:, 1:]])
    fields = np.stack([(features @ rng.normal(size=(6, 3))).ravel() for _ in range(p + q)], axis=1)
    basis, _ = np.linalg.qr(fields)
    shape_basis, action_basis = basis[:, :p], basis[:, p:]
    node_rms = np.sqrt(num_nodes)
    shape_var = (0.005 * node_rms) ** 2 * np.linspace(1.0, 0.3, p)
    action_var = (0.003 * node_rms) ** 2 * np.linspace(1.0, 0.5, q)
    return FaceModel(
        node_names=mesh_topology(num_nodes).node_names,
        mean_shape=reference.ravel(),
        shape_basis=shape_basis,
        action_basis=action_basis,
        shape_eigenvalues=shape_var,
        action_eigenvalues=action_var,
        sigma_prior_covariance=np.diag(shape_var),
        alpha_prior_covariance=np.diag(action_var),
    )


def make_texture(height: int = 480, width: int = 640, seed: int = 0) -> np.ndarray:
    """A smooth random (H, W) float32 texture in [30, 220] with detail at several scales."""
    rng = np.random.default_rng(seed)
    texture = np.zeros((height, width), np.float32)
    for blur, weight in ((1.5, 0.5), (4.0, 1.0), (12.0, 1.0)):
        noise = rng.standard_normal((height, width)).astype(np.float32)
        layer = cv2.GaussianBlur(noise, (0, 0), blur)
        texture += weight * layer / layer.std()
    texture -= texture.min()
    return (30.0 + 190.0 * texture / texture.max()).astype(np.float32)


@pytest.fixture
def model_factory() -> ModelFactory:
    """:func:`make_model`."""
    return make_model


@pytest.fixture
def texture_factory() -> Callable[..., np.ndarray]:
    """:func:`make_texture`."""
    return make_texture


@pytest.fixture
def true_model_factory() -> Callable[..., FaceModel]:
    """:func:`face_tracking_ros.synthetic.true_model.true_face_model`."""
    return true_face_model
