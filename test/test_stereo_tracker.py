"""Tests of the stereo tracker (eq. 4 and 5) on a textured plane seen by an ideal stereo rig.

A plane needs no face renderer: both views are exact homographies of one texture, so every node
placed on the plane has a known 3-D position in every frame.
"""

from __future__ import annotations

from dataclasses import replace
import re
from types import SimpleNamespace

from call_recording import record_method
import cv2
import numpy as np
import pytest
from scipy.interpolate import LinearNDInterpolator

from face_tracking_ros.errors import ConfigError, InputError, ModelFileError
from face_tracking_ros.geometry.camera import PinholeCamera, StereoRig
from face_tracking_ros.imaging import GRADIENT_MARGIN, ImagePyramid, PyramidLevel, inside_xy
from face_tracking_ros.model.topology import Group, mesh_topology
from face_tracking_ros.synthetic.surface import head_surface
from face_tracking_ros.tracking.camera_gain import relative_gain
from face_tracking_ros.tracking.depth_refinement import (
    DepthEvidence,
    DepthRefinement,
    depth_evidence,
)
from face_tracking_ros.tracking.initialisation import Initialisation
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.tracking.row_offset import row_offset
from face_tracking_ros.tracking.stereo import StereoTracker, track_sequence
from face_tracking_ros.tracking.stereo_config import StereoInitConfig, StereoTrackerConfig
from face_tracking_ros.tracking.stereo_data import (
    GroupStatistics,
    Huber,
    Residuals,
    Sampled,
    SampleLayout,
    SampleSet,
    depth_terms,
    group_contrast,
    group_statistics,
    homogeneous_pixels,
    level_projections,
    node_blocks,
    rim_points,
    robust_residuals,
    sample_images,
    sample_values,
)
from face_tracking_ros.tracking.stereo_init import (
    FLAT_STD,
    epipolar_match,
    initial_nodes,
)
from face_tracking_ros.tracking.stereo_kernels import largest_motion, space_rows
from face_tracking_ros.tracking.stereo_loss import loss_reason
from face_tracking_ros.tracking.stereo_solve import (
    LevelSolver,
    PairEnergy,
    Point,
    System,
    _damped_step,
)
from face_tracking_ros.tracking.stereo_templates import TemplateSamples, texture_triangles
from face_tracking_ros.tracking.surface_patches import (
    PatchDeformation,
    patch_field,
    surface_patch_offsets,
)

RIG = StereoRig.ideal()
# A plane is no face: accept any depth difference from the reference face at initialisation.
PLANE_INIT = StereoInitConfig(max_face_error=0.2)
# The 19-node mesh has no face-boundary nodes, whose depth comes from the (curved) reference face.
PLANE_CONFIG = StereoTrackerConfig(num_nodes=19, init=PLANE_INIT)
TEXEL = 0.0005  # m per texel


def _grouped(samples: SampleSet, values: np.ndarray) -> tuple[np.ndarray, ...]:
    """Views (..., G_l, M_l) of (..., S) sample arrays, one per layout of ``samples``."""
    return tuple(
        values[..., samples.bounds[index] : samples.bounds[index + 1]].reshape(
            *values.shape[:-1], *layout.mask.shape
        )
        for index, layout in enumerate(samples.layouts)
    )


def _texture(seed: int = 0, size: int = 512) -> np.ndarray:
    """Multi-scale smooth noise in [30, 230] grey levels, float32."""
    rng = np.random.default_rng(seed)
    texture = np.zeros((size, size), np.float32)
    for scale in (2, 4, 8, 16, 32):
        noise = rng.normal(size=(size // scale + 2, size // scale + 2)).astype(np.float32)
        texture += np.sqrt(scale) * cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)
    return (texture - texture.min()) / np.ptp(texture) * 200 + 30


TEXTURE = _texture()


class _Plane:
    """A textured plane: origin (3,), in-plane unit axes e1, e2 (3,), in the left frame, m."""

    def __init__(self, origin: np.ndarray, yaw: float = 0.3) -> None:
        self.origin = np.asarray(origin, float)
        self.e1 = np.array([np.cos(yaw), 0.0, np.sin(yaw)])
        self.e2 = np.array([0.0, 1.0, 0.0])

    def moved(self, shift: np.ndarray) -> _Plane:
        plane = _Plane(self.origin + shift)
        plane.e1, plane.e2 = self.e1, self.e2
        return plane

    def nodes(self, count: int = 34) -> np.ndarray:
        """The reference face's (x, y) laid on the plane: (count, 3), m."""
        reference = mesh_topology(count).reference_shape
        return self.origin + reference[:, :1] * self.e1 + reference[:, 1:2] * self.e2

    def image(self, camera: PinholeCamera) -> np.ndarray:
        """(H, W) float32 view of the plane (texture centred on the face, 45 mm below the eyes)."""
        corner = self.origin + 0.045 * self.e2 - TEXTURE.shape[0] / 2 * TEXEL * (self.e1 + self.e2)
        frame = np.stack([TEXEL * self.e1, TEXEL * self.e2, corner], axis=1)
        homography = camera.p[:, :3] @ frame
        homography[:, 2] += camera.p[:, 3]
        size = (camera.width, camera.height)
        return cv2.warpPerspective(TEXTURE, homography, size, flags=cv2.INTER_CUBIC)

    def pair(self) -> tuple[np.ndarray, np.ndarray]:
        return self.image(RIG.left), self.image(RIG.right)


PLANE = _Plane([0.0, -0.03, 0.6])
MOVING_PLANE = [PLANE.moved(np.array([0.0015, -0.001, 0.003]) * k) for k in range(6)]


def _rms_mm(nodes: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((nodes - truth) ** 2, axis=1))) * 1000)


def test_triangulation_recovers_points_and_takes_an_empty_set() -> None:
    truth = PLANE.nodes()
    found = RIG.triangulate(RIG.left.project(truth), RIG.right.project(truth))
    np.testing.assert_allclose(found, truth, atol=1e-9)
    # An initialisation whose second epipolar search matches no node triangulates none.
    assert RIG.triangulate(np.zeros((0, 2)), np.zeros((0, 2))).shape == (0, 3)


def test_epipolar_match_and_initial_nodes_are_sub_pixel() -> None:
    left, right = PLANE.pair()
    truth = PLANE.nodes()
    depths = (np.full(34, 0.3), np.full(34, 1.5))
    right_px, scores = epipolar_match(RIG, left, right, RIG.left.project(truth), depths, 7)
    assert scores.min() > 0.9
    assert np.abs(right_px - RIG.right.project(truth)).max() < 0.3
    # Half the nodes given: the rest come from the reference face, then depth refinement.
    topology = mesh_topology(34)
    left_px = RIG.left.project(truth)
    left_px[1::2] = np.nan
    initial = initial_nodes(RIG, left, right, left_px, topology, PLANE_INIT)
    nodes = initial.nodes
    given = np.isfinite(left_px[:, 0])
    matched = given & ~topology.group_mask(Group.EDGE)
    np.testing.assert_array_equal(initial.matched, matched)  # every given inner node matched
    assert np.linalg.norm(nodes[matched] - truth[matched], axis=1).max() < 0.0005
    # Given boundary nodes keep their left-image position at the fitted face's depth.
    boundary = given & topology.group_mask(Group.EDGE)
    assert np.abs(RIG.left.project(nodes[boundary]) - left_px[boundary]).max() < 1e-6
    # The others lie on the plane at the reference face's (x, y) but its depth relief.
    assert np.linalg.norm(nodes[~matched] - truth[~matched], axis=1).max() < 0.06
    edge_only = np.where(topology.group_mask(Group.EDGE)[:, None], RIG.left.project(truth), np.nan)
    with pytest.raises(InputError, match='gives 0 inner nodes .* the face edge alone cannot'):
        initial_nodes(RIG, left, right, edge_only, topology, PLANE_INIT)


def test_a_faint_stretch_of_the_right_image_is_never_matched() -> None:
    """A window flatter than FLAT_STD (the sensor noise) is not matched, however it correlates."""
    left, right = PLANE.pair()
    nose = PLANE.nodes()[2:3]
    true_px = RIG.right.project(nose)  # 110 px disparity
    # Nearer than the nose, the right image shows the left one 150 px on, at 1/40 the contrast:
    # the nose's window there (NCC 0.9999 with the left one) is flatter than FLAT_STD.
    faint = 128.0 + 0.025 * np.roll(left, -150, axis=1)
    assert faint[240:255, 162:177].std() < FLAT_STD
    right = right.copy()
    right[:, :189] = faint[:, :189]
    found, score = epipolar_match(
        RIG, left, right, RIG.left.project(nose), (np.full(1, 0.3), np.full(1, 1.5)), 7
    )
    assert np.abs(found - true_px).max() < 0.1 and 0.95 < score[0] < 0.999


def test_a_correlation_rising_to_the_end_of_the_range_is_no_match() -> None:
    """A range ending a pixel of disparity short of the nose: its best is the end, no peak."""
    left, right = PLANE.pair()
    nose = PLANE.nodes()[2:3]
    left_px, true_px = RIG.left.project(nose), RIG.right.project(nose)
    focal_baseline = (left_px[0, 0] - true_px[0, 0]) * nose[0, 2]  # disparity d = f B / z
    for short in (1.0, -1.0):  # the range's far end beyond, then its near end short of it
        end = np.full(1, focal_baseline / (left_px[0, 0] - true_px[0, 0] + short))
        ranges = (np.full(1, 0.3), end) if short > 0 else (end, np.full(1, 1.5))
        found, score = epipolar_match(RIG, left, right, left_px, ranges, 7)
        assert score[0] == -1.0 and np.isnan(found).all()
    found, score = epipolar_match(RIG, left, right, left_px, (end - 0.01, end + 0.01), 7)
    assert np.abs(found - true_px).max() < 0.1 and score[0] > 0.95


