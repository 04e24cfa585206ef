"""Per-frame compute of the mono and stereo trackers and of the LK+PnP baseline (issue 9).

For each image size and mesh size, a stereo sequence of the test subject is rendered first; the
mono tracker and the baseline run on its left images, the stereo tracker on the pairs, each
initialised from the same simulated clicks. Only ``step()`` is timed (``time.perf_counter``),
the initialising first frame excluded. Targets (one core): mono <= 2 ms and stereo <= 5 ms per
frame at 640x480. Also timed per size: the rectification the tracker nodes add for a raw image
(:mod:`~face_tracking_ros.imaging.rectification`) of a camera with lens distortion and a
rectification rotation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from face_tracking_ros.bench.common import BenchOptions, time_calls, timing_summary
from face_tracking_ros.bench.world import (
    RenderedSequence,
    learned_model,
    render_sequence,
    scene_config,
)
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging.rectification import Rectifier
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.synthetic.scenes import Kind
from face_tracking_ros.tracking.baseline import LKPnPTracker
from face_tracking_ros.tracking.mono import MonoTracker
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.tracking.stereo import StereoTracker
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig

SIZES = ((320, 240), (640, 480), (1280, 720))
QUICK_SIZES = ((320, 240),)
NODE_COUNTS = (19, 34)
RAW_DISTORTION = np.array([-0.28, 0.09, 0.001, -0.001, 0.0])  # plumb_bob k1 k2 p1 p2 k3
FRAMES, QUICK_FRAMES = 100, 5  # 40 left the median to a few frames and p99 to the slowest


def run(options: BenchOptions) -> dict[str, Any]:
    """Median and p99 step time of every tracker at every size; the baseline ratio.

    Returns:
        ``{'<W>x<H>': {'<N>_nodes': {'mono': {...}, 'stereo': {...}, 'baseline': {...},
        'mono_over_baseline': ratio, 'stereo_over_baseline': ratio}}}`` (times in ms;
        ``tracked`` is the share of frames with status TRACKING; the ratios are of medians).
    """
    sizes = QUICK_SIZES if options.quick else SIZES
    frames = QUICK_FRAMES if options.quick else FRAMES
    models = {n: learned_model(n, options.seed).model for n in NODE_COUNTS}
    results: dict[str, Any] = {}
    for width, height in sizes:
        config = scene_config(Kind.STEREO, width, height, frames + 1, options.seed)
        sequence = render_sequence(config)
        results[f'{width}x{height}'] = {
            f'{n}_nodes': _one_size(sequence, models[n], options.seed) for n in NODE_COUNTS
        }
        results[f'{width}x{height}']['rectification'] = _rectification(sequence)
    return results


def _rectification(sequence: RenderedSequence) -> dict[str, Any]:
    """Time rectifying the sequence's left images as the raw images of a real camera's.

    plumb_bob distortion as of a wide lens and a rectification rotation of 3 degrees (the
    rectifier's work does not depend on the image content).
    """
    turn = rodrigues(np.radians([0.0, 3.0, 0.0]))[0]
    camera = replace(sequence.rig().left, d=RAW_DISTORTION, r=turn)
    rectifier = Rectifier(camera)
    left = sequence.images('left')
    return timing_summary(
        time_calls([lambda image=image: rectifier.image(image) for image in left])
    )


def _one_size(sequence: RenderedSequence, model: FaceModel, seed: int) -> dict[str, Any]:
    """The three trackers on one rendered sequence with one model."""
    init = sequence.initialisation(model.node_names, seed)
    left, right = sequence.images('left'), sequence.images('right')
    mono = MonoTracker(model, sequence.reference)
    mono.reset(init)
    stereo = StereoTracker(sequence.rig(), StereoTrackerConfig(num_nodes=model.num_nodes), model)
    stereo.reset(init)
    figures: dict[str, Any] = {
        'mono': _timed(lambda f: mono.step(left[f]).status, len(left)),
        'stereo': _timed(lambda f: stereo.step(left[f], right[f]).status, len(left)),
    }
    baseline = LKPnPTracker(model, sequence.reference)
    baseline.reset(init)
    figures['baseline'] = _timed(lambda f: baseline.step(left[f]).status, len(left))
    for tracker in ('mono', 'stereo'):
        ratio = figures[tracker]['median_ms'] / figures['baseline']['median_ms']
        figures[f'{tracker}_over_baseline'] = ratio
    return figures


def _timed(step: Callable[[int], TrackStatus], frames: int) -> dict[str, Any]:
    """Run ``step(0)`` (initialisation, untimed), then time ``step(f)`` for the other frames."""
    step(0)
    statuses: list[TrackStatus] = []
    durations = time_calls([lambda f=f: statuses.append(step(f)) for f in range(1, frames)])
    summary: dict[str, Any] = timing_summary(durations)
    summary['tracked'] = float(np.mean([s == TrackStatus.TRACKING for s in statuses]))
    return summary
