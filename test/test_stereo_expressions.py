"""The expression recogniser on a rendered face tracked by the stereo tracker, its head turning.

Seed 1's subject 0 moving freely (yaw 18 -> 28 -> -20 -> 30 degrees) at 640x480, 30 fps,
tracked by the stereo tracker with the packaged model from 1-px clicks, as the stereo_tracker
node streams it; the face opens its jaw from 2.5 s to 7.1 s. Each pair's ``face/state`` and
``face/action`` go to the expression recogniser in the order the tracker publishes them. And
seed 6's, smiling from 4.5 s while an occluder passes in front of its mouth (4.0 s to 5.5 s),
and seed 4's, puckering then; seed 3's, frowning through the pass of an occluder that hides
nearly all its face.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from tracked_expressions import one_expression, recognised_outputs, scripted_frames

from face_tracking_ros.bench.world import scene_config
from face_tracking_ros.data import default_model_path
from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.model.topology import Group
from face_tracking_ros.synthetic.clicks import simulated_clicks
from face_tracking_ros.synthetic.motion import ExpressionScript, ExpressionSegment
from face_tracking_ros.synthetic.scenes import Kind, SequenceRenderer, SyntheticFrame
from face_tracking_ros.tracking.result import TrackResult, TrackStatus
from face_tracking_ros.tracking.stereo import StereoTracker
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig

FRAMES = 300
JAW_OPEN = ExpressionSegment('jaw_open', 2.5, 0.3, 4.0, 0.3, 0.9)
SMILE = ExpressionSegment('smile', 4.5, 0.3, 2.0, 0.3, 0.9)
PUCKER = replace(SMILE, label='pucker')
FROWN = replace(JAW_OPEN, label='frown')
OCCLUDER_PASS = (4.0, 1.5)  # s: start, duration
SMILE_FRAMES = 225  # to 7.5 s, the smile gone at 7.1 s


def tracks(
    seed: int, frames: int, segment: ExpressionSegment, occluder: tuple[float, float] | None
) -> tuple[list, np.ndarray, list]:
    """The rendered pairs, each pair's node errors (px, left image) and its state and action.

    The first ``frames`` of seed ``seed``'s 300-pair sequence at 640x480 with ``segment`` alone
    (and ``occluder``'s pass), tracked with the packaged model from 1-px clicks.
    """
    config = replace(
        scene_config(Kind.STEREO, 640, 480, FRAMES, seed), occlusion=occluder is not None
    )
    renderer = SequenceRenderer(config, 0)
    pairs = scripted_frames(renderer, frames, ExpressionScript((segment,)), occluder)
    model = load_model(default_model_path())
    rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
    tracker = StereoTracker(rig, StereoTrackerConfig(num_nodes=model.num_nodes), model)
    clicks = np.random.default_rng(seed)
    tracker.reset(
        simulated_clicks(model.node_names, pairs[0].truth.nodes_camera, rig.left, 1.0, clicks)
    )
    errors = []

    def step(frame: SyntheticFrame) -> TrackResult:
        result = tracker.step(frame.images['left'], frame.images['right']).as_track_result()
        truth = rig.left.project(frame.truth.nodes_camera[: model.num_nodes])
        errors.append(np.linalg.norm(result.nodes_px - truth, axis=1))
        return result

    outputs = recognised_outputs(pairs, step, 'left', model)
    return pairs, np.array(errors), outputs


@pytest.fixture(scope='module')
def tracked() -> tuple[list, list]:
    """Seed 1's rendered pairs and, per pair, the tracker's state and action (if tracked)."""
    frames, _, outputs = tracks(1, FRAMES, JAW_OPEN, None)
    return frames, outputs


def test_a_held_expression_of_a_turning_head_is_one_event(tracked) -> None:
    frames, outputs = tracked
    status = np.array([image[0].msg.status for image in outputs])
    assert np.all(status == TrackStatus.TRACKING)
    yaw = np.degrees([frame.truth.omega[1] for frame in frames])
    assert yaw.max() > 28.0 and yaw.min() < -19.0  # the head turns both ways
    # Measured: the jaw_open's onset at frame 82 and offset at 214 (the truth rises from frame
    # 75 and has fallen at 213). Before the fit's prior on alpha (fit_node_noise) a frown
    # followed at frames 220-246, the head turned 30 degrees: nodes a few mm off, most of it in
    # depth, read on alpha's smallest mode (the frown's), which the classifier weighs most.
    events = one_expression(frames, outputs, JAW_OPEN)
    start = frames[0].stamp_ns / 1e9
    assert abs(events[1].stamp - (start + JAW_OPEN.end)) < 0.2


def after_the_pass(seed: int, segment: ExpressionSegment) -> tuple[list, np.ndarray, list]:
    """Seed ``seed``'s pairs with ``segment`` starting under the occluder, all tracked.

    Returns the pairs, the node errors (px) from the end of the pass to the segment's fall, and
    each pair's state and action.
    """
    frames, errors, outputs = tracks(seed, SMILE_FRAMES, segment, OCCLUDER_PASS)
    status = np.array([image[0].msg.status for image in outputs])
    assert np.all(status == TrackStatus.TRACKING)
    seconds = np.array([frame.stamp_ns - frames[0].stamp_ns for frame in frames]) / 1e9
    after = (seconds > sum(OCCLUDER_PASS)) & (seconds < segment.end - segment.fall)
    return frames, errors[after], outputs


def test_mouth_nodes_held_while_a_smile_starts_under_an_occluder_are_found_again() -> None:
    """Mouth nodes held while a smile starts under an occluder are found when it has gone.

    The mouth corners move 10-12 px while the occluder covers them. Measured, from the end of
    the pass to the smile's fall: the mouth nodes at most 4.5 px off, and the smile read from
    frame 157 (the nodes found again on frame 155). With the held nodes' face texture kept but
    nothing found again, 8.7 px and the smile from frame 181; with the texture sampled afresh
    on every pair (the occluder, then the face at the held mesh), 15.9 px and no smile read.
    """
    frames, errors, outputs = after_the_pass(6, SMILE)
    mouth = load_model(default_model_path()).topology.group_mask(Group.MOUTH)
    assert errors[:, mouth].max() < 6.0
    one_expression(frames, outputs, SMILE)


def test_nodes_still_flagged_as_the_occluder_leaves_are_found_again() -> None:
    """A pucker started under the occluder: the nodes found again while a few are still flagged.

    Seed 4's occluder covers up to 23 nodes as it passes. Measured, with the region found again
    on the first pair with none flagged: its far brow end, eye corner and temple stayed flagged
    28 pairs after it, off the face, the far cheek drifting; the region grew to all 34 nodes,
    whose solve failed (residual 0.74 of the contrast): from the end of the pass to the pucker's
    fall nodes up to 25.6 px off, a smile read and not ended. Found again as the occluder leaves
    (no node newly flagged, fewer than on the last pair; frame 154, 4 nodes still flagged, none
    after): at most 5.5 px, the pucker read from 5.2 s to 7.07 s.
    """
    frames, errors, outputs = after_the_pass(4, PUCKER)
    assert errors.max() < 7.0
    one_expression(frames, outputs, PUCKER)


@pytest.fixture(scope='module')
def hidden() -> tuple[list, np.ndarray, list]:
    """Seed 3's pairs frowning through the occluder's pass, their node errors and outputs."""
    return tracks(3, SMILE_FRAMES, FROWN, OCCLUDER_PASS)


def test_a_frown_held_while_an_occluder_hides_the_face_is_one_event(hidden) -> None:
    """A frown held while the occluder passes over all but a few nodes is not ended there.

    Seed 3's occluder covers 20-29 of the 34 nodes on pairs 136-145, up to 27 of them too
    many for the rest to hold. Measured: LOST on pairs 140-148 with the last tracked pair's
    26 flagged nodes, one frown from frame 84 to 210. Before, pair 140 was tracked with no node
    held (its templates sampled over the occluder), pair 141 lost with no flag, and the frown
    ended there and started again at 158.
    """
    frames, _, outputs = hidden
    states = [image[0].msg for image in outputs]
    lost = [state for state in states if state.status == TrackStatus.LOST]
    mouth = load_model(default_model_path()).topology.group_mask(Group.MOUTH)
    assert lost
    assert all(np.count_nonzero(np.asarray(state.occluded) & mouth) >= 2 for state in lost)
    one_expression(frames, outputs, FROWN)


def test_a_face_lost_while_an_occluder_hid_it_is_found_again_where_it_was(hidden) -> None:
    """A track lost under the occluder is found again from its last nodes as it leaves.

    Measured: LOST on pairs 140-148, then within 2.5 px RMS. Before, the search (which followed
    the occluder in the last tracked image, 18-140 px off) and frame 1's start failed to pair
    154: LOST on pairs 140-154, found again 7.4 px off.
    """
    _, errors, outputs = hidden
    status = np.array([image[0].msg.status for image in outputs])
    lost = np.flatnonzero(status == TrackStatus.LOST)
    assert 0 < len(lost) <= 10
    rms = np.sqrt(np.mean(errors**2, axis=1))
    assert rms[lost[-1] + 1 :].max() < 3.0
