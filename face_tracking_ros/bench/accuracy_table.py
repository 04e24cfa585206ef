"""The accuracy table on the synthetic world: mono, stereo, baseline, learning, recognition.

- Trackers: one rendered 640x480 stereo sequence of the unseen test subject moving freely; the
  mono tracker and the LK+PnP baseline run on its left images, the stereo tracker on the pairs,
  all from the same simulated clicks and the same learned 34-node model. Mono (its published,
  smoothed pose) and baseline are scored by :func:`tracking_accuracy` (pose against the model
  fitted to the true nodes, node RMS, alpha, drift, jitter), stereo by :func:`evaluate_stereo`
  (node RMS, reprojection, drift) twice: as the live node streams it (``stereo``) and as
  ``face-tracking learn`` tracks raw stereo bags, with the depths refined over the sequence
  applied to every pair (``stereo_offline``, ``retroactive_depths``); and that second way again
  on the same sequence rendered with real skin, the packaged face photo as the subject's
  texture (``stereo_photo``; :func:`~face_tracking_ros.data.photo_face_paths`). Mono again on
  the same scene rendered with an occluder (a hand, a mug) passing once in front of the face
  for 1.5 s (``mono_occlusion``): the same head, expressions, light and clicks, the backdrop
  drawn anew.
- Learning: the benchmark model's §3.4 learner against the population's true subspaces
  (:func:`evaluate`: LOO stability, truth similarity, identity / expression from sigma / alpha).
- Recognition: the issue 7 scenario of :func:`run_benchmark` with this model (identity windows,
  expressions of held-out subjects, events).
"""

from __future__ import annotations

from dataclasses import asdict, replace
from typing import Any

import numpy as np

from face_tracking_ros.bench.common import BenchOptions
from face_tracking_ros.bench.world import (
    RenderedSequence,
    learned_model,
    render_sequence,
    scene_config,
    training_set,
)
from face_tracking_ros.data import photo_face_paths
from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.evaluation import evaluate, population_truth
from face_tracking_ros.learning.seed import learn_seed
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.recognition.benchmark import BenchmarkConfig, run_benchmark
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.scenes import Kind
from face_tracking_ros.tracking.accuracy import tracking_accuracy
from face_tracking_ros.tracking.baseline import LKPnPTracker
from face_tracking_ros.tracking.initialisation import Initialisation
from face_tracking_ros.tracking.mono import MonoTracker
from face_tracking_ros.tracking.pose_filter import FilteredTracker, PoseFilter
from face_tracking_ros.tracking.result import TrackResult
from face_tracking_ros.tracking.stereo import StereoTracker
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig
from face_tracking_ros.tracking.stereo_evaluation import evaluate_stereo

WIDTH, HEIGHT = 640, 480
NUM_NODES = 34
FRAMES, QUICK_FRAMES = 150, 8
LEARNING_SUBJECTS, LEARNING_FRAMES = 11, 200
RECOGNITION = BenchmarkConfig(subjects=11, strangers=11, duration=20.0)
QUICK_RECOGNITION = BenchmarkConfig(subjects=3, strangers=2, training_sequences=1, duration=6.0)


def run(options: BenchOptions) -> dict[str, Any]:
    """Every row of the accuracy table.

    Returns:
        ``{'mono': {...}, 'baseline': {...}, 'stereo': {...}, 'mono_occlusion': {...},
        'learning': {...}, 'recognition': {...}}`` (and the other stereo rows); lengths in mm,
        angles in degrees, shares in [0, 1].
    """
    model = learned_model(NUM_NODES, options.seed).model
    frames = QUICK_FRAMES if options.quick else FRAMES
    scene = scene_config(Kind.STEREO, WIDTH, HEIGHT, frames, options.seed)
    sequence = render_sequence(scene)
    truth = sequence.true_nodes(NUM_NODES)
    init = sequence.initialisation(model.node_names, options.seed)
    left = sequence.images('left')
    table: dict[str, Any] = {
        'scene': f'{WIDTH}x{HEIGHT} stereo, {frames} frames at {scene.fps:g} fps, '
        'free head motion',
        'mono': _mono(sequence, model, init),
    }
    baseline = LKPnPTracker(model, sequence.reference)
    baseline.reset(init)
    table['baseline'] = _scored(model, [baseline.step(image) for image in left], truth)
    table['stereo'] = _stereo(sequence, model, init, offline=False)
    table['stereo_offline'] = _stereo(sequence, model, init, offline=True)
    photo, photo_nodes = photo_face_paths()
    photo_scene = replace(scene, texture=photo, texture_nodes=photo_nodes)
    table['stereo_photo'] = _stereo(render_sequence(photo_scene), model, init, offline=True)
    occluded = render_sequence(replace(scene, occlusion=True))
    table['mono_occlusion'] = _mono(occluded, model, init)
    table['learning'] = _learning(options.seed)
    table['recognition'] = _recognition(
        model, QUICK_RECOGNITION if options.quick else RECOGNITION, options.seed
    )
    return table


