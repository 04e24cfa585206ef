"""Tests of the simulated clicks (clicks.py): truth projections, click noise, the init file."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.synthetic.clicks import clicks_from_bag, simulated_clicks, write_init_file
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.recording import record
from face_tracking_ros.synthetic.scenes import SceneConfig, SequenceRenderer
from face_tracking_ros.tracking.initialisation import Initialisation, load_init_file

CAMERA = PinholeCamera.ideal(640, 480, 600.0)


def _nodes_at(pixels: np.ndarray, depth: float = 0.6) -> np.ndarray:
    """(N, 3) camera-frame points, ``depth`` m away, that project to (N, 2) ``pixels``."""
    k = CAMERA.k
    x = (pixels[:, 0] - k[0, 2]) * depth / k[0, 0]
    y = (pixels[:, 1] - k[1, 2]) * depth / k[1, 1]
    return np.column_stack([x, y, np.full(len(pixels), depth)])


def test_noiseless_clicks_are_the_projections_inside_the_image():
    edge = 1e-6  # clear of the rounding of the projection
    inside = [[edge, edge], [639 - edge, 479 - edge], [edge, 479 - edge], [639 - edge, edge]]
    inside += [[320.0, 240.0], [100.0, 300.0]]
    outside = [[-1e-3, 100.0], [639.001, 100.0], [100.0, 479.001], [100.0, -1e-3]]
    pixels = np.array(outside[:2] + inside + outside[2:])
    names = tuple(f'n{k}' for k in range(len(pixels)))
    init = simulated_clicks(names, _nodes_at(pixels), CAMERA, rng=None)
    assert init.node_names == names[2:8]
    np.testing.assert_allclose(init.points, pixels[2:8], atol=1e-9)


def test_clicks_that_leave_too_few_nodes_in_the_image_name_the_noise():
    """A noise of 1e6 px left no node inside: 'initialisation needs at least 6 nodes, got 0'."""
    pixels = np.column_stack([np.linspace(100, 500, 10), np.full(10, 240.0)])
    names = tuple(f'n{k}' for k in range(len(pixels)))
    with pytest.raises(
        ConfigError,
        match=r'^simulated clicks: 0 of the 10 nodes fall inside the '
        r'640x480 image with a click noise of 1e\+06 px; the initialisation needs '
        r'at least 6$',
    ):
        simulated_clicks(names, _nodes_at(pixels), CAMERA, 1e6, np.random.default_rng(0))


@pytest.mark.parametrize('noise_px', [None, 0.5])
def test_click_noise_has_the_asked_std_and_1_px_by_default(noise_px):
    rng = np.random.default_rng(7)
    pixels = np.column_stack([rng.uniform(50, 590, 4000), rng.uniform(50, 430, 4000)])
    names = tuple(f'n{k}' for k in range(len(pixels)))
    kwargs = {} if noise_px is None else {'noise_px': noise_px}
    init = simulated_clicks(
        names, _nodes_at(pixels), CAMERA, rng=np.random.default_rng(1), **kwargs
    )
    error = init.points - pixels
    assert np.abs(error.mean(axis=0)).max() < 0.05
    np.testing.assert_allclose(error.std(axis=0), [noise_px or 1.0] * 2, rtol=0.05)


def test_an_init_file_reads_back_with_its_sigma(tmp_path):
    init = Initialisation(
        node_names=('right_eye', 'left_eye', 'nose_tip', 'mouth_right', 'mouth_left', 'chin'),
        points=np.array([[1.5, 2.0], [300, 4.25], [5, 200], [400, 300], [90, 10], [11, 412.125]]),
        sigma=np.array([0.001, -0.002]),
    )
    back = load_init_file(write_init_file(init, tmp_path / 'init.json'))
    assert back.node_names == init.node_names
    np.testing.assert_array_equal(back.points, init.points)
    np.testing.assert_array_equal(back.sigma, init.sigma)


def test_bag_clicks_are_the_first_truth_in_the_left_camera_seeded_by_the_bag_name(tmp_path):
    config = SceneConfig(kind='stereo', sequences=2, frames=1, width=320, height=240, focal=300.0)
    first, second = (bag.path for bag in record(config, tmp_path))
    exact = clicks_from_bag(first, 0.0)
    truth = next(SequenceRenderer(config, 0).frames(0)).truth
    names = FacePopulation().node_names
    expected = simulated_clicks(names, truth.nodes_camera, config.cameras()['left'])
    assert exact.node_names == expected.node_names
    np.testing.assert_allclose(exact.points, expected.points, atol=1e-9)
    seeded = clicks_from_bag(first, seed=zlib.crc32(b'subject_00_seq_00'))
    np.testing.assert_array_equal(clicks_from_bag(first).points, seeded.points)
    error = clicks_from_bag(first).points - exact.points
    assert 0.0 < np.abs(error).max() < 5.0  # 1 px noise
    assert not np.array_equal(
        clicks_from_bag(second).points - clicks_from_bag(second, 0.0).points, error
    )