def test_four_inner_nodes_place_the_face_and_three_do_not() -> None:
    left, right = PLANE.pair()
    topology = mesh_topology(34)
    inner = ('right_eye', 'left_eye', 'nose_tip', 'mouth_right')
    given = [topology.index(name) for name in (*inner, 'right_temple', 'left_temple')]
    left_px = np.full((34, 2), np.nan)
    left_px[given] = RIG.left.project(PLANE.nodes())[given]
    initial = initial_nodes(RIG, left, right, left_px, topology, PLANE_INIT)
    assert np.flatnonzero(initial.matched).tolist() == sorted(given[:4])
    left_px[given[3]] = np.nan
    left_px[topology.index('chin')] = RIG.left.project(PLANE.nodes())[topology.index('chin')]
    with pytest.raises(InputError, match='gives 3 inner nodes .* at least 4 are needed'):
        initial_nodes(RIG, left, right, left_px, topology, PLANE_INIT)


def test_nodes_named_left_for_right_fit_a_face_turned_away_and_are_refused() -> None:
    left, right = PLANE.pair()
    topology = mesh_topology(34)
    mirrored = [
        topology.index(name.replace('right', '?').replace('left', 'right').replace('?', 'left'))
        for name in topology.node_names
    ]
    with pytest.raises(InputError, match='turned away') as refused:
        initial_nodes(
            RIG, left, right, RIG.left.project(PLANE.nodes())[mirrored], topology, PLANE_INIT
        )
    # Measured 13 mm: the reference face's nose is 27 mm before its eyes; fitted turned round
    # to a plane (no relief), it keeps part of that behind them.
    behind = float(re.search(r'its nose (\d+) mm behind', str(refused.value)).group(1))
    assert 10 <= behind <= 27, refused.value


def _wave(phase: float) -> np.ndarray:
    """A smooth sinusoidal image, so the central-difference image gradient is the true slope."""
    rows, cols = np.mgrid[0:480, 0:640].astype(np.float64)
    value = 50 * np.sin(cols / 13 + phase) * np.cos(rows / 9) + 30 * np.sin((cols + rows) / 21)
    return (100 + value).astype(np.float32)


@pytest.mark.parametrize('layout_kind', ['patches', 'texture'])
def test_image_normal_equations_gradient_matches_finite_differences(layout_kind: str) -> None:
    truth = PLANE.nodes()
    if layout_kind == 'patches':
        one_sided = np.zeros(34, dtype=bool)
        one_sided[::3] = True
        layout = SampleLayout.node_patches(truth, truth[:, 2] / 600, 3, one_sided)
        assert layout.mask[~one_sided].all() and 0.4 < layout.mask[one_sided].mean() < 0.7
    else:  # three nodes per group
        layout = SampleLayout.triangle_texture(mesh_topology(34).triangles, 4)
    samples = SampleSet.of((layout,), 34)
    offsets = samples.level_offsets(np.eye(3), 0)
    projections = level_projections((RIG.left, RIG.right), 0)
    # Both images against templates of both (eq. 4's four terms), Huber on the larger residuals.
    earlier = (_wave(0.0), _wave(0.4))
    current = (_wave(0.1), _wave(0.5))
    sampled = sample_images(earlier, projections, samples.points(truth, offsets), samples.mask)
    templates = np.stack([sampled.values, sampled.values[::-1]], axis=1)
    coefficients = np.repeat([[0.6], [0.4]], samples.size, axis=1)
    huber = Huber.of(samples, [8.0])
    moved = truth + np.random.default_rng(0).normal(0, 0.0003, truth.shape)

    def evaluate(nodes: np.ndarray) -> tuple[Sampled, Residuals]:
        sampled = sample_images(current, projections, samples.points(nodes, offsets), samples.mask)
        return sampled, robust_residuals(samples, sampled, templates, coefficients, huber)

    sampled, residuals = evaluate(moved)
    assert np.mean(residuals.weight < 1.0) > 0.05  # some samples beyond the Huber threshold
    hessian, gradient = samples.assemble(*node_blocks(samples, sampled, residuals, projections))
    analytic = 2 * gradient  # d cost / dX = 2 J^T W r
    step = 3e-4
    numeric = np.empty_like(analytic)
    for k in range(analytic.size):
        plus, minus = moved.ravel().copy(), moved.ravel().copy()
        plus[k] += step
        minus[k] -= step
        numeric[k] = (
            evaluate(plus.reshape(-1, 3))[1].cost - evaluate(minus.reshape(-1, 3))[1].cost
        ) / (2 * step)
    assert np.linalg.norm(analytic - numeric) < 0.05 * np.linalg.norm(numeric)
    # J^T W J is symmetric positive semi-definite.
    assert np.allclose(hessian, hessian.T) and np.linalg.eigvalsh(hessian).min() > -1e-6


def test_the_damped_step_solves_the_normal_equations_with_a_relative_diagonal_damping() -> None:
    # Two nodes: -(H + d diag(H))^-1 g, with the diagonal damped relative to itself.
    rng = np.random.default_rng(3)
    jacobian = rng.normal(size=(9, 6)) * [1.0, 2.0, 5.0, 10.0, 20.0, 50.0]
    hessian, gradient = jacobian.T @ jacobian, rng.normal(size=6)
    step = _damped_step(System(hessian, gradient), 0.5)
    damped = hessian + 0.5 * np.diag(np.diag(hessian))
    np.testing.assert_allclose(step.ravel(), -np.linalg.solve(damped, gradient), rtol=1e-10)
    assert step.shape == (2, 3)


def test_the_pair_energy_holds_eq5_and_the_face_model_term(monkeypatch) -> None:
    """E(n)'s cost and its normal equations' gradient both hold eq. 5 and the face-model term.

    The energy of the moving plane's third pair on level 0, as the tracker made it, with its
    image terms weighted 0 (their gradient is checked above): at nodes 0.5 mm off the solve's
    start, the cost's finite-difference gradient is twice the normal equations' (measured
    0.2% apart, the model term's one-step refit), where eq. 5 is 14% of it and the model term
    91%.
    """
    calls = record_method(monkeypatch, LevelSolver, 'solve', lambda *args: args[:3])
    frames = [plane.pair() for plane in MOVING_PLANE[:3]]
    track_sequence(StereoTracker(RIG, PLANE_CONFIG), frames, RIG.left.project(PLANE.nodes(19)))
    energy, level, start = calls[-1]
    assert level.index == 0 and energy.prior is not None
    energy = replace(energy, coefficients=np.zeros_like(energy.coefficients))
    fit = energy.theta
    nodes = start + np.random.default_rng(0).normal(0, 0.0005, start.shape)

    def cost(flat: np.ndarray) -> float:
        energy.theta = fit  # each evaluation refits the model term from the same fit
        return energy.evaluate(level, flat.reshape(-1, 3)).cost

    point = energy.evaluate(level, nodes)
    assert point.residuals.cost == 0.0
    assert energy.regulariser.cost(nodes, energy.previous) > 0.05 * point.cost
    assert point.prior.cost > 0.5 * point.cost
    analytic = 2 * energy.linearise(level, point).gradient  # d cost / dX = 2 J^T r
    numeric = np.empty_like(analytic)
    for k in range(analytic.size):
        shift = np.zeros(analytic.size)
        shift[k] = 1e-6
        numeric[k] = (cost(nodes.ravel() + shift) - cost(nodes.ravel() - shift)) / 2e-6
    assert np.linalg.norm(analytic - numeric) < 0.01 * np.linalg.norm(numeric)


class _UphillEnergy:
    """A stand-in for PairEnergy whose cost |n - c|^2 rises along every linearised step."""

    def __init__(self, centre: np.ndarray) -> None:
        self.centre = centre

    def evaluate(self, _level: object, nodes: np.ndarray) -> Point:
        return Point(nodes, float(np.sum((nodes - self.centre) ** 2)), None, None, None)

    def linearise(self, _level: object, point: Point) -> System:
        return System(np.eye(point.nodes.size), (self.centre - point.nodes).ravel())


def test_a_rejected_step_raises_the_damping_tenfold_until_it_passes_a_thousand() -> None:
    nodes = PLANE.nodes(19)
    solver = LevelSolver(
        replace(PLANE_CONFIG, max_iterations=20), level_projections((RIG.left, RIG.right), 0)
    )
    energy = _UphillEnergy(nodes - [0.5, 0.0, 0.0])
    solved = solver.solve(energy, SimpleNamespace(index=0), nodes)
    assert solved is not None
    found, iterations, costs, point = solved
    # Damping 1e-4, 1e-3, ..., 1e3: eight rejected steps (the last 0.5 mm, over 0.1 px), then
    # 1e4 > 1e3 ends the level where it started.
    assert iterations == 8 and costs == [] and np.array_equal(found, nodes)
    assert point.cost == pytest.approx(19 * 0.25)


class _BowlEnergy(_UphillEnergy):
    """A stand-in for PairEnergy of cost |n - c|^2, whose Gauss-Newton step is exact."""

    def linearise(self, _level: object, point: Point) -> System:
        return System(np.eye(point.nodes.size), (point.nodes - self.centre).ravel())


