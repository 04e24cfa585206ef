"""MonoTracker and the LK + PnP baseline on rendered synthetic faces (short sequences).

The full-length figures of issue 6 (1000 frames) come from the benchmark; these tests use 24
frames of a held-out subject with free head motion, moving light and sensor noise, with bounds
loose enough for so few frames but tight enough to catch a broken tracker; the first test runs
on procedural skin, on a real face photo, with motion blur and on JPEG-compressed frames. The
last two follow a head moving fast (about 8 px a frame at 10 fps, seed 7, subject 0) across a
bundle adjustment and a re-acquisition.
"""

from __future__ import annotations

from dataclasses import replace
import itertools

import cv2
import numpy as np
import pytest

from face_tracking_ros.data import photo_face_paths
from face_tracking_ros.synthetic.clicks import simulated_clicks
from face_tracking_ros.synthetic.scenes import SceneConfig, SequenceRenderer
from face_tracking_ros.tracking.baseline import LKPnPTracker
from face_tracking_ros.tracking.evaluation import evaluate_tracker
from face_tracking_ros.tracking.mono import MonoTracker
from face_tracking_ros.tracking.result import TrackStatus

SUBJECT = 9  # not among the learner's usual first training subjects


def _free_sequence(config: SceneConfig):
    """The subject's first sequence: images, true nodes, camera, population."""
    renderer = SequenceRenderer(config, SUBJECT)
    frames = list(renderer.frames(0))
    return (
        [f.images['image'] for f in frames],
        np.array([f.truth.nodes_camera for f in frames]),
        config.cameras()['image'],
        renderer.population,
    )


FREE = SceneConfig(kind='mono', subjects=SUBJECT + 1, frames=24, fps=30.0, motion='free')


@pytest.fixture(scope='module')
def free_sequence():
    """24 frames at 30 fps of free head motion, procedural skin."""
    return _free_sequence(FREE)


@pytest.fixture(scope='module')
def photo_sequence():
    """The same frames with real skin: the packaged face photo as the texture."""
    photo, nodes = photo_face_paths()
    return _free_sequence(replace(FREE, texture=photo, texture_nodes=nodes))


@pytest.fixture(scope='module')
def blurred_sequence():
    """The same motion with motion blur: each frame the face averaged over half a frame period."""
    return _free_sequence(replace(FREE, motion_blur=True))


@pytest.fixture(scope='module')
def jpeg_sequence(free_sequence):
    """The procedural-skin frames JPEG-compressed at quality 75.

    As a compressed image topic carries them at a bandwidth-saving setting (image_transport's
    default is 95): block artifacts and lost fine texture.
    """
    images, *rest = free_sequence
    encode = [cv2.IMWRITE_JPEG_QUALITY, 75]
    decoded = [cv2.imdecode(cv2.imencode('.jpg', image, encode)[1], -1) for image in images]
    return (decoded, *rest)


@pytest.mark.parametrize(
    'sequence', ['free_sequence', 'photo_sequence', 'blurred_sequence', 'jpeg_sequence']
)
def test_mono_tracks_a_free_moving_face_and_beats_lk_pnp(sequence, true_model_factory, request):
    images, true_nodes, camera, population = request.getfixturevalue(sequence)
    model = true_model_factory(population)
    init = simulated_clicks(model.node_names, true_nodes[0], camera, 1.0, np.random.default_rng(3))
    mono = evaluate_tracker(MonoTracker(model, camera), model, images, true_nodes, init)
    baseline = evaluate_tracker(LKPnPTracker(model, camera), model, images, true_nodes, init)
    accuracy = mono.accuracy
    assert accuracy.lost == 0 and accuracy.tracked == len(images)
    assert max(accuracy.rotation_mae_deg) < 1.5
    assert max(accuracy.translation_mae_mm[:2]) < 2.0 and accuracy.translation_mae_mm[2] < 8.0
    assert accuracy.node_rms_mm < 5.0
    assert np.mean(accuracy.rotation_mae_deg) < 0.5 * np.mean(baseline.accuracy.rotation_mae_deg)


