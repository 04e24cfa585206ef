"""RoiLayout.patch_coordinates and roi, and Params.updated (tracking/mono_rois.py), by hand."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.imaging import square_offsets
from face_tracking_ros.model.topology import Group
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.mono_rois import Params, RoiLayout
from face_tracking_ros.tracking.surface_patches import ThinPlate, patch_basis, patch_interpolation


def test_coarser_levels_reach_twice_as_far_each_held_at_the_level_0_roi_edge(
    model_factory,
) -> None:
    """An inner node's sample 1 step right of centre (h = 4): 0.25 of the half-width on level 0.

    By hand: 0.5 on level 1, 1.0 on level 2, and 2.0 held at the ROI's edge, 1.0, on level 3;
    the corner sample (4, -4) stays at (1, -1) on every level.
    """
    model = model_factory()
    config = MonoTrackerConfig(patch_half_size=4)
    grid = square_offsets(4)
    layout = RoiLayout(model, 600.0, grid, config)
    inner = int(np.flatnonzero(~model.topology.group_mask(Group.EDGE))[0])
    steps = layout.grid(model.shape())
    right = int(np.flatnonzero((grid[:, 0] == 1) & (grid[:, 1] == 0))[0])
    corner = int(np.flatnonzero((grid[:, 0] == 4) & (grid[:, 1] == -4))[0])
    for level, expected in enumerate((0.25, 0.5, 1.0, 1.0)):
        coordinates = layout.patch_coordinates(steps, level)[inner]
        np.testing.assert_allclose(coordinates[right], [expected, 0.0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(coordinates[corner], [1.0, -1.0], rtol=0, atol=1e-12)


def test_a_skin_depth_moves_the_samples_and_carries_their_bases(model_factory) -> None:
    """2 mm of skin depth plus 1 mm times u^2 moves every sample by 2 + u^2 mm along its ray.

    The bases that move the samples with alpha and sigma are carried to where they moved: the
    thin-plate interpolation's at the moved samples, on every level, not the surface's.
    """
    model = model_factory()
    layout = RoiLayout(model, 600.0, square_offsets(4), MonoTrackerConfig())
    q, p = model.action_basis_nodes().shape[2], model.shape_basis_nodes().shape[2]
    params = Params(np.zeros(3), np.array([0.0, 0.0, 0.6]), np.zeros(q), np.zeros(p))
    depth = np.zeros((model.num_nodes, 6))
    depth[:, 0], depth[:, 3] = 0.002, 0.001
    u = layout.patch_coordinates(layout.grid(model.shape()), 0)[..., 0]
    surface = layout.at(params)
    for level in range(4):
        on_skin, on_surface = layout.roi(surface, level, depth), layout.roi(surface, level)
        if level == 0:
            moved = np.linalg.norm(on_skin.offsets - on_surface.offsets, axis=0)
            np.testing.assert_allclose(moved, 0.002 + 0.001 * u**2, rtol=0, atol=1e-8)
        weights = patch_interpolation(
            ThinPlate.through(model.shape()), on_skin.offsets.transpose(1, 2, 0)
        )
        for basis, nodes in (
            (on_skin.action, model.action_basis_nodes()),
            (on_skin.identity, model.shape_basis_nodes()),
        ):
            expected = patch_basis(weights, nodes).transpose(3, 2, 0, 1)
            np.testing.assert_allclose(basis, expected, rtol=0, atol=1e-15)
        assert not np.array_equal(on_skin.action, on_surface.action)


def test_a_solver_step_adds_to_omega_t_alpha_and_sigma_in_turn() -> None:
    """Step (omega 3, t 3, alpha q = 2, sigma p = 1), and one without sigma leaves it."""
    params = Params(np.zeros(3), np.array([0.0, 0.0, 0.6]), np.array([0.1, -0.1]), np.ones(1))
    step = np.arange(1.0, 10.0) / 100
    moved = params.updated(step, 2)
    np.testing.assert_allclose(moved.omega, [0.01, 0.02, 0.03], rtol=0, atol=1e-15)
    np.testing.assert_allclose(moved.t, [0.04, 0.05, 0.66], rtol=0, atol=1e-15)
    np.testing.assert_allclose(moved.alpha, [0.17, -0.02], rtol=0, atol=1e-15)
    np.testing.assert_allclose(moved.sigma, [1.09], rtol=0, atol=1e-15)
    assert params.updated(step[:8], 2).sigma is params.sigma
