"""Raw camera images and pixels to the rectified image of P (imaging.rectification)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging.rectification import Rectifier

RIG = StereoRig.ideal(640, 480, 600.0, 0.11)
TURN = rodrigues(np.radians([0.5, -2.0, 0.3]))[0]
RAW_K = np.array([[612.0, 0.0, 331.0], [0.0, 608.0, 236.5], [0.0, 0.0, 1.0]])
CAMERAS = {
    'plumb_bob': replace(
        RIG.right, k=RAW_K, d=np.array([-0.28, 0.09, 0.001, -0.001, 0.01]), r=TURN
    ),
    'rational_polynomial': replace(
        RIG.left,
        d=np.array([-0.2, 0.05, 0.0005, 0.0002, 0.0, 0.01, 0.002, 0.0]),
        distortion_model='rational_polynomial',
        r=TURN,
    ),
    'equidistant': replace(
        RIG.left, k=RAW_K, d=np.array([0.05, -0.01, 0.002, 0.0]), distortion_model='equidistant'
    ),
}


def _face_points(count: int = 60) -> np.ndarray:
    """Points where a face would be: 0.4-0.9 m ahead, within the field of view."""
    rng = np.random.default_rng(3)
    return rng.uniform([-0.15, -0.12, 0.4], [0.15, 0.12, 0.9], (count, 3))


@pytest.mark.parametrize('model', sorted(CAMERAS))
def test_raw_pixels_of_points_rectify_to_their_projection_through_p(model):
    camera = CAMERAS[model]
    points = _face_points()
    raw = camera.raw_pixels(points)
    assert np.abs(raw - camera.project(points)).max() > 3.0  # the raw image differs
    np.testing.assert_allclose(Rectifier(camera).points(raw), camera.project(points), atol=1e-3)


def test_rectified_image_shows_each_raw_pixel_where_p_projects_its_point():
    """A raw image of bright dots: rectified, each dot's centre is where its raw pixel maps to."""
    camera = CAMERAS['plumb_bob']
    points = _face_points(12)
    raw_px = camera.raw_pixels(points)
    raw = np.zeros((camera.height, camera.width), np.uint8)
    for x, y in np.round(raw_px).astype(int):
        raw[y - 1 : y + 2, x - 1 : x + 2] = 255
    rectified = Rectifier(camera).image(raw).astype(float)
    expected = camera.rectified_pixels(np.round(raw_px))  # the dots sit on whole raw pixels
    rows, columns = np.mgrid[: camera.height, : camera.width]
    for x, y in expected:
        window = (np.abs(columns - x) < 6) & (np.abs(rows - y) < 6)
        weights = rectified * window
        centre = np.array([(weights * columns).sum(), (weights * rows).sum()]) / weights.sum()
        assert np.linalg.norm(centre - (x, y)) < 0.1


def test_a_camera_without_distortion_or_rotation_passes_images_and_points_through():
    image = np.arange(640 * 480, dtype=np.uint32).astype(np.uint8).reshape(480, 640)
    points = np.array([[10.5, 20.25], [300.0, 200.0]])
    for rectifier in (Rectifier(RIG.right), Rectifier(CAMERAS['plumb_bob'], enabled=False)):
        assert rectifier.identity
        assert rectifier.image(image) is image
        np.testing.assert_array_equal(rectifier.points(points), points)
    assert not RIG.left.needs_rectification and not Rectifier(CAMERAS['plumb_bob']).identity


def test_a_projection_other_than_k_needs_rectification_too():
    camera = replace(RIG.left, k=RAW_K)  # no distortion, R = I, but P's intrinsics differ
    assert camera.needs_rectification
    points = _face_points()
    np.testing.assert_allclose(camera.rectified_pixels(camera.raw_pixels(points)),
                               camera.project(points), atol=1e-6)  # fmt: skip


def test_an_unknown_distortion_model_is_refused_by_name():
    camera = replace(RIG.left, d=np.array([0.1, 0.0, 0.0]), distortion_model='kannala_brandt')
    with pytest.raises(InputError, match="distortion model 'kannala_brandt' with 3 coefficients"):
        Rectifier(camera)
    no_distortion = replace(RIG.left, d=np.zeros(3), distortion_model='kannala_brandt')
    assert Rectifier(no_distortion).identity  # zero D: nothing to rectify, whatever its name


def test_a_change_of_distortion_or_rotation_is_a_new_calibration():
    camera = CAMERAS['plumb_bob']
    assert camera.same_calibration(replace(camera, k=camera.k.copy()))
    assert not camera.same_calibration(replace(camera, d=camera.d * 1.1))
    assert not camera.same_calibration(replace(camera, r=np.eye(3)))
    assert not camera.same_calibration(replace(camera, d=camera.d[:4]))
    # A driver recomputing its camera_info: differences within 1e-4 are the same calibration.
    assert camera.same_calibration(replace(camera, p=camera.p * (1 + 5e-5)))
    assert not camera.same_calibration(replace(camera, p=camera.p * (1 + 1e-3)))