def test_19_node_model_tracks_too(free_sequence, true_model_factory):
    """Without face-edge nodes the first-frame fit is weaker (a 3 degree yaw error here)."""
    images, true_nodes, camera, population = free_sequence
    model = true_model_factory(population, num_nodes=19)
    nodes = true_nodes[:, :19]
    init = simulated_clicks(model.node_names, nodes[0], camera, 1.0, np.random.default_rng(4))
    result = evaluate_tracker(MonoTracker(model, camera), model, images[:12], nodes[:12], init)
    accuracy = result.accuracy
    assert accuracy.lost == 0 and accuracy.tracked == 12
    # Measured: 0.36 / 3.29 / 0.14 degrees, 0.13 / 0.43 mm laterally; frame 1's pose held
    # throughout would give 0.68 / 9.49 / 1.05 degrees, 5.3 / 3.0 mm.
    assert max(accuracy.rotation_mae_deg) < 4.0
    assert max(accuracy.translation_mae_mm[:2]) < 1.5


def test_occluded_face_is_lost_then_reacquired(free_sequence, true_model_factory):
    images, true_nodes, camera, population = free_sequence
    model = true_model_factory(population)
    init = simulated_clicks(model.node_names, true_nodes[0], camera)
    tracker = MonoTracker(model, camera)
    tracker.reset(init)
    for image in images[:4]:
        assert tracker.step(image).ok
    blank = np.full_like(images[0], 90)
    lost = [tracker.step(blank) for _ in range(3)]
    assert all(r.status == TrackStatus.LOST for r in lost)
    resumed = [tracker.step(image) for image in images[4:8]]
    assert resumed[-1].ok, resumed[-1].reason
    error_mm = 1000 * np.abs(resumed[-1].nodes_cam - true_nodes[7]).max()
    assert error_mm < 15.0


FAST = SceneConfig(kind='mono', frames=150, fps=10.0, seed=7, motion='free')


def _rendered(config: SceneConfig, start: int, stop: int):
    """Images start to stop - 1 of ``config`` (subject 0), true nodes, camera, population."""
    renderer = SequenceRenderer(config, 0)
    frames = list(itertools.islice(renderer.frames(0), start, stop))
    images = [f.images['image'] for f in frames]
    nodes = np.array([f.truth.nodes_camera for f in frames])
    return images, nodes, config.cameras()['image'], renderer.population


@pytest.fixture(scope='module')
def fast_sequence():
    """Images 0-34 of FAST, subject 0 (the head moves about 8 px a frame), and its camera."""
    return _rendered(FAST, 0, 35)


def _tracked(fast_sequence, model, images) -> tuple[list[TrackStatus], np.ndarray]:
    """Each image's status and node RMS px off the truth, tracked from 1-px clicks on image 0."""
    _, true_nodes, camera, _ = fast_sequence
    nodes = true_nodes[:, : model.num_nodes]
    init = simulated_clicks(model.node_names, nodes[0], camera, 1.0, np.random.default_rng(3))
    tracker = MonoTracker(model, camera)
    tracker.reset(init)
    results = [tracker.step(image) for image in images]
    errors = [
        np.sqrt(np.mean(np.sum((r.nodes_px - camera.project(n)) ** 2, axis=1)))
        for r, n in zip(results, nodes, strict=True)
    ]
    return [r.status for r in results], np.array(errors)


def _assert_followed_closely(sequence, true_model_factory) -> None:
    """Every image of ``sequence`` TRACKING within 1.5 px of the truth (the true model)."""
    images, *_, population = sequence
    statuses, errors = _tracked(sequence, true_model_factory(population), images)
    assert statuses == [TrackStatus.TRACKING] * len(images)
    assert errors.max() < 1.5, np.round(errors, 1)


def test_the_image_after_a_bundle_adjustment_is_solved_from_the_motion_prediction(
    fast_sequence, true_model_factory
):
    """The adjustment applied at image 27 carries the prediction's other point with it.

    Solved from image 27's adjusted estimate instead, with no motion, image 28 settled 7.9 px
    off with 19 of 34 nodes failing, LOST.
    """
    _assert_followed_closely(fast_sequence, true_model_factory)


def test_the_image_after_a_reacquisition_is_solved_from_the_motion_prediction(
    fast_sequence, true_model_factory
):
    """Image 28 blank (LOST), 29 re-acquired: 30 is predicted from the motion from 27 to 29.

    Solved from image 29's estimate instead, the solve settled 8.1 px off and passed, and the
    track stayed 8.1-9.1 px off, TRACKING, over images 30-34.
    """
    images, *_, population = fast_sequence
    blanked = [*images[:28], np.full_like(images[28], 128), *images[29:]]
    statuses, errors = _tracked(fast_sequence, true_model_factory(population), blanked)
    assert statuses[28] == TrackStatus.LOST
    assert statuses[29:] == [TrackStatus.TRACKING] * 6
    assert errors[29:].max() < 1.5, np.round(errors[29:], 1)


