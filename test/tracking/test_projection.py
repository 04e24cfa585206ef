"""Analytic Jacobians of eq. 1-3 against finite differences, and the surface patches."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.tracking.projection import photometric_jacobian, project_with_jacobian
from face_tracking_ros.tracking.surface_patches import (
    node_frames,
    patch_basis,
    surface_patch_offsets,
)

CAMERA = PinholeCamera.ideal()
OMEGA = np.array([0.15, -0.35, 0.1])
T = np.array([0.02, -0.01, 0.6])


def _setup() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    points = rng.normal(0.0, 0.05, (4, 5, 3))
    basis = rng.normal(0.0, 1.0, (4, 3, 2))
    coefficients = np.array([0.01, -0.02])
    return points, basis, coefficients


def _pixels(params: np.ndarray, points: np.ndarray, basis: np.ndarray) -> np.ndarray:
    moved = points + (basis @ params[6:])[:, None, :]
    return project_with_jacobian(CAMERA, params[:3], params[3:6], moved).pixels


def test_projection_jacobian_matches_finite_differences() -> None:
    points, basis, coefficients = _setup()
    params = np.concatenate([OMEGA, T, coefficients])
    moved = points + (basis @ coefficients)[:, None, :]
    analytic = project_with_jacobian(CAMERA, OMEGA, T, moved, basis[:, None]).jacobian
    assert analytic.shape == (4, 5, 2, 8)
    step = 1e-7
    numeric = np.stack(
        [
            (_pixels(params + e, points, basis) - _pixels(params - e, points, basis)) / (2 * step)
            for e in np.eye(8) * step
        ],
        axis=-1,
    )
    assert np.abs(numeric - analytic).max() < 1e-4 * np.abs(analytic).max()


def test_photometric_jacobian_is_the_gradient_contracted_chain_rule() -> None:
    points, basis, _ = _setup()
    gradient = np.random.default_rng(1).normal(0.0, 10.0, (4, 5, 2))
    projection = project_with_jacobian(CAMERA, OMEGA, T, points, basis[:, None])
    expected = np.einsum('nma,nmap->nmp', gradient, projection.jacobian)
    rotated = (projection.points_cam - T).transpose(2, 0, 1)
    actual = photometric_jacobian(CAMERA, OMEGA, rotated, T, gradient.transpose(2, 0, 1), basis)
    assert actual.shape == (8, 4, 5)
    assert np.abs(actual - expected.transpose(2, 0, 1)).max() < 1e-9 * np.abs(expected).max()
    no_basis = photometric_jacobian(CAMERA, OMEGA, rotated, T, gradient.transpose(2, 0, 1))
    assert np.array_equal(no_basis, actual[:6])
    # A linear map of each node's samples (a photometric projection) maps every row alike.
    mixing = np.random.default_rng(2).normal(size=(4, 5, 5))

    def project(rows: np.ndarray) -> np.ndarray:
        return np.einsum('nml,jnl->jnm', mixing, rows)

    mapped = photometric_jacobian(
        CAMERA, OMEGA, rotated, T, gradient.transpose(2, 0, 1), basis, project
    )
    assert np.abs(mapped - project(actual)).max() < 1e-9 * np.abs(expected).max()


def test_node_frames_are_orthonormal_and_face_the_camera() -> None:
    topology = mesh_topology(34)
    frames = node_frames(topology.reference_shape, topology.triangles)
    assert frames.shape == (34, 3, 3)
    assert np.allclose(frames @ frames.transpose(0, 2, 1), np.eye(3), atol=1e-12)
    assert np.all(frames[:, 2, 2] < 0)  # normals towards -z (a frontal camera)
    assert np.all(frames[:, 0, 0] > 0.5) and np.all(frames[:, 1, 1] > 0.5)
    # (x, y, -n) is right-handed like the face frame, so grids keep a frontal view's orientation.
    assert np.allclose(np.linalg.det(frames), -1.0)
    # Face-edge normals turn outwards: the right temple's normal points to the subject's right.
    assert frames[topology.index('right_temple'), 2, 0] < -0.3
    # A flat mesh has the normal -z everywhere.
    flat = topology.reference_shape * [1, 1, 0]
    assert np.allclose(node_frames(flat, topology.triangles)[:, 2], [0, 0, -1])


def test_node_frames_reject_an_isolated_node() -> None:
    topology = mesh_topology(19)
    with pytest.raises(InputError, match=r'nodes \[18\] belong to no triangle'):
        node_frames(
            topology.reference_shape, topology.triangles[~np.any(topology.triangles == 18, 1)]
        )


def test_surface_patch_offsets_lie_on_the_thin_plate_surface() -> None:
    topology = mesh_topology(34)
    shape = topology.reference_shape
    right_eye, nose_tip = topology.index('right_eye'), topology.index('nose_tip')
    to_nose = shape[nose_tip, :2] - shape[right_eye, :2]
    grid = np.array([[0.0, 0.0], [0.002, 0.001], to_nose])
    offsets = surface_patch_offsets(shape, grid)
    assert offsets.shape == (34, 3, 3)
    assert np.allclose(offsets[..., :2], np.broadcast_to(grid, (34, 3, 2)), atol=1e-15)
    assert np.abs(offsets[:, 0]).max() < 1e-12  # the node itself
    # The surface interpolates the nodes: from the right eye, the nose tip's (x, y) lands on it.
    assert np.allclose(shape[right_eye] + offsets[right_eye, 2], shape[nose_tip], atol=1e-9)
    # A flat mesh gives a flat surface.
    flat = surface_patch_offsets(shape * [1, 1, 0], grid)
    assert np.abs(flat[..., 2]).max() < 1e-12


def test_patch_basis_carries_node_motion_to_the_samples() -> None:
    topology = mesh_topology(34)
    shape = topology.reference_shape
    grid = np.array([[0.0, 0.0], [0.003, -0.002], [-0.004, 0.004]])
    offsets = surface_patch_offsets(shape, grid)
    rng = np.random.default_rng(0)
    # Column 0 moves every node the same affine way (a stretch plus a shift): every sample
    # follows it exactly. Column 1 moves one node only: the samples around it follow partly.
    affine = np.array([[0.1, 0.02, 0.0], [0.0, -0.05, 0.0], [0.03, 0.01, 0.0]])
    stretch = shape @ affine.T + [0.001, -0.002, 0.0005]
    lip = topology.index('lower_lip')
    single = np.zeros_like(shape)
    single[lip] = rng.normal(size=3) * 0.003
    basis = np.stack([stretch, single], axis=-1)  # (N, 3, 2)
    dense = patch_basis(shape, offsets, basis)
    assert dense.shape == (34, 3, 3, 2)
    samples = shape[:, None, :] + offsets
    expected = samples @ affine.T + [0.001, -0.002, 0.0005] - stretch[:, None, :]
    assert np.allclose(dense[..., 0], expected, atol=1e-12)
    assert np.abs(dense[:, 0]).max() < 1e-12  # a node's own sample moves with the node
    # Samples near the lip node move towards its motion, those of far nodes hardly at all.
    near = dense[lip, 1:, :, 1] + single[lip]
    assert np.all(np.einsum('ma,a->m', near, single[lip]) > 0.3 * single[lip] @ single[lip])
    far = topology.index('left_brow_outer')
    assert np.abs(dense[far, :, :, 1]).max() < 0.1 * np.abs(single[lip]).max()