def test_an_accepted_step_lowers_the_damping_tenfold() -> None:
    """Steps of damping 1, 0.1, 0.01, 0.001, then 1e-4 from a 0.5 m error.

    A step of damping d leaves d / (1 + d) of the way to the minimum; the fifth moves less
    than step_tolerance and ends the level unevaluated.
    """
    nodes = PLANE.nodes(19)
    solver = LevelSolver(
        replace(PLANE_CONFIG, damping=1.0, max_iterations=20),
        level_projections((RIG.left, RIG.right), 0),
    )
    centre = nodes - [0.5, 0.0, 0.0]
    solved = solver.solve(_BowlEnergy(centre), SimpleNamespace(index=0), nodes)
    assert solved is not None
    found, iterations, costs, _ = solved
    left = np.cumprod([d / (1.0 + d) for d in (1.0, 0.1, 0.01, 0.001, 1e-4)])
    assert iterations == 5
    assert costs == pytest.approx(list(19 * 0.25 * left[:4] ** 2), rel=1e-9)
    np.testing.assert_allclose(found, centre + left[-1] * (nodes - centre), rtol=0, atol=1e-15)


def test_face_edge_patches_follow_the_skin_that_turns_away_beyond_the_edge() -> None:
    # The synthetic head at rest (the reference face's nodes) 0.6 m in front of the camera.
    surface = head_surface()
    head = np.all(np.isclose(1000.0 * surface.rest_vertices[:, :2], surface.uv), axis=1)
    skin = LinearNDInterpolator(surface.rest_vertices[head, :2], surface.rest_vertices[head, 2])
    topology = mesh_topology(34)
    nodes = topology.reference_shape + [0.0, 0.0, 0.6]
    edge = topology.group_mask(Group.EDGE)
    layout = SampleLayout.node_patches(nodes, nodes[:, 2] / 600.0, 3, edge)
    samples = (nodes[:, None] + layout.offsets)[layout.mask & edge[:, None]]
    behind_skin = samples[:, 2] - 0.6 - skin(samples[:, :2])
    # Through the nodes alone the face-edge patches lie 1.4 mm behind the skin on average (2.0
    # mm RMS); through the points beyond the edge too, on it within 0.8 mm RMS.
    assert abs(behind_skin.mean()) < 3e-4
    assert np.sqrt(np.mean(behind_skin**2)) < 1e-3
    # A mesh without face-edge nodes (19 nodes) keeps the surface through its nodes alone.
    inner = SampleLayout.node_patches(nodes, nodes[:, 2] / 600.0, 3, np.zeros(34, dtype=bool))
    grid = inner.offsets[..., :2]
    np.testing.assert_array_equal(inner.offsets, surface_patch_offsets(nodes, grid))


def test_rim_points_lie_outward_of_each_boundary_node_and_behind_it() -> None:
    # Four nodes about the centroid (0.01, -0.02): the two boundary ones 50 mm right of it and
    # 30 mm below it; their rim points RIM_OUTWARD (10 mm) farther out, RIM_BEHIND (20 mm) deeper.
    nodes = np.array(
        [[0.06, -0.02, 0.6], [0.01, -0.05, 0.62], [-0.04, -0.02, 0.6], [0.01, 0.01, 0.58]]
    )
    rim = rim_points(nodes, np.array([True, True, False, False]))
    np.testing.assert_allclose(rim, [[0.07, -0.02, 0.62], [0.01, -0.06, 0.64]], atol=1e-12)


@pytest.mark.parametrize('level', [0, 1])
def test_patches_deform_with_an_affine_stretch_of_the_nodes_exactly(level: int) -> None:
    """A thin plate reproduces an affine motion: a sample moves A o more than its node.

    Times 2^level on that level (o is level 0's offset); the texture samples keep their offsets.
    """
    first = PLANE.nodes(19)
    stretch = np.array([[0.1, 0.05], [0.0, -0.08]])  # on camera x-y
    nodes = first.copy()
    nodes[:, :2] += first[:, :2] @ stretch.T
    patches = SampleLayout.node_patches(first, first[:, 2] / 600, 2, np.zeros(19, dtype=bool))
    texture = SampleLayout.triangle_texture(mesh_topology(19).triangles, 4)
    samples = SampleSet.of((patches, texture), 19)
    rigid = samples.level_offsets(np.eye(3), level)
    deformation = PatchDeformation.of(first, patches.offsets)
    field = patch_field(deformation, nodes, first, np.eye(3))
    deformed = samples.points(nodes, rigid, field, 2.0**level) - samples.points(nodes, rigid)
    offsets = patches.offsets.reshape(-1, 3)
    expected = np.zeros_like(rigid)
    expected[:2, : len(offsets)] = 2**level * (offsets[:, :2] @ stretch.T).T
    np.testing.assert_allclose(deformed, expected, rtol=0, atol=1e-12)
    assert np.abs(expected).max() > 1e-4  # m: the deformation moves samples
    assert patch_field(None, nodes, first, np.eye(3)) is None  # rigid patches