# Seed 13 at 5 fps: the head moves 14 px between images 85 and 86 (twice FAST's speed).
FASTER = SceneConfig(kind='mono', frames=150, fps=5.0, seed=13, motion='free')


def test_a_followed_solve_that_matches_loosely_is_made_again(true_model_factory):
    """Images 83-88 of FASTER tracked from 1-px clicks on image 83.

    Image 86's solve from the motion prediction (level 1, 5.4 px off) settled 4.3 px off with 30
    of 33 voting nodes above ``reacquire_residual_ratio`` (13 above ``lost_residual_ratio``:
    passed), and the track stayed there, 5.8-6.0 px off, TRACKING. Made again from the last
    estimate on level 1 it converges 0.7 px off with 1 of 31 failing, and is taken.
    """
    _assert_followed_closely(_rendered(FASTER, 83, 89), true_model_factory)


# Seed 12 at 5 fps: the head moves 20 px between images 0 and 1.
FAST_START = SceneConfig(kind='mono', frames=150, fps=5.0, seed=12, motion='free')


def test_a_track_whose_second_image_moved_far_finds_the_face_there(true_model_factory):
    """Images 0-5 of FAST_START tracked from 1-px clicks on image 0.

    Image 1 has no motion prediction: solved from image 0's estimate, and made again from there
    on the coarsest level, it settled 7.1 px off with the expression wrong and 7 nodes taken as
    covered (no occluder), and the track stayed 6-7 px off, TRACKING. Solved from where image
    0's inner face correlates best (3.1 px off) it converges 0.6 px off, and is taken.
    """
    _assert_followed_closely(_rendered(FAST_START, 0, 6), true_model_factory)


# Seed 4 at 5 fps: at image 14 the head moves 13 px and the motion prediction is 11 px off.
FAST_TURN = SceneConfig(kind='mono', frames=150, fps=5.0, seed=4, motion='free')


def test_a_doubtful_solve_not_mended_by_its_retries_is_solved_from_where_the_face_is(
    true_model_factory,
):
    """Images 0-15 of FAST_TURN tracked from 1-px clicks on image 0.

    Image 14's solve from the motion prediction settled 6.3-6.8 px off with 8 nodes taken as
    covered (no occluder), and the retry from the last estimate 6.6 px off with 9: the first
    stood, and images 14-15 were TRACKING 6.8 px off. Solved from where image 13's inner face
    correlates best (5.2 px off) it converges 0.7 px off, none covered, and is taken.
    """
    _assert_followed_closely(_rendered(FAST_TURN, 0, 16), true_model_factory)


# Seed 14 at 5 fps: at image 8 the head moves 8 px and the motion prediction is 8 px off.
FAST_MISS = SceneConfig(kind='mono', frames=150, fps=5.0, seed=14, motion='free')


def test_a_failed_followed_solve_is_solved_from_where_the_face_is(true_model_factory):
    """Images 0-9 of FAST_MISS tracked from 1-px clicks on image 0.

    Image 8's solve from the motion prediction (8.0 px off) failed with 22 of 32 textured nodes
    not matching, as did the re-acquisition from frame 1's face: LOST, found again at image 9.
    Solved from where image 7's inner face correlates best (1.4 px off) it converges 0.8 px
    off, and solving image 7 back from it returns within 0.1 px of image 7's estimate: taken.
    """
    _assert_followed_closely(_rendered(FAST_MISS, 0, 10), true_model_factory)


# Seed 36 at 10 fps: by image 19 the views are turned 16-45 degrees from frame 1.
TURNED_VIEWS = SceneConfig(kind='mono', frames=150, fps=10.0, seed=36, motion='free')


def test_an_adjustment_leaving_the_nodes_off_the_skin_is_not_applied(true_model_factory):
    """Images 0-25 of TURNED_VIEWS tracked from 1-px clicks on image 0: TRACKING within 3 px.

    The adjustment made after image 19 set frame 1's nodes a common 4.2 mm before the skin its
    views measured, which no view's photometric term sees: 2.98 px in the newest view. Applied,
    image 19 went from 2.0 to 4.7 px off the true nodes and images 20-25 were 3.9-4.6 px off,
    TRACKING. Refused, they are at most 2.1 px off.
    """
    images, *_, population = sequence = _rendered(TURNED_VIEWS, 0, 26)
    statuses, errors = _tracked(sequence, true_model_factory(population), images)
    assert statuses == [TrackStatus.TRACKING] * len(images)
    assert errors.max() < 3.0, np.round(errors, 1)
