"""Faults on rendered sequences: the mono tracker says LOST and recovers within 1 s by itself.

Scenes are 320x240 at 15 fps (see :mod:`fault_scenes`): a face that leaves the image and comes
back, a full occlusion of 3 s, an abrupt change of light, five dropped frames while the head
turns. The tracker is initialised once, on the first frame, and never reset.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from fault_scenes import CAMERA, FPS, FaultScene
import numpy as np
import pytest

from face_tracking_ros.synthetic.render import Lighting, Occluder
from face_tracking_ros.tracking.mono import MonoTracker
from face_tracking_ros.tracking.result import TrackStatus

RECOVERY_FRAMES = round(1.0 * FPS)  # 1 s
GOOD_PX = 3.0  # RMS node projection error of a correct estimate, px
AFTER_GAP_PX = 4.0  # the same after an unannounced gap of five frames in a fast turn, px


@dataclass(frozen=True)
class Run:
    """Per-frame status, RMS node projection error (px) and covered nodes of a tracked sequence."""

    status: np.ndarray
    error_px: np.ndarray
    occluded: np.ndarray  # (F, N) bool, the results' nodes judged covered by an occluder

    def good(self) -> np.ndarray:
        """Frames tracked correctly: TRACKING and within GOOD_PX of the truth."""
        return (self.status == TrackStatus.TRACKING) & (self.error_px < GOOD_PX)

    def recovery_frames(self, visible_from: int) -> int:
        """Frames from ``visible_from`` to the first frame after which every frame is good."""
        bad = np.flatnonzero(~self.good()[visible_from:])
        return 0 if not bad.size else int(bad[-1]) + 1


@pytest.fixture(scope='module')
def scene() -> FaultScene:
    return FaultScene()


def _track(scene: FaultScene, specs: Sequence[dict]) -> Run:
    """Render each frame spec (keyword arguments of FaultScene.render) and track it."""
    frames = [scene.render(noise_seed=n, **spec) for n, spec in enumerate(specs)]
    tracker = MonoTracker(scene.model, CAMERA)
    tracker.reset(scene.initialisation(frames[0]))
    status, error, occluded = [], [], []
    for frame in frames:
        result = tracker.step(frame.image)
        status.append(result.status)
        offsets = result.nodes_px - CAMERA.project(frame.nodes)
        error.append(np.sqrt(np.mean(np.sum(offsets**2, axis=1))))
        occluded.append(result.occluded)
    return Run(np.array(status), np.nan_to_num(np.array(error), nan=np.inf), np.array(occluded))


def _inside(scene: FaultScene, x: float) -> float:
    """Fraction of the face's nodes inside the image at lateral offset x (m)."""
    pixels = CAMERA.project(scene.render(x=x).nodes)
    inside = (pixels >= 0).all(axis=1) & (pixels <= [CAMERA.width - 1, CAMERA.height - 1]).all(1)
    return float(inside.mean())


def test_a_face_leaving_the_image_is_lost_and_reacquired_within_1_s(scene):
    # 2 s out to 0.5 m to the right (8 px per frame), 0.7 s away, 2 s back, 1 s still.
    out = np.linspace(0.0, 0.5, 31)
    xs = np.concatenate([np.zeros(5), out[1:], np.full(10, 0.5), out[::-1][1:], np.zeros(15)])
    inside = np.array([_inside(scene, x) for x in xs])
    run = _track(scene, [{'x': x} for x in xs])
    gone = inside < 0.5
    visible_again = int(np.flatnonzero(inside < 1.0)[-1]) + 1
    assert run.good()[:10].all()
    assert run.recovery_frames(visible_again) <= RECOVERY_FRAMES
    falsely_tracking = int(np.sum(run.status[gone] == TrackStatus.TRACKING))
    assert falsely_tracking == 0, f'TRACKING in {falsely_tracking} of {gone.sum()} frames'