def test_sample_points_and_pixels_are_the_numpy_formulas_to_the_bit() -> None:
    """The compiled passes of an evaluation: points, then pixels, stencil maps and validity.

    A point behind the camera or a pixel within GRADIENT_MARGIN of the border is not valid; a
    non-finite pixel is refused.
    """
    rng = np.random.default_rng(12)
    first = PLANE.nodes(19)
    nodes = first + rng.normal(0.0, 0.002, first.shape)
    patches = SampleLayout.node_patches(first, first[:, 2] / 600, 2, np.zeros(19, dtype=bool))
    texture = SampleLayout.triangle_texture(mesh_topology(19).triangles, 4)
    samples = SampleSet.of((patches, texture), 19)
    offsets = samples.level_offsets(np.eye(3), 1)
    field = PatchDeformation.of(first, patches.offsets).field(nodes, first, np.eye(3))
    points = samples.points(nodes, offsets, field, 2.0)
    deformed = offsets.copy()
    deformed[:, : field.shape[1]] += 2.0 * field
    corners = nodes.T[:, texture.nodes]  # (3, T, 3): the nodes of each triangle
    weighted = (corners[:, :, None, :] * texture.bary[None, None]).sum(axis=-1).reshape(3, -1)
    expected = np.concatenate([np.repeat(nodes.T, len(patches.bary), axis=1), weighted], axis=1)
    assert (points == expected + deformed).all()
    points[:, :2] = [[-0.5, 0.0], [0.0, 0.0], [0.6, -0.6]]  # off both images; behind them
    projections = level_projections((RIG.left, RIG.right), 1)
    images = [np.zeros((RIG.left.height // 2, RIG.left.width // 2), np.float32)] * 2
    mask = samples.mask
    sampled = sample_images(images, projections, points, mask)
    pixels = sampled.homogeneous[:, :2] / sampled.homogeneous[:, 2:]
    inside = inside_xy(pixels[:, 0], pixels[:, 1], images[0].shape, GRADIENT_MARGIN)
    assert (sampled.valid == inside & (points[2] > 0) & mask).all()
    assert not sampled.valid[:, :2].any() and sampled.valid[:, 2:].all()
    strided = sample_images(images, projections, np.asfortranarray(points), mask.repeat(2)[::2])
    assert (strided.valid == sampled.valid).all()  # any memory layout of the points and mask
    points[:, 5] = np.nan
    with pytest.raises(InputError, match='NaN or Inf'):
        sample_images(images, projections, points, samples.mask)


def test_template_coefficients_split_gamma_and_epsilon_and_weigh_the_texture() -> None:
    """The a_k of the table in stereo_templates' docstring.

    k = frame n - 1 in the same / other camera, frame 1 in the same / other camera; face-edge
    patches with boundary_gamma; the texture in the same camera only, times its weight.
    """
    topology = mesh_topology(34)
    config = StereoTrackerConfig(gamma=0.4, boundary_gamma=0.1, epsilon=0.2, texture_weight=0.5)
    template_samples = TemplateSamples(config, topology)
    layouts = template_samples.layouts(PLANE.nodes(), RIG.left.focal)
    samples = SampleSet.of(layouts, 34)
    patches, texture = _grouped(samples, template_samples.coefficients(samples))
    edge = topology.group_mask(Group.EDGE)
    # (1 - 0.2) (1 - 0.4), 0.8 0.4, 0.2 0.6, 0.2 0.4; edge: gamma 0.1; texture: 0.8 0.5, 0.2 0.5
    assert np.allclose(patches[:, ~edge], np.array([0.48, 0.32, 0.12, 0.08])[:, None, None])
    assert np.allclose(patches[:, edge], np.array([0.72, 0.08, 0.18, 0.02])[:, None, None])
    assert np.allclose(texture, np.array([0.4, 0.0, 0.1, 0.0])[:, None, None])
    assert texture.shape[1] == len(texture_triangles(topology)) > 0
    without = TemplateSamples(replace(config, texture_weight=0.0), topology)
    assert len(without.layouts(PLANE.nodes(), RIG.left.focal)) == 1


def test_the_templates_are_frame_n_1_s_and_frame_1_s_in_the_same_and_the_other_camera(
    monkeypatch,
) -> None:
    """T_k of eq. 4 with the drift term: k = 0, 1 frame n - 1, k = 2, 3 frame 1; then the other.

    Pair 2 is pair 1 plus 20 grey levels (which the ZSSD removes: found 0.08 mm from pair 1),
    so pair 3's frame n - 1 templates are frame 1's plus 20 (to 0.18 measured) and its frame-1
    templates are frame 1's to the bit.
    """
    levels = record_method(monkeypatch, LevelSolver, 'solve', lambda _energy, level, *_: level)
    left, right = PLANE.pair()
    pairs = [(left, right), (left + 20, right + 20), (left + 20, right + 20)]
    init = RIG.left.project(PLANE.nodes(19))
    assert track_sequence(StereoTracker(RIG, PLANE_CONFIG), pairs, init).status.tolist() == [1] * 3
    first, third = (level.templates for level in levels if level.index == 0)
    assert np.abs(third[:, :2] - first[:, :2] - 20.0).max() < 0.5
    assert np.array_equal(third[:, 2:], first[:, 2:])
    assert np.array_equal(first[:, 0], first[:, 2])  # pair 2's frame n - 1 is frame 1
    for templates in (first, third):  # left's of the right image, right's of the left
        assert np.array_equal(templates[:, 1], templates[::-1, 0])
        assert np.array_equal(templates[:, 3], templates[::-1, 2])


@pytest.mark.parametrize('level', [0, 1])
def test_pyramid_levels_sample_as_their_full_images_made_around_the_face_only(level: int) -> None:
    """Pyramids made where sampled give the full levels' samples to the bit, made in part.

    As the tracker builds them: 8-bit images, the right one scaled by its camera's gain.
    """
    truth = PLANE.nodes()
    layouts = (
        SampleLayout.node_patches(truth, truth[:, 2] / 600, 3, np.zeros(34, dtype=bool)),
        SampleLayout.triangle_texture(mesh_topology(34).triangles, 4),
    )
    samples = SampleSet.of(layouts, 34)
    projections = level_projections((RIG.left, RIG.right), level)
    offsets = float(1 << level) * samples.level_offsets(np.eye(3), 0)
    points = samples.points(truth, offsets, None, float(1 << level))
    images = [np.clip(_wave(phase), 0, 255).astype(np.uint8) for phase in (0.1, 0.5)]
    factors = (1.0, 1 / 1.02)
    blank = np.zeros_like(images[0])
    pyramids = []
    for image, factor in zip(images, factors, strict=True):
        previous = ImagePyramid.build(blank, 2)
        previous.levels  # noqa: B018 - zeros wherever the new pyramid is not made
        pyramids.append(ImagePyramid.build(image, 2, reuse=previous, factor=factor))
    full = [ImagePyramid.build(image, 2) for image in images]
    full[1].scale(factors[1])
    sources = [PyramidLevel(pyramid, level) for pyramid in pyramids]
    arrays = [pyramid.levels[level] for pyramid in full]
    got = sample_images(sources, projections, points, samples.mask)
    expected = sample_images(arrays, projections, points, samples.mask)
    assert (got.values == expected.values).all() and (got.gradient == expected.gradient).all()
    assert (sample_values(sources, projections, points) == got.values).all()
    for pyramid in pyramids:
        made = pyramid.level_reaching(level, (0.0, -1.0, 0.0, -1.0))
        assert 0.02 < np.mean(made != 0) < 0.5, np.mean(made != 0)


def test_robust_residuals_are_the_huber_terms_of_the_patch_and_texture_residuals() -> None:
    truth = PLANE.nodes()
    layouts = (
        SampleLayout.node_patches(truth, truth[:, 2] / 600, 3, np.zeros(34, dtype=bool)),
        SampleLayout.triangle_texture(mesh_topology(34).triangles, 4),
    )
    samples = SampleSet.of(layouts, 34)
    projections = level_projections((RIG.left, RIG.right), 0)
    points = samples.points(truth, samples.level_offsets(np.eye(3), 0))
    sampled = sample_images((_wave(0.1), _wave(0.5)), projections, points, samples.mask)
    rng = np.random.default_rng(5)
    templates = (sampled.values[:, None] + rng.normal(0, 20, (2, 3, samples.size))).astype(
        np.float32
    )
    valid = sampled.valid & (rng.uniform(size=sampled.valid.shape) > 0.1)
    sampled = sampled._replace(valid=valid)
    coefficients = rng.uniform(0.1, 1.0, (3, samples.size))
    huber = Huber.of(samples, [15.0, 10.0])
    residuals = robust_residuals(samples, sampled, templates, coefficients, huber)
    expected = sampled.values[:, None] - templates
    patches, texture = _grouped(samples, expected)
    patches_valid, texture_valid = _grouped(samples, valid)
    # Texture: I - T_k minus its group's mean over the valid samples (float32 sums, as numpy).
    total = (texture * texture_valid[:, None]).sum(axis=-1, keepdims=True)
    texture -= total / np.maximum(texture_valid.sum(axis=-1), 1)[:, None, :, None]
    # Node patches: minus its least-squares brightness ramp a + b u + c v over the valid ones.
    basis = layouts[0].brightness  # (M, 3): 1, u, v
    valid_basis = patches_valid[..., None] * basis  # (C, G, M, 3)
    normal = np.einsum('cgmi,mj->cgij', valid_basis, basis)
    projected = np.einsum('cgmi,ckgm->ckgi', valid_basis, patches.astype(float))
    ramp = np.linalg.solve(normal[:, None], projected[..., None])[..., 0]
    fitted = (patches - np.einsum('ckgi,mi->ckgm', ramp, basis)).astype(np.float32)
    expected *= valid[:, None]
    fitted *= patches_valid[:, None]
    assert residuals.differences.dtype == np.float32
    patch_residuals, texture_residuals = _grouped(samples, residuals.differences)
    assert np.array_equal(texture_residuals, texture * texture_valid[:, None])  # bit for bit
    np.testing.assert_allclose(patch_residuals, fitted, atol=1e-3)  # of residuals up to ~80
    assert np.abs(fitted).max() > 40.0
    # The Huber weights and losses of those residuals, summed as numpy sums them.
    expected = residuals.differences
    magnitude = np.abs(expected)
    with np.errstate(divide='ignore'):
        weighted = coefficients * np.minimum(1.0, huber.threshold / magnitude)
    assert 0.05 < np.mean(weighted < coefficients) < 0.95  # both sides of the thresholds
    assert np.array_equal(residuals.weight, weighted.sum(axis=1))
    assert np.array_equal(residuals.weighted_residual, (weighted * expected).sum(axis=1))
    loss = np.where(
        magnitude <= huber.inlier_bound, magnitude**2, huber.twice * magnitude - huber.square
    )
    assert residuals.cost == float((coefficients * loss).sum())
    assert [c.tolist() for c in residuals.counts] == [
        v.sum(axis=-1).tolist() for v in _grouped(samples, valid)
    ]


def test_no_motion_gives_exactly_zero_motion() -> None:
    left, right = PLANE.pair()
    tracker = StereoTracker(RIG, StereoTrackerConfig(gamma=0.0, init=PLANE_INIT))
    tracker.reset(RIG.left.project(PLANE.nodes()))  # 34 nodes: boundary ones off the plane
    first = tracker.step(left, right)
    assert first.status == TrackStatus.TRACKING
    for _ in range(2):
        again = tracker.step(left.copy(), right.copy())
        assert again.status == TrackStatus.TRACKING
        assert np.array_equal(again.nodes_cam, first.nodes_cam)


def test_tracks_a_moving_plane_in_3d() -> None:
    frames = MOVING_PLANE
    tracker = StereoTracker(RIG, PLANE_CONFIG)
    init = RIG.left.project(PLANE.nodes(19))
    tracked = track_sequence(tracker, [f.pair() for f in frames], init)
    assert tracked.meshes.shape == (6, 19, 3)
    assert np.all(tracked.status == TrackStatus.TRACKING)
    errors = [_rms_mm(mesh, f.nodes(19)) for mesh, f in zip(tracked.meshes, frames, strict=True)]
    assert max(errors) < 0.5, errors
    final = tracked.results[-1]
    assert np.all(final.left_residuals < 10) and np.all(final.right_residuals < 10)
    assert np.abs(final.left_px - RIG.left.project(frames[-1].nodes(19))).max() < 1.0


def test_templates_left_to_prepare_give_the_same_track_whenever_it_runs() -> None:
    """prepare() after each step (a node, once the outputs are out) or in the next step.

    The caller writes every pair into the same two arrays, as a camera driver's buffers: the
    templates the next step samples must be the last pair's, not the next one's.
    """
    pairs = [f.pair() for f in MOVING_PLANE]
    left, right = (np.empty_like(image) for image in pairs[0])
    runs = []
    for prepared in (False, True):
        tracker = StereoTracker(RIG, PLANE_CONFIG)
        tracker.reset(RIG.left.project(PLANE.nodes(19)))
        meshes = []
        for pair in pairs:
            left[:], right[:] = pair
            meshes.append(tracker.step(left, right).nodes_cam)
            if prepared:
                tracker.prepare()
                tracker.prepare()  # nothing left to do
        runs.append(np.array(meshes))
    assert np.array_equal(*runs)
    errors = [_rms_mm(mesh, f.nodes(19)) for mesh, f in zip(runs[1], MOVING_PLANE, strict=True)]
    assert max(errors) < 0.5, errors


def _moving_plane_error(
    config: StereoTrackerConfig, pairs: list[tuple[np.ndarray, np.ndarray]]
) -> tuple[StereoTracker, float]:
    """A tracker after MOVING_PLANE's ``pairs``, and its largest node RMS error on them, mm."""
    tracker = StereoTracker(RIG, config)
    tracked = track_sequence(tracker, pairs, RIG.left.project(PLANE.nodes(19)))
    truth = [plane.nodes(19) for plane in MOVING_PLANE]
    return tracker, max(map(_rms_mm, tracked.meshes, truth))


@pytest.mark.parametrize('gain', [1.2, 0.8])
def test_the_right_cameras_gain_is_measured_and_divided_out(gain: float) -> None:
    pairs = [(left, right * gain + 10.0) for left, right in (f.pair() for f in MOVING_PLANE)]
    tracker, compensated = _moving_plane_error(PLANE_CONFIG, pairs)
    assert tracker.right_gain == pytest.approx(gain, abs=0.01)  # measured 1.196, 0.796
    _, ignored = _moving_plane_error(replace(PLANE_CONFIG, gain_compensation=False), pairs)
    # Measured: 0.17 mm with the gain divided out (as with equal cameras), 0.33 / 0.30 without.
    assert compensated < 0.2 < 0.25 < ignored, (compensated, ignored)


@pytest.mark.parametrize(('gain', 'matchings'), [(1.0, 1), (1.05, 2)])
def test_a_gain_beyond_the_measurements_resolution_has_the_nodes_matched_again(
    monkeypatch: pytest.MonkeyPatch, gain: float, matchings: int
) -> None:
    """Above GAIN_RESOLUTION (0.03) the nodes are matched again on the corrected pair."""
    matched = record_method(monkeypatch, StereoTracker, '_initial_nodes', lambda *_: None)
    left, right = PLANE.pair()
    tracker = StereoTracker(RIG, replace(PLANE_CONFIG, row_offset_correction=False))
    tracker.reset(RIG.left.project(PLANE.nodes(19)))
    assert tracker.step(left, right * gain).ok
    assert len(matched) == matchings
    assert tracker.right_gain == pytest.approx(gain, abs=0.005)


@pytest.mark.parametrize('offset', [0.5, -0.4])
def test_row_offset_follows_three_nodes_into_a_shifted_image(offset: float) -> None:
    """The right image is the left one moved down by ``offset`` px: three nodes measure it."""
    texture = cv2.GaussianBlur(np.random.default_rng(5).uniform(0, 255, (240, 320)), (0, 0), 3.0)
    left = (texture - texture.mean()) * 16.0 + 128.0  # a quarter of it beyond 0-255
    down = np.float32([[1, 0, 0], [0, 1, offset]])
    right = cv2.warpAffine(
        left, down, (320, 240), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )
    nodes = np.array([[100.0, 80.0], [160.0, 120.0], [220.0, 160.0]])
    measured = row_offset(left, right, nodes, nodes)
    assert measured == pytest.approx(offset, abs=0.05)  # measured 0.499, -0.424
    # Grey levels beyond 0-255 read as saturated (wrapped round, 0.609 and -0.300 were measured).
    saturated = row_offset(np.clip(left, 0, 255), np.clip(right, 0, 255), nodes, nodes)
    assert measured == saturated
    assert row_offset(left, right, nodes[:2], nodes[:2]) == 0.0  # fewer than MIN_NODES = 3


@pytest.mark.parametrize('offset', [0.4, -0.4, 3.0])
def test_a_row_offset_between_the_images_is_measured_and_taken_into_the_rig(offset: float) -> None:
    right_camera = RIG.with_right_rows_shifted(offset).right  # what the calibration missed
    pairs = [(f.image(RIG.left), f.image(right_camera)) for f in MOVING_PLANE]
    tracker, corrected = _moving_plane_error(PLANE_CONFIG, pairs)
    # Measured 0.410, -0.415 and 3.018 (4.475 in the first round: the nodes matched 3 px off)
    assert tracker.right_row_offset == pytest.approx(offset, abs=0.03)
    tracker.reset(RIG.left.project(PLANE.nodes(19)))
    assert tracker.right_row_offset == 0.0  # measured afresh on the next pair
    uncorrected = replace(PLANE_CONFIG, row_offset_correction=False)
    ignoring, ignored = _moving_plane_error(uncorrected, pairs)
    # Measured: 0.18 / 0.17 / 0.17 mm with the offset corrected (0.16 with none), 0.45 / 0.53 mm
    # without; at 3 px the nodes, matched 3 px off, triangulate to a plane 3.3 times the size of
    # a face, so the initialisation is refused (a track 203 mm off before that check).
    assert corrected < 0.2, corrected
    if abs(offset) < 1.0:
        assert ignored > 0.35, ignored
    else:
        after = ignoring.step(*pairs[0])
        assert after.status == TrackStatus.INITIALIZING
        assert 'a face 3.29 times the size' in after.reason


def test_group_contrast_is_the_rms_of_the_valid_values_about_their_mean() -> None:
    values = np.array([[[1.0, 2.0, 3.0, 100.0], [4.0, 8.0, np.nan, 6.0], [5.0, 5.0, 5.0, 5.0]]])
    valid = np.isfinite(values) & (values < 50.0)
    valid[0, 2] = False
    contrast = group_contrast(values, valid)
    # sqrt(((1 - 2)^2 + 0 + (3 - 2)^2) / 3), sqrt((4 + 4 + 0) / 3); no valid value: NaN
    np.testing.assert_allclose(contrast[0, :2], [np.sqrt(2 / 3), np.sqrt(8 / 3)], rtol=1e-12)
    assert contrast.shape == (1, 3) and np.isnan(contrast[0, 2])


def test_group_statistics_are_numpys_sums_to_the_bit() -> None:
    """The compiled RMS and contrasts equal the numpy expressions they replace, bit for bit.

    Node patches (a one-sided one among them, a group with no valid sample) and face-texture
    triangles, float32 grey levels at random valid samples.
    """
    rng = np.random.default_rng(5)
    truth = PLANE.nodes()
    one_sided = np.arange(34) % 7 == 0
    layouts = (
        SampleLayout.node_patches(truth, truth[:, 2] / 600, 3, one_sided),
        SampleLayout.triangle_texture(mesh_topology(34).triangles, 5),
    )
    samples = SampleSet.of(layouts, 34)
    size = samples.size
    valid = samples.mask & (rng.random((2, size)) < 0.8)
    valid[:, :49] = False  # node 0's patch: nothing valid in either image
    values = rng.uniform(0, 255, (2, size)).astype(np.float32)
    templates = rng.uniform(0, 255, (2, 4, size)).astype(np.float32)
    sampled = Sampled(np.ones((2, 3, size)), values, np.zeros((2, 2, size), np.float32), valid)
    coefficients = np.full((4, size), 0.25)
    residuals = robust_residuals(
        samples, sampled, templates, coefficients, Huber.of(samples, [3.0, 4.0])
    )
    got = group_statistics(samples, sampled, residuals, templates[:, 0])
    with np.errstate(invalid='ignore', divide='ignore'):
        rms = [
            np.sqrt((difference**2).sum(axis=-1) / count)
            for difference, count in zip(
                _grouped(samples, residuals.differences[:, 0]), residuals.counts, strict=True
            )
        ]
    patches = [_grouped(samples, array)[0] for array in (templates[:, 0], values, valid)]
    expected = (group_contrast(patches[0], patches[2]), group_contrast(patches[1], patches[2]))
    for new, old in [*zip(got.rms, rms, strict=True), *zip(got[1:], expected, strict=True)]:
        assert new.shape == old.shape and np.array_equal(new, old, equal_nan=True)
    assert np.isnan(got.rms[0][:, 0]).all() and np.isnan(got.contrast[:, 0]).all()


def test_the_gain_is_the_median_contrast_ratio_of_the_textured_patches() -> None:
    rng = np.random.default_rng(0)
    left = rng.normal(100.0, 10.0, (6, 49))
    values = np.stack([left, 1.3 * left - 20.0])
    mask = np.ones((6, 49), bool)
    values[1, 0] *= 3.0  # a highlight in one view: outvoted
    assert relative_gain(values, mask, floor=2.0) == pytest.approx(1.3)
    mask[:, 25:] = False  # a rim patch's other side: not sampled, not counted
    values[:, :, 25:] = np.nan
    assert relative_gain(values, mask, floor=2.0) == pytest.approx(1.3)
    values[:, 3:] = 100.0  # flat skin: 3 textured patches are enough, 2 are not
    assert relative_gain(values, mask, floor=2.0) == pytest.approx(1.3)
    values[:, 2] = 100.0
    assert relative_gain(values, mask, floor=2.0) == 1.0


def test_a_steady_motion_is_predicted_and_costs_fewer_iterations() -> None:
    frames = [PLANE.moved(np.array([0.003, -0.002, 0.004]) * k) for k in range(8)]
    init = RIG.left.project(PLANE.nodes(19))
    spent = {}
    for predict in (True, False):
        tracker = StereoTracker(RIG, replace(PLANE_CONFIG, predict_motion=predict))
        tracked = track_sequence(tracker, [f.pair() for f in frames], init)
        assert np.all(tracked.status == TrackStatus.TRACKING)
        errors = [_rms_mm(m, f.nodes(19)) for m, f in zip(tracked.meshes, frames, strict=True)]
        assert max(errors) < 0.5, errors
        spent[predict] = sum(r.iterations for r in tracked.results[3:])  # two pairs before
    assert spent[True] < 0.8 * spent[False], spent


def test_the_coarsest_level_runs_only_for_a_plane_too_far_for_the_next(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """coarsest_level_px on: level 0 alone for a small motion, level 1 first for a jump.

    The plane stands still for a pair first: the first pair after the initial one is solved as
    a pair after a gap (every level of ``gap_pyramid_levels``).
    """
    levels = record_method(monkeypatch, StereoTracker, '_level', lambda _s, _p, index: index)
    init = RIG.left.project(PLANE.nodes(19))
    for shift, order in ((0.0002, [0]), (0.004, [0, 1, 0])):
        frames = [PLANE, PLANE, PLANE.moved(np.array([shift, 0.0, 0.0]))]
        nodes = {}
        for limit in (0.5, 0.0):
            tracker = StereoTracker(RIG, replace(PLANE_CONFIG, coarsest_level_px=limit))
            tracker.reset(init)
            for frame in frames[:2]:
                tracker.step(*frame.pair())
            levels.clear()
            result = tracker.step(*frames[2].pair())
            assert levels == (order if limit else [1, 0])
            # Measured 0.15-0.16 mm; frame 0's nodes are 0.26 mm off after the 0.2 mm shift.
            assert _rms_mm(result.nodes_cam, frames[2].nodes(19)) < 0.2
            nodes[limit] = result.nodes_cam
        if len(order) > 1:  # started over from the same point: the full solve
            # (but pair 1, solved from level 0 alone with the limit and from every level
            # without, ends 27 um apart, and this pair 2 um)
            assert np.abs(nodes[0.5] - nodes[0.0]).max() < 1e-5


def test_a_coarse_level_ends_at_its_own_step_tolerance(monkeypatch: pytest.MonkeyPatch) -> None:
    """Level 1 stops at a larger step than level 0: fewer linearisations there, same track.

    Without the prediction, whose starts leave level 1 little to do: 16 against 22 coarse
    linearisations when written, the tracks 0.11 mm apart.
    """
    linearised = record_method(
        monkeypatch, PairEnergy, 'linearise', lambda level, _point: level.index
    )
    frames = [PLANE.moved(np.array([0.003, -0.002, 0.004]) * k) for k in range(5)]
    init = RIG.left.project(PLANE.nodes(19))
    coarse, meshes = {}, {}
    for tolerance in (0.5, 0.1):
        linearised.clear()
        config = replace(PLANE_CONFIG, coarse_step_tolerance=tolerance, predict_motion=False)
        tracker = StereoTracker(RIG, config)
        tracked = track_sequence(tracker, [f.pair() for f in frames], init)
        assert np.all(tracked.status == TrackStatus.TRACKING)
        coarse[tolerance] = linearised.count(1)
        meshes[tolerance] = tracked.meshes
        errors = [_rms_mm(m, f.nodes(19)) for m, f in zip(tracked.meshes, frames, strict=True)]
        assert max(errors) < 0.5, errors
    assert coarse[0.5] < coarse[0.1], coarse
    assert np.abs(meshes[0.5] - meshes[0.1]).max() < 2e-4  # m


def test_reset_from_a_named_initialisation() -> None:
    left, right = PLANE.pair()
    truth = PLANE.nodes()
    names = ('right_eye', 'left_eye', 'nose_tip', 'mouth_right', 'mouth_left', 'upper_lip')
    indices = [mesh_topology(34).index(name) for name in names]
    init = Initialisation(node_names=names, points=RIG.left.project(truth)[indices])
    tracker = StereoTracker(RIG, StereoTrackerConfig(init=PLANE_INIT))
    tracker.reset(init)
    result = tracker.step(left, right)
    assert result.ok
    assert np.linalg.norm(result.nodes_cam[indices] - truth[indices], axis=1).max() < 0.0005
    with pytest.raises(ConfigError, match='unknown node name'):
        tracker.reset(Initialisation(node_names=(*names[:5], 'ear'), points=init.points))
    assert tracker.step(left, right).ok  # a refused reset leaves the track as it was


def test_automatic_initialisation_by_a_detector() -> None:
    left, right = PLANE.pair()
    truth = PLANE.nodes(19)
    names = mesh_topology(19).node_names
    answers = iter([None, Initialisation(node_names=names, points=RIG.left.project(truth))])
    seen: list[np.ndarray] = []

    def detector(gray: np.ndarray) -> Initialisation | None:
        seen.append(gray)
        return next(answers)

    tracker = StereoTracker(RIG, PLANE_CONFIG, detector=detector)
    tracker.reset()
    waiting = tracker.step(left, right)
    assert waiting.status == TrackStatus.INITIALIZING and 'none detected' in waiting.reason
    found = tracker.step(left, right)
    # 0.52 mm measured (0.39 before each node patch's brightness ramp was removed from its
    # residuals: on this plane the ramp takes some of the texture's low frequencies).
    assert found.ok and np.linalg.norm(found.nodes_cam - truth, axis=1).max() < 0.0006
    assert tracker.step(left, right).ok and len(seen) == 2  # no detection while tracking
    assert seen[0].dtype == np.uint8 and seen[0].shape == left.shape
    with pytest.raises(ConfigError, match='needs a landmark detector'):
        StereoTracker(RIG, PLANE_CONFIG).reset()


def test_a_detector_finds_the_face_again_after_a_loss_and_each_track_keeps_its_depths() -> None:
    names = mesh_topology(19).node_names

    def found(plane: _Plane) -> Initialisation:
        return Initialisation(node_names=names, points=RIG.left.project(plane.nodes(19)))

    answers = iter([found(MOVING_PLANE[0]), None, found(MOVING_PLANE[3])])
    config = replace(PLANE_CONFIG, refine_depths=True)
    tracker = StereoTracker(RIG, config, detector=lambda gray: next(answers))
    tracker.reset()
    blank = np.zeros_like(PLANE.pair()[0])
    first = [tracker.step(*plane.pair()) for plane in MOVING_PLANE[:3]]
    lost = tracker.step(blank + 255, blank)
    waiting = tracker.step(blank + 255, blank)  # the detector sees no face
    second = [tracker.step(*plane.pair()) for plane in MOVING_PLANE[3:]]
    # A blank pair passes the residual test on this mesh (0.64 of the templates' contrast,
    # below lost_ratio 0.8); it has no texture left (min_texture_ratio).
    assert lost.status == TrackStatus.LOST and 'almost no texture' in lost.reason
    assert waiting.status == TrackStatus.LOST and 'none detected' in waiting.reason
    assert [r.new_track for r in first + second] == [True, False, False, True, False, False]
    assert all(r.ok for r in first + second)
    assert _rms_mm(second[-1].nodes_cam, MOVING_PLANE[5].nodes(19)) < 1.0
    # Offline, each track gets the frame-1 depths refined over its own pairs, not the last
    # track's (which would move the first track's meshes by the plane's 9 mm motion).
    final = tracker.with_final_depths([*first, lost, waiting, *second])
    alone = tracker.with_final_depths(first) + tracker.with_final_depths(second)
    for result, expected in zip(final[:3] + final[5:], alone, strict=True):
        np.testing.assert_array_equal(result.nodes_cam, expected.nodes_cam)


def test_bad_frames_never_raise() -> None:
    left, right = PLANE.pair()
    tracker = StereoTracker(RIG, StereoTrackerConfig(init=PLANE_INIT))
    before = tracker.step(left, right)
    assert before.status == TrackStatus.INITIALIZING and 'reset' in before.reason
    assert before.iterations == 0 and before.cost_history == ()
    tracker.reset(RIG.left.project(PLANE.nodes()))
    assert tracker.step(left, right).ok
    wrong = tracker.step(left[:100], right)
    assert wrong.status == TrackStatus.LOST and 'bad frame' in wrong.reason
    assert np.all(np.isfinite(wrong.nodes_cam))
    # The track survives a bad frame; a blank pair loses it, and another keeps it lost, with
    # the reason it was lost, why the search did not find it again, and the last valid estimate
    # (as FaceState's LOST promises; zeros until 2026-12-06); without a detector the next pair
    # that shows the face re-acquires it (it stayed LOST until a reset).
    assert tracker.step(left, right).ok
    blank = np.zeros_like(left)
    lost = tracker.step(blank + 255, blank)
    assert lost.status == TrackStatus.LOST and 'lost' in lost.reason
    still = tracker.step(blank + 255, blank)
    assert still.status == TrackStatus.LOST
    assert still.reason.startswith(f'{lost.reason}; not found again: patch residual / contrast')
    assert np.all(np.isfinite(lost.nodes_cam))
    np.testing.assert_array_equal(still.nodes_cam, lost.nodes_cam)
    np.testing.assert_array_equal(still.left_px, lost.left_px)
    assert tracker.step(left, right).ok


def test_initialisation_failure_is_reported() -> None:
    left, right = PLANE.pair()
    tracker = StereoTracker(RIG, StereoTrackerConfig(init=PLANE_INIT))
    tracker.reset(np.full((34, 2), 5.0))  # every node in the same corner, all matches equal
    result = tracker.step(np.zeros_like(left), np.zeros_like(right))
    # No estimate: INITIALIZING (LOST carries the last valid estimate), until a reset.
    assert result.status == TrackStatus.INITIALIZING and 'initialisation failed' in result.reason
    assert 'both images show the whole face with some texture' in result.reason  # black images
    later = tracker.step(left, right)
    assert later.status == TrackStatus.INITIALIZING and later.reason == result.reason
    assert np.all(np.isnan(later.nodes_cam))


def test_config_accepts_the_smallest_noise_floor_and_patch_it_documents() -> None:
    config = StereoTrackerConfig(noise_floor=0.5, patch_half_size=1)
    assert (config.noise_floor, config.patch_half_size) == (0.5, 1)
    for name, value in (('noise_floor', 0.0), ('patch_half_size', 0)):
        with pytest.raises(ConfigError, match=f'{name} = {value}'):
            StereoTrackerConfig(**{name: value})


def test_reset_and_config_reject_bad_input() -> None:
    tracker = StereoTracker(RIG, StereoTrackerConfig(init=PLANE_INIT))
    with pytest.raises(InputError, match=r'\(34, 2\)'):
        tracker.reset(np.zeros((19, 2)))
    few = np.full((34, 2), np.nan)
    few[:5] = 100.0
    with pytest.raises(InputError, match='only 5 nodes given'):
        tracker.reset(few)
    with pytest.raises(ConfigError, match='gamma'):
        StereoTrackerConfig(gamma=1.5)
    with pytest.raises(ConfigError, match='num_nodes'):
        StereoTrackerConfig(num_nodes=20)
    with pytest.raises(ConfigError, match='min_depth'):
        StereoInitConfig(min_depth=3.0)
    # An init file or ResetTracking request names at least 6 nodes (Initialisation), so a
    # smaller minimum would be accepted here and never reached.
    with pytest.raises(ConfigError, match='min_given_nodes'):
        StereoInitConfig(min_given_nodes=5)
    with pytest.raises(ConfigError, match='model_weight_edge'):
        StereoTrackerConfig(model_weight_edge=-1.0)
    with pytest.raises(ConfigError, match='fit_edge_weight'):
        StereoTrackerConfig(fit_edge_weight=2.0)
    with pytest.raises(ConfigError, match='coarsest_level_px'):
        StereoTrackerConfig(coarsest_level_px=-1.0)
    with pytest.raises(ConfigError, match='coarse_step_tolerance'):
        StereoTrackerConfig(coarse_step_tolerance=0.0)
    with pytest.raises(ConfigError, match='gap_pyramid_levels'):
        StereoTrackerConfig(gap_pyramid_levels=0)


def test_too_deep_a_pyramid_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match='too deep for 120x90 images: at most 3 leave'):
        StereoTracker(StereoRig.ideal(120, 90), StereoTrackerConfig(pyramid_levels=4))
    tracker = StereoTracker(StereoRig.ideal(120, 96), StereoTrackerConfig(pyramid_levels=3))
    assert tracker.topology.num_nodes == 34  # 96 px leave 24 px at level 2


def test_face_model_term_needs_a_model(monkeypatch: pytest.MonkeyPatch) -> None:
    def missing(num_nodes: int) -> None:
        raise ModelFileError(f'no default model of {num_nodes} nodes')

    monkeypatch.setattr('face_tracking_ros.tracking.stereo.default_model_path', missing)
    with pytest.raises(ConfigError, match='face-model term needs a model'):
        StereoTracker(RIG, StereoTrackerConfig())
    # Without the term no model is needed.
    off = StereoTrackerConfig(model_weight_edge=0.0, model_weight_inner=0.0)
    assert StereoTracker(RIG, off).topology.num_nodes == 34


def _noisy_pair(rng: np.random.Generator, plane: _Plane = PLANE) -> tuple[np.ndarray, np.ndarray]:
    """The plane's views with independent sensor noise of 2 grey levels."""
    return tuple(  # type: ignore[return-value]
        (image + rng.normal(0.0, 2.0, image.shape)).astype(np.float32) for image in plane.pair()
    )


def _patch_sq(layout: SampleLayout, image: np.ndarray, other: np.ndarray, nodes: np.ndarray):
    """Mean squared ZSSD residual (N,) of each node patch between two left images."""
    patches = SampleSet.of((layout,), 34)
    points = patches.points(nodes, patches.level_offsets(np.eye(3), 0))
    values = sample_values((image, other), level_projections((RIG.left, RIG.left), 0), points)
    difference = (values[0] - values[1]).reshape(34, -1)
    difference -= difference.mean(axis=1, keepdims=True)
    return np.mean(difference**2, axis=1)


def _highlight_depth_errors(ramp: bool) -> np.ndarray:
    """(19,) depth errors, m, of Gauss-Newton on the left-right term with a highlight in one view.

    Three highlights (40 grey levels, 8 px wide) near the nose tip and both lips' centres show
    in the right image only, as a skin highlight moves with the viewpoint.
    """
    left, right = PLANE.pair()
    truth = PLANE.nodes(19)
    rows, cols = np.mgrid[0 : right.shape[0], 0 : right.shape[1]].astype(np.float32)
    for x, y in RIG.right.project(truth)[[2, 8, 11]]:
        right = right + 40 * np.exp(-((cols - x - 4) ** 2 + (rows - y - 3) ** 2) / (2 * 8.0**2))
    rays = truth / np.linalg.norm(truth, axis=1, keepdims=True)
    nodes = truth.copy()
    for _ in range(8):
        layout = SampleLayout.node_patches(nodes, nodes[:, 2] / 600, 3, np.zeros(19, bool))
        if not ramp:  # the mean removed only (ZSSD)
            layout = replace(layout, terms=np.ones(19, dtype=np.int64))
        patches = SampleSet.of((layout,), 19)
        image = right.astype(np.float32)
        terms = depth_terms(RIG, left, image, patches, nodes, rays, np.eye(3), 1e6)
        step = np.clip(-terms.slope / terms.curvature, -0.003, 0.003)
        nodes = nodes + rays * step[:, None]
    return np.einsum('nd,nd->n', nodes - truth, rays)


def test_a_highlight_in_one_view_does_not_bias_the_depths() -> None:
    # Measured: at most 0.58 mm with each patch's brightness ramp removed, 3.75 mm with its mean.
    assert np.abs(_highlight_depth_errors(ramp=True)).max() < 0.0008
    assert np.abs(_highlight_depth_errors(ramp=False)).max() > 0.002


def test_depth_refinement_pools_noisy_pairs_into_the_true_depths() -> None:
    rng = np.random.default_rng(5)
    truth = PLANE.nodes()
    rays = truth / np.linalg.norm(truth, axis=1, keepdims=True)
    offsets = np.zeros(34)
    offsets[[10, 20, 30]] = [-0.003, 0.002, 0.003]  # m along the rays, within the linear range
    nodes = truth + offsets[:, None] * rays
    layout = SampleLayout.node_patches(nodes, nodes[:, 2] / RIG.left.focal, 3, np.zeros(34, bool))
    patches = SampleSet.of((layout,), 34)
    refinement = DepthRefinement.start(nodes, np.full(34, 0.005))
    max_step = np.full(34, 0.002)
    previous = _noisy_pair(rng)[0]
    steps = []
    for _ in range(15):
        left, right = _noisy_pair(rng)
        evidence = depth_evidence(RIG, left, right, patches, nodes, rays, np.eye(3), 6.0)
        temporal = _patch_sq(layout, left, previous, nodes)
        step = refinement.update(evidence, temporal, 2.0 * np.sqrt(2.0), max_step, 2.0)
        assert np.all(np.abs(step) <= max_step)
        nodes = nodes + step[:, None] * rays
        steps.append(step)
        previous = left
    error = np.einsum('nd,nd->n', nodes - truth, rays)
    # One pair measures a depth to about a millimetre here; fifteen pooled pairs to 0.25 mm
    # (0.2 before the brightness ramp was removed from each patch's left-right difference:
    # it takes some of this plane texture's low frequencies).
    assert np.sqrt(np.mean(error**2)) < 0.0003 and np.abs(error).max() < 0.0006
    np.testing.assert_allclose(refinement.correction, -offsets, atol=0.0006)
    assert np.all(refinement.information > 1.0 / 0.005**2)
    # The first pair moves the displaced nodes by up to max_step, the last ones barely move.
    assert np.abs(steps[0][[10, 20, 30]]).min() > 0.001
    assert np.abs(steps[-1]).max() < 0.0002


def test_depth_refinement_ignores_views_that_disagree() -> None:
    rng = np.random.default_rng(6)
    truth = PLANE.nodes()
    rays = truth / np.linalg.norm(truth, axis=1, keepdims=True)
    layout = SampleLayout.node_patches(truth, truth[:, 2] / RIG.left.focal, 3, np.zeros(34, bool))
    patches = SampleSet.of((layout,), 34)
    refinement = DepthRefinement.start(truth, np.full(34, 0.002))
    previous = _noisy_pair(rng)[0]
    # The right camera sees another surface (an occluder, or skin beyond the rim).
    other = _Plane([0.01, -0.03, 0.6], yaw=-0.4)
    nodes = truth
    for _ in range(10):
        left = _noisy_pair(rng)[0]
        right = _noisy_pair(rng, other)[1]
        evidence = depth_evidence(RIG, left, right, patches, nodes, rays, np.eye(3), 6.0)
        temporal = _patch_sq(layout, left, previous, nodes)
        step = refinement.update(evidence, temporal, 2.8, np.full(34, 0.002), 2.0)
        nodes = nodes + step[:, None] * rays
        previous = left
    # The gate closes at once: no node moves, none gains information.
    assert not np.any(refinement.correction)
    np.testing.assert_array_equal(refinement.information, np.full(34, 1.0 / 0.002**2))


def test_depth_refinement_steps_by_recursive_least_squares_within_three_sigmas() -> None:
    refinement = DepthRefinement.start(PLANE.nodes()[:3], np.array([0.001, 0.002, 0.004]))
    # Node 0 and 1 pulled far out and in (g = -+1e9 grey^2/m), node 2 a little (g = -2e3).
    evidence = DepthEvidence(
        slope=np.array([-1e9, 1e9, -2e3]),
        curvature=np.array([1e9, 1e9, 1e6]),
        minimum_sq=np.ones(3),
    )
    steps = [refinement.update(evidence, np.ones(3), 2.0, np.full(3, 0.01), 2.0) for _ in range(3)]
    # Nodes 0 and 1 stop at CORRECTION_SIGMAS (3) initial standard deviations in one step.
    # Node 2: I = 1 / 0.004^2 + k 1e6 / 2^2 after k pairs, step -(g / 2^2) / I = 500 / I m.
    information = 1 / 0.004**2 + np.arange(1, 4) * 2.5e5
    expected = np.zeros((3, 3))
    expected[0, :2] = [0.003, -0.006]
    expected[:, 2] = 500.0 / information
    np.testing.assert_allclose(steps, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(refinement.correction, expected.sum(axis=0), rtol=1e-12)
    # A pair where node 2's temporal residual is unknown adds nothing to its residual sums.
    refinement.update(evidence, np.array([1.0, 1.0, np.nan]), 2.0, np.full(3, 0.01), 2.0)
    assert refinement.left_right_sq.tolist() == [4.0, 4.0, 3.0]
    assert refinement.temporal_sq.tolist() == [4.0, 4.0, 3.0]


def test_a_pair_whose_projections_are_not_rectified_is_refused_by_name() -> None:
    right = RIG.right
    wider = replace(right, p=right.p * np.array([[1.2], [1.0], [1.0]]))  # fx 720 against 600
    with pytest.raises(InputError, match=r'left and right P differ in fx \(600 and 720\)'):
        StereoRig(RIG.left, wider)
    taller = replace(right, p=right.p * np.array([[1.0], [1.1], [1.0]]))  # fy 660 against 600
    with pytest.raises(InputError, match=r'left and right P differ in fy \(600 and 660\)'):
        StereoRig(RIG.left, taller)
    within = replace(right, p=right.p * np.array([[1.0], [1.00005], [1.0]]))  # 5e-5 <= 1e-4
    assert StereoRig(RIG.left, within).right is within
    lower = right.p.copy()
    lower[1, 3] = -6.0  # a vertical baseline
    with pytest.raises(InputError, match=r'P\[1,3\] must be 0 \(a horizontal baseline\)'):
        StereoRig(RIG.left, replace(right, p=lower))
    assert StereoRig(RIG.left, RIG.with_right_rows_shifted(0.3).right).baseline == RIG.baseline


def test_a_pair_given_left_for_right_is_said_to_be_swapped() -> None:
    """Left and right topics exchanged: the right camera has Tx = 0 and the left -fx B."""
    with pytest.raises(InputError) as refused:
        StereoRig(RIG.right, RIG.left)
    assert str(refused.value) == (
        'invalid camera: right P[0,3] must be -fx*B < 0 for a rectified stereo pair (it is 0; '
        "the left camera's is -66: are left and right swapped?)"
    )
    flat = replace(RIG.right, p=RIG.left.p)  # two cameras of Tx 0: no hint of a swap
    with pytest.raises(InputError, match=r'rectified stereo pair \(it is 0\)$'):
        StereoRig(RIG.left, flat)


def test_a_baseline_in_millimetres_is_refused_before_any_pair() -> None:
    """The right camera_info's P[0,3] = -fx B with B = 110 (mm) instead of 0.11 m.

    Every face 0.25-2 m away is 33000 px or more apart between the images: refused when the
    tracker is built, naming the unit (matched regardless, 6 of 60 synthetic faces read 0.38 to
    0.90 times an adult's, the others too few nodes). Left and right exchanged as well, the rig's
    own check names the swap first.
    """
    millimetres = replace(RIG.right, p=RIG.right.p * np.array([[1, 1, 1, 1000]]))
    rig = StereoRig(RIG.left, millimetres)
    with pytest.raises(InputError) as refused:
        StereoTracker(rig, StereoTrackerConfig())
    assert str(refused.value) == (
        "the right camera_info's P[0,3] = -6.6e+04 (-fx B) gives a baseline B = 110 m: is it "
        'in millimetres? P[0,3] takes B in metres (0.11 m: P[0,3] = -66). A face 0.25-2 m away '
        'would be 33000 px or more apart between the images, wider than they are (640 px): no '
        'face is seen by both cameras'
    )
    with pytest.raises(InputError, match='are left and right swapped'):
        StereoRig(millimetres, RIG.left)
    # The widest baseline the synthetic rigs take (0.3 m) at a long focal length passes.
    StereoTracker(StereoRig.ideal(focal=1400.0, baseline=0.3), StereoTrackerConfig())


def test_loss_reason_names_each_check_by_hand() -> None:
    """§3.3's checks one at a time: a face in view with matching patches is tracked."""
    nodes = mesh_topology(34).reference_shape + np.array([0.0, 0.0, 0.6])
    config = StereoTrackerConfig()  # lost_ratio 0.8, min_texture_ratio 0.3

    def reason(points: np.ndarray, rms: float = 5.0, image_contrast: float = 10.0) -> str:
        shape = (2, len(nodes))  # both cameras' node patches, template contrast 10
        statistics = GroupStatistics(
            (np.full(shape, rms),), np.full(shape, 10.0), np.full(shape, image_contrast)
        )
        return loss_reason(points, statistics, RIG, config)

    assert reason(nodes) == ''
    assert reason(np.where(np.arange(34)[:, None] == 3, np.nan, nodes)) == 'non-finite nodes'
    behind = nodes.copy()
    behind[3, 2] = -0.1
    assert reason(behind) == 'a node went behind the camera'
    # 50 px from the left image's edge, the right camera sees a node f B / z = 110 px further:
    # outside its image. A face-edge node may be (the left image carries it), an inner one not.
    topology = mesh_topology(34)
    edge_node, inner_node = np.flatnonzero(topology.group_mask(Group.EDGE))[0], 3
    assert not topology.group_mask(Group.EDGE)[inner_node]
    side = [(50.0 - 319.5) * 0.6 / 600.0, 0.0, 0.6]
    assert RIG.left.project(np.array([side]))[0] == pytest.approx([50.0, 239.5])
    assert RIG.right.project(np.array([side]))[0, 0] == pytest.approx(-60.0)
    for index, expected in (
        (edge_node, ''),
        (inner_node, f'inner nodes outside the right image ({topology.node_names[inner_node]})'),
    ):
        moved = nodes.copy()
        moved[index] = side
        assert reason(moved) == expected
    # While tracking, a node counts as seen while its patch (half size 3) reaches into the
    # image: an inner node 2.5 px beyond the right image's side is, 3.5 px beyond is not.
    for beyond, expected in (
        (2.5, ''),
        (3.5, f'inner nodes outside the right image ({topology.node_names[inner_node]})'),
    ):
        moved = nodes.copy()
        moved[inner_node] = [(110.0 - beyond - 319.5) * 0.6 / 600.0, 0.0, 0.6]
        assert RIG.right.project(moved[inner_node : inner_node + 1])[0, 0] == pytest.approx(
            -beyond
        )
        assert reason(moved) == expected
    moved = nodes.copy()
    moved[edge_node] = [0.0, -0.5, 0.6]  # above both images
    name = topology.node_names[edge_node]
    assert reason(moved) == f'face-edge nodes outside both images ({name})'
    assert reason(nodes, rms=8.0) == ''
    assert reason(nodes, rms=8.5) == 'patch residual / contrast 0.85 exceeds 0.8'
    assert reason(nodes, image_contrast=3.0) == ''
    assert reason(nodes, image_contrast=2.9).startswith(
        'the images show almost no texture where the face was (patch contrast 0.29 of'
    )


def test_space_rows_carry_the_image_gradient_to_the_points() -> None:
    """``h = (P_(1, 2)' g - (g . x) P_3) / (P X)_3`` of eq. 2, zero where not valid."""
    rng = np.random.default_rng(39)
    projections = level_projections((RIG.left, RIG.right), 1)
    points = PLANE.nodes().T + rng.normal(0, 0.01, (3, 34))
    homogeneous = homogeneous_pixels(projections, points)
    gradient = rng.normal(0, 20, (2, 2, 34)).astype(np.float32)
    valid = rng.random((2, 34)) < 0.8
    rows = space_rows(projections, homogeneous, gradient, valid)
    pixels = homogeneous[:, :2] / homogeneous[:, 2:]
    for camera in range(2):
        for s in range(34):
            p, g = projections[camera, :, :3], gradient[camera, :, s].astype(float)
            jacobian = (p[:2] - pixels[camera, :, s, None] * p[2]) / homogeneous[camera, 2, s]
            expected = jacobian.T @ g if valid[camera, s] else np.zeros(3)
            np.testing.assert_allclose(rows[camera, :, s], expected, rtol=1e-12, atol=1e-9)


def test_largest_motion_is_the_largest_pixel_shift_in_either_image() -> None:
    rng = np.random.default_rng(40)
    nodes = PLANE.nodes()
    moved = nodes + rng.normal(0, 0.002, nodes.shape)
    projections = level_projections((RIG.left, RIG.right), 0)
    shifts = [camera.project(moved) - camera.project(nodes) for camera in (RIG.left, RIG.right)]
    expected = np.abs(shifts).max()
    assert largest_motion(projections, nodes, moved) == pytest.approx(expected, rel=1e-12)
    moved[3, 2] = np.nan
    assert np.isnan(largest_motion(projections, nodes, moved))


def test_assembled_normal_equations_are_bincounts_sums_to_the_bit() -> None:
    rng = np.random.default_rng(41)
    truth = PLANE.nodes()
    layouts = (
        SampleLayout.node_patches(truth, truth[:, 2] / 600, 3, np.zeros(34, dtype=bool)),
        SampleLayout.triangle_texture(mesh_topology(34).triangles, 4),
    )
    for samples in (SampleSet.of(layouts, 34), SampleSet.of(layouts[:1], 34)):
        sizes = [
            (len(layout.mask), 3 * len(gather))  # groups, 3 k (k slot nodes)
            for layout, gather in zip(layouts, samples.gather, strict=False)
        ]
        blocks = [rng.normal(size=(groups, size, size)) for groups, size in sizes]
        vectors = [rng.normal(size=(groups, size)) for groups, size in sizes]
        matrix, vector = samples.assemble(blocks, vectors)
        values = np.concatenate([block.ravel() for block in blocks])
        expected = np.bincount(samples.block_index, weights=values, minlength=102 * 102)
        assert np.array_equal(matrix, expected.reshape(102, 102))
        values = np.concatenate([part.ravel() for part in vectors])
        assert np.array_equal(vector, np.bincount(samples.vector_index, values, minlength=102))