def _mono(sequence: RenderedSequence, model: FaceModel, init: Initialisation) -> dict[str, Any]:
    """The mono tracker's published (smoothed) figures on a sequence's left images."""
    camera = sequence.reference
    mono = FilteredTracker(MonoTracker(model, camera), PoseFilter(camera), sequence.config.fps)
    mono.reset(init)
    left = sequence.images('left')
    return _scored(model, [mono.step(image) for image in left], sequence.true_nodes(NUM_NODES))


def _stereo(
    sequence: RenderedSequence, model: FaceModel, init: Initialisation, offline: bool
) -> dict[str, Any]:
    """Stereo figures of a sequence, streamed as the node or (offline) as learn tracks it."""
    config = StereoTrackerConfig(num_nodes=NUM_NODES, refine_depths=offline)
    stereo = StereoTracker(sequence.rig(), config, model)
    stereo.reset(init)
    left, right = sequence.images('left'), sequence.images('right')
    results = [stereo.step(a, b) for a, b in zip(left, right, strict=True)]
    if offline:
        results = stereo.with_final_depths(results)
    figures = evaluate_stereo(
        np.stack([r.nodes_cam for r in results]),
        sequence.true_nodes(NUM_NODES),
        sequence.rig(),
        model.topology,
        np.array([r.status for r in results]),
    )
    return figures.in_mm()


def _scored(model: FaceModel, results: list[TrackResult], truth: np.ndarray) -> dict[str, Any]:
    """Tracking accuracy of a mono-like tracker's results against the true nodes."""
    accuracy = tracking_accuracy(
        model,
        np.array([r.status for r in results]),
        np.stack([r.omega for r in results]),
        np.stack([r.t for r in results]),
        np.stack([r.alpha for r in results]),
        np.stack([r.nodes_cam for r in results]),
        truth,
    )
    return accuracy.as_dict()


def _learning(seed: int) -> dict[str, Any]:
    """The §3.4 learner's figures on the benchmark training set against the truth."""
    population = FacePopulation(seed=seed)
    training = align_training_set(
        training_set(
            population, NUM_NODES, LEARNING_SUBJECTS, LEARNING_FRAMES, np.random.default_rng(seed)
        )
    )
    truth = population_truth(population, NUM_NODES, range(1, LEARNING_SUBJECTS + 1))
    evaluation, _, _ = evaluate(training, learn_seed, truth=truth)
    return evaluation.as_dict()


def _recognition(model: FaceModel, config: BenchmarkConfig, seed: int) -> dict[str, Any]:
    """Identity, expression and event figures of the issue 7 scenario with this model."""
    config = BenchmarkConfig(**{**asdict(config), 'seed': seed})
    report = run_benchmark(model, config)
    return {
        'identity_closed_set': report.identity.closed_set,
        'identity_open_set': report.identity.open_set,
        'stranger_rejection': report.identity.rejection,
        'identity_windows': report.identity.windows,
        'expression_clear_frames': report.expression.clear,
        'expression_balanced': report.expression.balanced,
        'event_f1': report.events_from_label_start.f1,
        'event_precision': report.events_from_label_start.precision,
        'event_recall': report.events_from_label_start.recall,
    }
