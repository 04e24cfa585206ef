"""Which ROI samples count as inside the image: FaceProjection.sample and the solver's own.

The solver's gradients are central differences one pixel either side of each sample
(``sample_with_gradient_xy``); a sample nearer the border than 1 px reads the replicated border,
so it must not count. Every node's ROI is made to land on the same hand-placed pixels on the
centre row (then column) of a 640 x 480 image, whose last pixel is 639 (479). By hand: on x,
0.5 and 638.5 are out (0.5 - 1 < 0, 638.5 + 1 > 639), 1.5, 2.5 and 637.5 in; on y, 0.5 and
478.5 out, 1.5 and 477.5 in.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.imaging import ImagePyramid, square_offsets
from face_tracking_ros.imaging.photometric import PhotometricInvariance
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.mono_priors import Priors
from face_tracking_ros.tracking.mono_projection import FaceProjection
from face_tracking_ros.tracking.mono_rois import Params, Roi
from face_tracking_ros.tracking.mono_solve import Level, MonoSolver

CAMERA = PinholeCamera.ideal()  # 640 x 480, focal 600 px, centre (319.5, 239.5)
DEPTH = 0.5
XS = (0.5, 1.5, 2.5, 637.5, 638.5)
YS = (0.5, 1.5, 477.5, 478.5)
INSIDE = [False, True, True, True, False] + [False, True, True, False]  # by hand, as above
PIXELS = np.array([(x, 239.5) for x in XS] + [(319.5, y) for y in YS])  # M = 9 = (2 h + 1)^2


def _hand_placed(model: FaceModel) -> tuple[Roi, Params]:
    """A ROI whose M = 9 samples of every node are seen at PIXELS from t = (0, 0, DEPTH)."""
    shape = model.shape()
    centred = (PIXELS - [319.5, 239.5]) * DEPTH / CAMERA.focal
    points = np.column_stack([centred, np.zeros(len(PIXELS))])  # face frame = camera axes
    offsets = np.ascontiguousarray((points[None, :, :] - shape[:, None, :]).transpose(2, 0, 1))
    p, q = model.p, model.q
    count, size = offsets.shape[1:]
    roi = Roi(offsets, np.zeros((q, 3, count, size)), np.zeros((p, 3, count, size)), np.zeros(p))
    return roi, Params(np.zeros(3), np.array([0.0, 0.0, DEPTH]), np.zeros(q), np.zeros(p))


def _hand_placed_face(
    model: FaceModel, texture: np.ndarray
) -> tuple[FaceProjection, ImagePyramid, Roi, Params]:
    """The model's projection, a one-level pyramid of ``texture`` and :func:`_hand_placed`."""
    face = FaceProjection(model, CAMERA, num_levels=1, visibility_cos=0.2)
    return face, ImagePyramid.build(texture, 1), *_hand_placed(model)


def test_a_sample_is_inside_when_its_central_differences_read_the_image(
    model_factory, texture_factory
) -> None:
    model = model_factory(planar=True)
    face, pyramid, roi, params = _hand_placed_face(model, texture_factory())

    sampled = face.sample(pyramid, params, 0, roi)

    maps = face.points(params, 0, roi)
    x, y = (axis.reshape(sampled.inside.shape) for axis in (maps.map_x, maps.map_y))
    assert np.abs(x - PIXELS[:, 0]).max() < 1e-3 and np.abs(y - PIXELS[:, 1]).max() < 1e-3
    assert sampled.inside.shape == (model.num_nodes, len(PIXELS))
    assert (sampled.inside == np.array(INSIDE)).all()


def test_the_solver_linearisation_counts_the_same_samples_inside(
    model_factory, texture_factory
) -> None:
    """A level's first evaluation weighs the samples taken with the gradient: same rule."""
    model = model_factory(planar=True)
    roi, params = _hand_placed(model)
    config = MonoTrackerConfig(patch_half_size=1)
    face = FaceProjection(model, CAMERA, num_levels=1, visibility_cos=0.2)
    invariance = PhotometricInvariance.of(config.photometric, square_offsets(1))
    solver = MonoSolver(model, config, face, invariance, Priors.of(model, config.prior_weight))
    pyramid = ImagePyramid.build(texture_factory(), 1)
    template = face.sample(pyramid, params, 0, roi).samples
    visibility = np.ones(template.shape)
    camera = face.level_cameras[0]
    level = Level(0, pyramid, camera, roi, template, invariance.projection(template), visibility)

    linear = solver._linearise(level, params, free_sigma=False)

    assert np.array_equal(linear.sampled.samples, template)
    assert (linear.sampled.inside == np.array(INSIDE)).all()


def test_the_solvers_cost_at_the_templates_own_samples_is_the_prior_alone(
    model_factory, texture_factory
) -> None:
    """Residuals all zero: eq. 6's cost is ``alpha' lambda Sigma_alpha^-1 alpha`` alone.

    By hand, lambda 2 on alpha variances (4, 1): at alpha (2, 1) the prior costs
    2 (4 / 4 + 1 / 1) = 4.
    """
    model = replace(model_factory(p=1, q=2), alpha_prior_covariance=np.diag([4.0, 1.0]))
    roi, params = _hand_placed(model)
    params = params._replace(alpha=np.array([2.0, 1.0]))
    config = MonoTrackerConfig(patch_half_size=1)
    face = FaceProjection(model, CAMERA, num_levels=1, visibility_cos=0.2)
    invariance = PhotometricInvariance.of(config.photometric, square_offsets(1))
    solver = MonoSolver(model, config, face, invariance, Priors.of(model, 2.0))
    pyramid = ImagePyramid.build(texture_factory(), 1)
    template = face.sample(pyramid, params, 0, roi).samples
    camera = face.level_cameras[0]
    projection = invariance.projection(template)
    level = Level(0, pyramid, camera, roi, template, projection, np.ones(template.shape))
    linear = solver._linearise(level, params, free_sigma=False)

    system = solver._evaluate(level, params, linear, 1.0, damping=1e-3, bound=np.inf)

    assert system.cost == pytest.approx(4.0)


def test_sampling_at_a_non_finite_estimate_is_an_input_error(
    model_factory, texture_factory
) -> None:
    """A diverged solve's points are refused before any image is read (the frame is LOST)."""
    face, pyramid, roi, params = _hand_placed_face(model_factory(planar=True), texture_factory())
    diverged = params._replace(t=np.array([np.nan, 0.0, DEPTH]))

    for sample in (face.sample, face.sample_stencil):
        with pytest.raises(InputError, match='NaN or Inf'):
            sample(pyramid, diverged, 0, roi)


def test_the_posed_shape_is_the_models_to_the_bit_as_sigma_and_alpha_change(
    model_factory,
) -> None:
    """Eq. 3 with its sigma part kept between poses: FaceModel.shape's values, sigma changing."""
    model = model_factory(p=2, q=3)
    face = FaceProjection(model, CAMERA, num_levels=1, visibility_cos=0.2)
    rng = np.random.default_rng(3)
    sigmas = [rng.normal(size=2) for _ in range(2)]
    for sigma in (sigmas[0], sigmas[0].copy(), sigmas[1], sigmas[0]):
        alpha = rng.normal(size=3)
        params = Params(rng.normal(0.0, 0.1, 3), np.array([0.0, 0.0, DEPTH]), alpha, sigma)
        assert np.array_equal(face.pose(params)[1], model.shape(sigma, alpha))