def test_a_face_hidden_for_3_s_is_lost_and_reacquired_within_1_s(scene):
    hand = Occluder((160.0, 120.0), (110.0, 120.0), 0.0, (60.0, 70.0, 110.0), texture_seed=3)
    hidden = round(3 * FPS)
    run = _track(scene, [{}] * 8 + [{'occluders': (hand,)}] * hidden + [{}] * 20)
    assert run.good()[:8].all()
    assert run.recovery_frames(8 + hidden) <= RECOVERY_FRAMES
    # Allow 0.2 s to notice the occlusion; from then on LOST until the hand has gone.
    noticed = 8 + round(0.2 * FPS)
    falsely_tracking = int(np.sum(run.status[noticed : 8 + hidden] == TrackStatus.TRACKING))
    assert falsely_tracking == 0, f'TRACKING in {falsely_tracking} of {hidden} hidden frames'


def test_a_hand_over_part_of_the_face_is_tracked_through(scene):
    # A hand comes in from the left over the right eye, brow and cheek (up to 10 of the 34 nodes'
    # centres) in 10 frames, stays 10 and leaves in 9, while the head turns to and fro.
    def hand(n: int) -> tuple[Occluder, ...]:
        if not 10 <= n < 39:
            return ()
        x = float(np.interp(n, [10, 20, 30, 39], [90.0, 135.0, 135.0, 90.0]))
        return (Occluder((x, 125.0), (20.0, 30.0), 10.0, (150.0, 110.0, 90.0), texture_seed=4),)

    run = _track(scene, [{'yaw': 0.3 * np.sin(n / 12), 'occluders': hand(n)} for n in range(50)])
    # Main (the covered nodes solved with the others) stayed TRACKING 7-8 px off while the hand
    # lay over the face, and 11-14 px off after it had gone.
    assert (run.status == TrackStatus.TRACKING).all()
    assert run.error_px.max() < 4.0
    assert run.error_px[-10:].max() < 1.5
    # The results say which nodes are taken as covered (FaceState.occluded): none before the
    # hand, up to 11 under it (measured from frame 17 on), and none once it has gone (frame 39;
    # measured: the last released at frame 38, as the hand left its centre). Before covered
    # nodes kept the nearest keyframe's templates, and a face-edge node stayed covered only
    # next to a covered inner node, six stayed covered to frame 46 and one to the end: their
    # templates were sampled while the hand came over them, before they were taken as covered.
    covering = run.occluded.sum(axis=1)
    assert not covering[:10].any() and covering[20:30].min() >= 8  # measured 11
    assert not covering[39:].any()


def test_an_abrupt_change_of_light_is_tracked_through(scene):
    left = Lighting(direction=np.array([-0.6, -0.3, -0.74]))
    right = Lighting(direction=np.array([0.6, -0.3, -0.74]), ambient=0.2, diffuse=1.0)
    specs = [{'lighting': left if n < 10 else right, 'yaw': 0.01 * n} for n in range(30)]
    run = _track(scene, specs)
    assert run.good()[:10].all()
    assert run.recovery_frames(10) <= RECOVERY_FRAMES
    assert run.error_px[-1] < 2.5


def test_dropped_frames_while_turning_are_tracked_through(scene):
    # 0.6 rad/s yaw; frames 10-14 never arrive, and the tracker is not told: one step turns
    # 0.24 rad. The image after the gap lands 2.5-3.7 px off over 24 noise seeds, because its
    # level 0 stops at max_iterations still moving (with this test's seeds 2.9 px before the
    # motion prediction was carried through the bundle adjustment, 3.5 px since). So it and the
    # next few are allowed AFTER_GAP_PX, and the track must be within GOOD_PX again within
    # RECOVERY_FRAMES (docs/performance.md, 2026-12-07: the mono motion prediction through a
    # bundle adjustment).
    run = _track(scene, [{'yaw': 0.04 * n} for n in range(30) if not 10 <= n < 15])
    assert run.good()[:10].all()
    assert (run.status == TrackStatus.TRACKING).all()
    assert run.recovery_frames(10) <= RECOVERY_FRAMES
    assert run.error_px.max() < AFTER_GAP_PX
