"""Analytic Jacobians of eq. 1-3 against finite differences, the compiled kernels, the patches."""

from __future__ import annotations

import numpy as np
from numpy.linalg import LinAlgError
import pytest

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging import (
    PhotometricModel,
    inside_xy,
    sample_maps,
    sample_with_gradient_xy,
    sample_xy,
    square_offsets,
)
from face_tracking_ros.imaging.photometric import PhotometricInvariance
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.tracking.mono_kernels import (
    blended_template,
    damped_step,
    huber_irls,
    iteration,
    linearised,
    loss_votes,
    median_rms_ratio,
    node_visibility,
    normal_equations,
    point_cost,
    prior_terms,
    roi_jacobian,
    roi_maps,
    roi_points,
    row_rms,
    weighted_gram,
)
from face_tracking_ros.tracking.projection import project_with_jacobian
from face_tracking_ros.tracking.surface_patches import (
    PatchDeformation,
    ThinPlate,
    node_frames,
    patch_basis,
    patch_interpolation,
    surface_patch_interpolation,
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


def test_roi_kernels_are_eq_1_to_3_and_the_gradient_contracted_chain_rule() -> None:
    points, node_basis, coefficients = _setup()  # (N, M, 3) face-frame offsets of 4 x 5 samples
    rng = np.random.default_rng(1)
    shape = rng.normal(0.0, 0.05, (4, 3))
    action = rng.normal(0.0, 0.01, (2, 3, 4, 5))  # the samples' own motion D_nm
    identity = rng.normal(0.0, 0.01, (1, 3, 4, 5))
    sigma_change = np.array([0.3])
    rotation, d_rotation = rodrigues(OMEGA)
    offsets = np.ascontiguousarray(points.transpose(2, 0, 1))
    rotated, pixels = roi_points(
        rotation, shape, T, CAMERA.p, offsets, action, coefficients, identity, sigma_change
    )
    face = (
        shape[:, None]
        + points
        + np.einsum('kanm,k->nma', action, coefficients)
        + np.einsum('kanm,k->nma', identity, sigma_change)
    )
    expected = project_with_jacobian(CAMERA, OMEGA, T, face)
    assert np.abs(rotated.transpose(1, 2, 0) + T - expected.points_cam).max() < 1e-15
    assert pixels.dtype == np.float32
    assert np.abs(pixels.transpose(1, 2, 0) - expected.pixels).max() < 1e-3  # float32 pixels
    # The Jacobian of the samples I(x) is grad I times that of their pixels (eq. 1-3), each
    # sample moving with its node's basis plus its own D_nm.
    gradient = rng.normal(0.0, 10.0, (2, 4, 5)).astype(np.float32)
    sample_basis = node_basis[:, None] + action.transpose(2, 3, 1, 0)  # (N, M, 3, c)
    chain = project_with_jacobian(CAMERA, OMEGA, T, face, sample_basis).jacobian
    jacobian, node_jacobian = roi_jacobian(
        rotated,
        rotation @ shape.T,
        T,
        CAMERA.p,
        gradient,
        rotation,
        d_rotation,
        node_basis,
        action,
    )
    contracted = np.einsum('anm,nmap->pnm', gradient.astype(float), chain)
    assert jacobian.shape == (8, 4, 5)
    assert np.abs(jacobian - contracted).max() < 1e-9 * np.abs(contracted).max()
    nodes = project_with_jacobian(CAMERA, OMEGA, T, shape, node_basis).jacobian  # (N, 2, 8)
    assert np.abs(node_jacobian - nodes.reshape(8, 8)).max() < 1e-9 * np.abs(nodes).max()


def _roi_inputs() -> tuple:
    """roi_points' inputs for 4 nodes of 3 x 3 samples, some beyond a 40 x 30 image's border."""
    rng = np.random.default_rng(2)
    rotation, _ = rodrigues(OMEGA)
    shape = rng.normal(0.0, 0.02, (4, 3))
    offsets = rng.normal(0.0, 0.001, (3, 4, 9))
    action = rng.normal(0.0, 0.001, (2, 3, 4, 9))
    identity = rng.normal(0.0, 0.001, (1, 3, 4, 9))
    camera = np.array([[40.0, 0, 1, 0], [0, 40.0, 15, 0], [0, 0, 1, 0]])  # x ~ 1: the border
    return rotation, shape, T, camera, offsets, action, np.array([0.5, -1.0]), identity, np.ones(1)


def test_roi_maps_are_the_pixels_the_stencil_and_the_inside_mask_of_roi_points() -> None:
    """What the tracker samples is what the separate samplers made of roi_points' pixels."""
    inputs = _roi_inputs()
    rotated, (x, y) = roi_points(*inputs)
    image = np.random.default_rng(3).uniform(0, 255, (30, 40)).astype(np.float32)
    same_rotated, map_x, map_y, inside, box = roi_maps(*inputs, False, 40.0, 30.0, 1.0)

    assert np.array_equal(same_rotated, rotated)
    assert np.array_equal(
        sample_maps(image, map_x.reshape(4, 9), map_y.reshape(4, 9)), sample_xy(image, x, y)
    )
    assert np.array_equal(inside, inside_xy(x, y, image.shape, margin=1.0)) and not inside.all()
    assert np.array_equal(box, [x.min(), x.max(), y.min(), y.max()])
    _, map_x, map_y, _, _ = roi_maps(*inputs, True, 40.0, 30.0, 1.0)
    values, gradient = sample_with_gradient_xy(image, x, y)
    stencil = sample_maps(image, map_x, map_y)
    assert map_x.shape == (5, 36) and np.array_equal(stencil[0].reshape(4, 9), values)
    assert np.array_equal((stencil[1] - stencil[2]) * np.float32(0.5), gradient[0].ravel())
    assert np.array_equal((stencil[3] - stencil[4]) * np.float32(0.5), gradient[1].ravel())


def test_roi_maps_box_is_nan_when_a_pixel_is_not_finite() -> None:
    rotation, shape, t, camera, offsets, *rest = _roi_inputs()
    offsets[2, 1, 4] = -t[2] - 1.0  # one sample far behind the camera, the rest in front
    assert np.isfinite(
        roi_maps(rotation, shape, t, camera, offsets, *rest, False, 40, 30, 1)[4]
    ).all()
    offsets[2, 1, 4] = np.inf
    box = roi_maps(rotation, shape, t, camera, offsets, *rest, False, 40.0, 30.0, 1.0)[4]
    assert np.isnan(box).all()


def test_linearised_is_the_projected_jacobian_and_its_visible_gram() -> None:
    """The linearisation: roi_jacobian of the stencil's gradient, projected, then J' V J."""
    inputs = _roi_inputs()
    rotation, shape, t, camera, _, action, _, _, _ = inputs
    image = np.random.default_rng(4).uniform(0, 255, (30, 40)).astype(np.float32)
    rotated, map_x, map_y, _, _ = roi_maps(*inputs, True, 40.0, 30.0, 1.0)
    stencil = sample_maps(image, map_x, map_y)
    values, gradient = sample_with_gradient_xy(
        image, map_x[0].reshape(4, 9), map_y[0].reshape(4, 9)
    )
    d_rotation = rodrigues(OMEGA)[1]
    node_basis = np.random.default_rng(5).normal(0.0, 1.0, (4, 3, 2))
    args = (rotated, rotation @ shape.T, t, camera)
    bases = (rotation, d_rotation, node_basis, action)
    jacobian, node_jacobian = roi_jacobian(*args, gradient, *bases)
    projection = PhotometricInvariance.of(
        PhotometricModel.GAIN_FIELD, square_offsets(1)
    ).projection(values)
    expected = projection.apply(jacobian).reshape(8, -1)
    visibility = np.repeat([1.0, 0.5, 0.0, 1.0], 9)

    jacobian_t, hessian, same_node_jacobian = linearised(
        stencil, *args, *bases, projection.basis_rows, visibility
    )

    assert np.array_equal(jacobian_t, expected)
    assert np.array_equal(hessian, weighted_gram(expected, visibility))
    assert np.array_equal(same_node_jacobian, node_jacobian)


def test_projected_residuals_are_the_projected_difference() -> None:
    rng = np.random.default_rng(6)
    samples = rng.uniform(0, 255, (4, 9)).astype(np.float32)
    invariance = PhotometricInvariance.of(PhotometricModel.GAIN_FIELD, square_offsets(1))
    for template in (rng.uniform(0, 255, (4, 9)), samples[::-1].copy()):  # float64, float32
        projection = invariance.projection(template)
        residuals = projection.residuals(samples, template)
        assert residuals.dtype == np.float64
        assert np.array_equal(residuals, projection.apply(samples - template))


@pytest.mark.parametrize('size', [5, 9, 81, 169, 961])
def test_row_rms_is_numpys_to_the_bit(size: int) -> None:
    """np.sqrt(np.mean(v**2, axis=1)) summed in numpy's order: below 8, to 128, and beyond."""
    rng = np.random.default_rng(size)
    values = rng.normal(0.0, 1.0, (40, size)) * 10.0 ** rng.uniform(-3.0, 3.0, (40, 1))
    assert np.array_equal(row_rms(values), np.sqrt(np.mean(values**2, axis=1)))


def test_blended_template_is_numpys_to_the_bit() -> None:
    """T = I_(n-1) + epsilon (I_1 - I_(n-1)) as numpy takes it, for float32 and float64 ones."""
    rng = np.random.default_rng(11)
    epsilon = rng.uniform(0.0, 0.2, 6)
    for previous_type, keyframe_type in ((np.float32, np.float32), (np.float32, np.float64)):
        previous = rng.uniform(0.0, 255.0, (6, 81)).astype(previous_type)
        keyframe = rng.uniform(0.0, 255.0, (6, 81)).astype(keyframe_type)
        expected = previous + epsilon[:, None] * (keyframe - previous)
        blended = blended_template(previous, keyframe, epsilon)
        assert blended.dtype == np.float64
        assert np.array_equal(blended, expected)


def test_loss_votes_are_the_loss_checks_masks_and_counts() -> None:
    """Visible nodes (weight > 0, inside the image), voters (textured) and failures."""
    rng = np.random.default_rng(12)
    count, floor, ratio = 200, 2.0, 0.8
    visibility = np.where(rng.uniform(size=count) < 0.2, 0.0, rng.uniform(size=count))
    pixels = rng.uniform(-20.0, 660.0, (count, 2))
    pixels[:4] = [[0.0, 0.0], [639.0, 479.0], [639.5, 10.0], [10.0, -0.5]]  # the edges
    image = rng.uniform(0.0, 5.0, count)
    template = rng.uniform(0.0, 5.0, count)
    template[:3] = np.nan  # np.maximum's NaN: the node abstains
    node_rms = rng.uniform(0.0, 5.0, count)
    votes = loss_votes(visibility, pixels, (640, 480), (image, template), node_rms, floor, ratio)
    visible = (visibility > 0) & inside_xy(pixels[:, 0], pixels[:, 1], (480, 640))
    voting = visible & (np.maximum(image, template) > floor)
    matched = (image > floor) & (node_rms < ratio * image)
    assert np.array_equal(votes.visible, visible)
    assert np.array_equal(votes.textured, visible & (image > floor))
    assert (votes.visible_count, votes.voting) == (visible.sum(), voting.sum())
    assert votes.failing == (voting & ~matched).sum()
    assert 0 < votes.failing < votes.voting < votes.visible_count < count


@pytest.mark.parametrize('counted', [0, 1, 6, 7])
def test_median_rms_ratio_is_numpys_median_of_the_rows_rms_over_texture(counted: int) -> None:
    rng = np.random.default_rng(counted)
    residuals = rng.normal(0.0, 1.0, (9, 81)) * 10.0 ** rng.uniform(-2.0, 2.0, (9, 1))
    texture = rng.uniform(0.5, 20.0, 9)
    nodes = np.zeros(9, dtype=bool)
    nodes[rng.permutation(9)[:counted]] = True
    expected = np.median(row_rms(residuals[nodes]) / texture[nodes]) if counted else 0.0
    assert median_rms_ratio(residuals, texture, nodes) == expected  # odd and even counts


def test_weighted_gram_and_huber_irls_match_their_formulas() -> None:
    rng = np.random.default_rng(3)
    rows, weights = rng.normal(size=(7, 50)), rng.uniform(0.0, 1.0, 50)
    gram = weighted_gram(rows, weights)
    assert np.abs(gram - (rows * weights) @ rows.T).max() < 1e-12
    residuals = rng.normal(0.0, 3.0, (5, 10))
    sample_weights = rng.uniform(0.0, 1.0, (5, 10))
    irls, cost = huber_irls(residuals, sample_weights, 1.5, 2.0)
    u = np.abs(residuals) / 1.5
    assert 0 < np.mean(u > 2.0) < 1  # both branches of the loss are exercised
    assert np.allclose(irls, (sample_weights * np.minimum(1.0, 2.0 / u)).ravel(), atol=1e-15)
    rho = np.where(u <= 2.0, u**2, 4.0 * u - 4.0)
    assert np.isclose(cost, np.sum(sample_weights * rho), rtol=1e-12)


def test_node_visibility_ramps_from_the_cosine_low_to_twice_it() -> None:
    """Weights ``clip((c - low) / low, 0, 1)``, c the cosine of the turned normal and the ray.

    By hand for low = 0.2: nodes straight ahead with normals turned away by 0, 60 degrees
    (c = 0.5: 1), acos(0.3) (0.5), 80 degrees (0.17: 0) and 180 degrees (-1: 0). The head
    turned 60 degrees about y turns them all back by 60 degrees: 120 degrees is still away.
    """
    angles = np.radians([0.0, 60.0, np.degrees(np.arccos(0.3)), 80.0, 180.0])
    normals = np.stack([np.sin(angles), np.zeros(5), -np.cos(angles)], axis=1)
    nodes = np.array([[0.0, 0.0, 0.5]] * 5)
    weights = node_visibility(normals, np.eye(3), nodes, 0.2)
    np.testing.assert_allclose(weights, [1.0, 1.0, 0.5, 0.0, 0.0], rtol=0, atol=1e-12)
    head_turn = np.ascontiguousarray(rodrigues(np.radians([0.0, 60.0, 0.0]))[0])
    turned = node_visibility(normals, head_turn, nodes, 0.2)
    np.testing.assert_allclose(turned, [1.0, 1.0, 1.0, 1.0, 0.0], rtol=0, atol=1e-12)


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


def test_surface_patch_interpolation_is_the_offsets_and_their_weights_at_once() -> None:
    shape = mesh_topology(34).reference_shape
    grid = np.random.default_rng(1).normal(0.0, 0.004, (34, 5, 2))
    plate = ThinPlate.through(shape)
    offsets, weights = surface_patch_interpolation(plate, grid)
    np.testing.assert_allclose(offsets, surface_patch_offsets(shape, grid), rtol=0, atol=1e-12)
    np.testing.assert_allclose(weights, patch_interpolation(plate, offsets), rtol=0, atol=1e-10)
    assert np.abs(offsets[..., 2]).max() > 1e-3  # off the flat: the surface's depth is used


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
    dense = patch_basis(patch_interpolation(ThinPlate.through(shape), offsets), basis)
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


def test_patch_deformation_moves_the_samples_with_the_mesh_but_not_with_the_head() -> None:
    topology = mesh_topology(34)
    first = topology.reference_shape + [0.0, 0.0, 0.6]
    grid = np.array([[0.0, 0.0], [0.003, -0.002], [-0.004, 0.004]])
    offsets = surface_patch_offsets(first, grid)
    deformation = PatchDeformation.of(first, offsets)
    rotation, _ = rodrigues(np.array([0.05, -0.2, 0.03]))
    # A head motion alone (rotation and translation) deforms nothing.
    moved = first @ rotation.T + [0.01, -0.02, 0.03]
    assert np.abs(deformation.field(moved, first, rotation)).max() < 1e-14
    # An affine deformation on top of it (a stretch) is carried to every sample exactly: the
    # samples land where the same motion takes the frame-1 samples.
    affine = np.eye(3) + np.array([[0.1, 0.02, 0.0], [0.0, -0.05, 0.0], [0.03, 0.01, 0.0]])
    centre = first.mean(axis=0)
    stretched = ((first - centre) @ affine.T + centre) @ rotation.T + [0.01, -0.02, 0.03]
    field = deformation.field(stretched, first, rotation).T.reshape(offsets.shape)
    samples = stretched[:, None, :] + offsets @ rotation.T + field
    expected = (((first[:, None, :] + offsets) - centre) @ affine.T + centre) @ rotation.T
    assert np.allclose(samples, expected + [0.01, -0.02, 0.03], atol=1e-12)
    assert np.abs(field[:, 0]).max() < 1e-12  # a node's own sample is the node
    # One node moving alone pulls the samples of its own patch along, not the far ones.
    lip, far = topology.index('lower_lip'), topology.index('left_brow_outer')
    single = first.copy()
    single[lip] += [0.0, 0.003, 0.0]
    field = deformation.field(single, first, np.eye(3)).T.reshape(offsets.shape)
    # Its own samples, 3.6 and 5.7 mm from it, follow it by more than half of its motion.
    assert np.all((field[lip, 1:, 1] < 0.0) & (field[lip, 1:, 1] > -0.0015))
    assert np.abs(field[far]).max() < 0.0003


def test_normal_equations_and_damped_step_match_their_formulas() -> None:
    rng = np.random.default_rng(4)
    jacobian_t = rng.normal(size=(6, 40))
    residuals, weights = rng.normal(0.0, 3.0, (4, 10)), rng.uniform(0.0, 1.0, (4, 10))
    visibility = np.repeat(rng.uniform(0.5, 1.0, (4, 1)), 10, axis=1)
    weights[0, :3] = 0.0  # outside the image
    visible_hessian = weighted_gram(jacobian_t, visibility.ravel())
    cost, hessian, gradient = normal_equations(
        jacobian_t, residuals, weights, visibility, 1.5, 2.0, visible_hessian
    )
    irls, expected_cost = huber_irls(residuals, weights, 1.5, 2.0)
    assert cost == expected_cost
    assert np.abs(hessian - (jacobian_t * irls) @ jacobian_t.T / 1.5**2).max() < 1e-12
    assert np.abs(gradient - jacobian_t @ (irls * residuals.ravel()) / 1.5**2).max() < 1e-12
    # The Levenberg-Marquardt step -(H + lambda diag H)^-1 g.
    step = damped_step(hessian, gradient, 0.1)
    damped = hessian + 0.1 * np.diag(np.diag(hessian))
    assert np.abs(step + np.linalg.solve(damped, gradient)).max() < 1e-10 * np.abs(step).max()
    hessian[2, 3] = np.nan
    with pytest.raises(LinAlgError, match='non-finite normal equations'):
        damped_step(hessian, gradient, 0.1)


@pytest.mark.parametrize('model', [PhotometricModel.NONE, PhotometricModel.GAIN_FIELD])
def test_point_cost_is_the_projected_residuals_huber_cost_and_priors(
    model: PhotometricModel,
) -> None:
    """:func:`point_cost` in one call is the parts it fuses, to the bit."""
    rng = np.random.default_rng(7)
    invariance = PhotometricInvariance.of(model, square_offsets(1))
    samples = rng.uniform(50.0, 200.0, (5, 9)).astype(np.float32)
    node_weights = rng.uniform(0.0, 1.0, 5)
    inside = rng.uniform(size=(5, 9)) > 0.2
    prior_hessian = np.zeros((8, 8))
    prior_hessian[6:, 6:] = [[2.0, 0.5], [0.5, 1.0]]
    alpha = np.array([0.3, -0.2])
    for template in (samples + rng.normal(0.0, 9.0, (5, 9)), samples[::-1].copy()):
        projection = invariance.projection(template)
        residuals, cost = point_cost(
            samples, template, projection.basis_rows, node_weights, inside, 2.5, 1.345,
            prior_hessian, alpha,
        )  # fmt: skip
        expected = projection.residuals(samples, template)
        weights = node_weights[:, None] * inside
        data_cost = huber_irls(expected, weights, 2.5, 1.345)[1]
        assert np.array_equal(residuals, expected)
        assert cost == data_cost + prior_terms(prior_hessian, alpha)[0]


def test_an_iteration_is_its_residuals_scale_normal_equations_priors_and_step() -> None:
    """:func:`iteration` in one call is the parts it fuses, taken one at a time."""
    rng = np.random.default_rng(5)
    invariance = PhotometricInvariance.of(PhotometricModel.GAIN_FIELD, square_offsets(1))
    template = rng.uniform(50.0, 200.0, (4, 9))
    samples = (template + rng.normal(0.0, 4.0, (4, 9))).astype(np.float32)
    projection = invariance.projection(template)
    visibility = np.repeat(rng.uniform(0.5, 1.0, (4, 1)), 9, axis=1)
    inside = np.ones((4, 9), dtype=bool)
    inside[1, :4] = False
    jacobian_t = rng.normal(size=(8, 36))
    visible_hessian = weighted_gram(jacobian_t, visibility.ravel())
    node_jacobian = rng.normal(size=(8, 8))
    prior_hessian = np.zeros((8, 8))
    prior_hessian[6:, 6:] = [[2.0, 0.5], [0.5, 1.0]]
    alpha = np.array([0.3, -0.2])
    linear = (jacobian_t, visible_hessian, node_jacobian)

    result = iteration(
        samples, template, projection.basis_rows, visibility, inside, None, 0.5, 1.345, linear,
        prior_hessian, alpha, 1e-3, np.inf,
    )  # fmt: skip

    residuals = projection.residuals(samples, template)
    weights = visibility * inside
    scale = 1.4826 * np.median(np.abs(residuals[weights > 0]))
    cost, hessian, gradient = normal_equations(
        jacobian_t, residuals, weights, visibility, scale, 1.345, visible_hessian
    )
    cost += alpha @ prior_hessian[6:, 6:] @ alpha
    hessian += prior_hessian
    gradient[6:] += prior_hessian[6:, 6:] @ alpha
    step = damped_step(hessian, gradient, 1e-3)
    assert np.abs(result.residuals - residuals).max() < 1e-12
    assert result.scale == pytest.approx(scale, rel=1e-12)
    assert result.cost == pytest.approx(cost, rel=1e-12)
    assert np.abs(result.hessian - hessian).max() < 1e-10 * np.abs(hessian).max()
    assert np.abs(result.step - step).max() < 1e-10 * np.abs(step).max()
    assert result.motion == pytest.approx(np.abs(node_jacobian @ step).max(), rel=1e-12)
    # A given scale is kept; from a point costing more than the bound no step is taken.
    again = iteration(
        samples, template, projection.basis_rows, visibility, inside, 3.0, 0.5, 1.345, linear,
        prior_hessian, alpha, 1e-3, 0.0,
    )  # fmt: skip
    assert again.scale == 3.0 and again.step.size == 0 and again.motion == 0.0
