"""The expression recogniser on a rendered face that holds an expression while an occluder passes.

Seed 1's subject 0 moving freely at 640x480, 30 fps, tracked by the mono tracker with the packaged
model from 1-px clicks; the face opens its jaw from 0.8 s to 4.6 s and the seed's occluder (a
hand or a mug 15 cm in front of the face) crosses it from 2.0 to 3.5 s. Each image's
``face/state`` and ``face/action`` go to the expression recogniser in the order the tracker
publishes them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from tracked_expressions import one_expression, recognised_outputs, scripted_frames

from face_tracking_ros.data import default_model_path
from face_tracking_ros.io import conversions
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.synthetic.clicks import simulated_clicks
from face_tracking_ros.synthetic.motion import ExpressionScript, ExpressionSegment
from face_tracking_ros.synthetic.scenes import SceneConfig, SequenceRenderer
from face_tracking_ros.tracking.mono import MonoTracker
from face_tracking_ros.tracking.result import TrackStatus

FRAMES = 150
JAW_OPEN = ExpressionSegment('jaw_open', 0.8, 0.3, 3.2, 0.3, 0.9)


@pytest.fixture(scope='module')
def tracked() -> tuple[list, list]:
    """The rendered frames and, per frame, the tracker's state and action (if tracked)."""
    config = SceneConfig(kind='mono', frames=FRAMES, fps=30.0, seed=1, motion='free')
    renderer = SequenceRenderer(replace(config, occlusion=True), 0)
    frames = scripted_frames(renderer, FRAMES, ExpressionScript((JAW_OPEN,)), (2.0, 1.5))
    model = load_model(default_model_path())
    camera = renderer.cameras['image']
    clicks = np.random.default_rng(1)
    tracker = MonoTracker(model, camera)
    tracker.reset(
        simulated_clicks(model.node_names, frames[0].truth.nodes_camera, camera, 1.0, clicks)
    )
    outputs = recognised_outputs(
        frames, lambda frame: tracker.step(frame.images['image']), 'camera', model
    )
    return frames, outputs


def test_an_expression_held_while_an_occluder_passes_is_one_event(tracked) -> None:
    frames, outputs = tracked
    states = [image[0].msg for image in outputs]
    status = np.array([state.status for state in states])
    covered = np.array([conversions.occluded_nodes(state).any() for state in states])
    # The occluder covers mouth nodes, then the face is lost behind it for a few images.
    assert covered.sum() >= 10, covered.sum()
    assert (status == TrackStatus.LOST).any(), status
    # Measured: mouth nodes flagged from frame 76, LOST at frames 81-92. With occlusion_hold 0
    # (as before) the jaw_open ended at frame 81 and started again at frame 95, an onset with no
    # new expression behind it; held, it ends at frame 137 (the truth's end: 138).
    events = one_expression(frames, outputs, JAW_OPEN)
    start = frames[0].stamp_ns / 1e9
    assert events[1].stamp > start + JAW_OPEN.start + JAW_OPEN.rise + JAW_OPEN.hold
