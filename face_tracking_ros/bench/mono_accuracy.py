"""The monocular tracker's accuracy by issue 6's protocol, with its baseline and ablations.

Each of three seeds gives a population and a 1000-frame 640x480 sequence at 30 fps of its
held-out subject 0 moving freely (±35° yaw, ±25° pitch, ±20° roll, expressions), initialised
from simulated clicks on the first frame (1 px noise). On the same frames run:

- ``true_model``: the tracker with the population's own model (what a perfect learner gives), so
  its figures are the tracker's own error; its pose is the published one, smoothed by the One Euro
  filter of :mod:`~face_tracking_ros.tracking.pose_filter` (the node's default), as in every row
  of the eq. 6 tracker;
- ``unfiltered``: the same tracker's raw pose (``smoothing.enabled`` false), from the same run:
  the filter smooths only the output, so one run gives both rows;
- ``learned_model``: the tracker with the benchmark's learned model (§3.4 on subjects 1-11);
- ``baseline``: per-node pyramidal Lucas-Kanade plus ``solvePnP`` on the same true model;
- ablations with the true model: ``epsilon_0`` (no drift term), ``prior_off`` (no §4.1 alpha
  prior), ``bundle_off`` (frame 1's pose and sigma from the clicks alone and the ROIs on the
  thin-plate surface: no bundle adjustment of the first views,
  :mod:`face_tracking_ros.tracking.bundle`) and ``nodes_19`` (the seed's 19-node mesh);
- ``true_model_click_draws``: ``true_model`` averaged over :data:`CLICK_DRAWS` draws of the
  click noise (the first is ``true_model``'s): the first frame's pose, fitted to 34 clicks,
  errs by about as much as the tracker does afterwards, so one draw per seed is a noisy figure;
- ``photo_texture`` and ``photo_baseline``: the default tracker (true model) and the baseline on
  the same sequence rendered with real skin, the packaged face photo
  (:func:`~face_tracking_ros.data.photo_face_paths`) as the subject's texture instead of the
  procedural one: same head, motion, expressions and light;
- ``motion_blur``: the default tracker (true model) on the same sequence rendered with motion
  blur, each frame the mean of the face over an exposure of half the frame period (1/60 s at
  30 fps) about its instant, as a camera records fast head motion;
- ``jpeg_quality_95`` and ``jpeg_quality_75``: the default tracker (true model) on the same
  frames JPEG-compressed at that quality, as a camera sends them through image_transport's
  compressed plugin (95 is its default ``jpeg_quality``; 75 saves bandwidth) and the nodes
  decode them (OpenCV, with ``compressed:=true``): 8x8 block artifacts, ringing and lost fine
  texture instead of sensor noise alone;
- ``small_face``: the default tracker (true model) on the same motion filmed with half the
  focal length (a wider lens), so the face is half as large in the image (its nodes span 50-65
  px from temple to temple instead of 105-135), as at twice the distance (1.1-1.4 m instead of
  0.55-0.7 m);
- ``realistic_true_model`` and ``realistic_packaged_model``: the default tracker on the same
  motion by subject 0 of the 'realistic' population of the seed (issue 11's world: thirteen
  identity modes led by face size, identity sharing directions with the expressions), with that
  population's own model and with the packaged model
  (:func:`~face_tracking_ros.data.default_model_path`, learned from the default population): a
  face whose identity and expressions the packaged model never saw.

A still head of the same subject (300 frames of the 'static' scene: head, neutral face and light
fixed, only the sensor noise changes) gives the jitter: the standard deviation of the estimated
rotation angles per axis (``angle_std_deg``, issue 6's measure) and the frame-to-frame noise
of the rotation error (``jitter_deg``, mean over the axes), smoothed and raw
(``angle_std_unfiltered_deg``, from the same run). Every figure is a mean over the
seeds, next to each seed's.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from face_tracking_ros.bench.common import BenchOptions, jpeg_compressed
from face_tracking_ros.bench.world import (
    RenderedSequence,
    learned_model,
    render_sequence,
    scene_config,
)
from face_tracking_ros.data import default_model_path, photo_face_paths
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.scenes import Kind
from face_tracking_ros.synthetic.true_model import true_face_model
from face_tracking_ros.tracking.baseline import LKPnPTracker
from face_tracking_ros.tracking.bundle import BundleConfig
from face_tracking_ros.tracking.evaluation import (
    Tracker,
    TrackerEvaluation,
    evaluate_sequence,
    evaluate_tracker,
    track_images,
    tracked_sequence,
)
from face_tracking_ros.tracking.initialisation import Initialisation
from face_tracking_ros.tracking.mono import MonoTracker
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.pose_filter import FilteredTracker, PoseFilter, filter_results

SEEDS = 3
CLICK_DRAWS = 3
CLICK_DRAW_STRIDE = 1000  # the click seeds of a seed's draws: seed, seed + 1000, ...
DRAWS_ROW = 'true_model_click_draws'
FRAMES, QUICK_FRAMES = 1000, 20
STILL_FRAMES, QUICK_STILL_FRAMES = 300, 10
WIDTH, HEIGHT = 640, 480
JPEG_QUALITIES = (95, 75)
ABLATIONS = {
    'epsilon_0': MonoTrackerConfig(epsilon=0.0),
    'prior_off': MonoTrackerConfig(prior_weight=0.0),
    'bundle_off': MonoTrackerConfig(bundle=BundleConfig(views=0)),
}


def run(options: BenchOptions) -> dict[str, Any]:
    """Every row of the protocol, per seed and averaged over the seeds.

    Returns:
        ``{'scene': str, 'rows': {row: {'mean': {...}, 'seeds': [{...}, ...], 'click_draws': n}},
        'still': {'mean': {...}, 'seeds': [...]}}``, with n the draws of the click noise per seed
        behind a row; angles in degrees, lengths in mm.
    """
    seeds = [options.seed + k for k in range(1 if options.quick else SEEDS)]
    frames = QUICK_FRAMES if options.quick else FRAMES
    rows: dict[str, list[dict[str, Any]]] = {}
    still: list[dict[str, Any]] = []
    for seed in seeds:
        for row, figures in _free_rows(seed, frames).items():
            rows.setdefault(row, []).append(figures)
        still.append(_still(seed, QUICK_STILL_FRAMES if options.quick else STILL_FRAMES))
    return {
        'scene': f'{WIDTH}x{HEIGHT} mono, {frames} frames at 30 fps, free head motion, '
        f'held-out subject of seeds {seeds[0]}-{seeds[-1]}, 1 px clicks',
        'rows': {
            row: {
                'mean': _mean(figures),
                'seeds': figures,
                'click_draws': CLICK_DRAWS if row == DRAWS_ROW else 1,
            }
            for row, figures in rows.items()
        },
        'still': {'mean': _mean(still), 'seeds': still},
    }


def _free_rows(seed: int, frames: int) -> dict[str, dict[str, Any]]:
    """Every tracker and ablation on one seed's free-motion sequence."""
    config = scene_config(Kind.MONO, WIDTH, HEIGHT, frames, seed)
    sequence = render_sequence(config)
    camera = sequence.reference
    population = FacePopulation(seed=seed)
    true34, true19 = true_face_model(population, 34), true_face_model(population, 19)
    learned = learned_model(34, seed).model

    def published(
        model: FaceModel,
        tracker_config: MonoTrackerConfig | None = None,
        lens: PinholeCamera = camera,
    ) -> Tracker:
        tracker = MonoTracker(model, lens, tracker_config)
        return FilteredTracker(tracker, PoseFilter(lens), config.fps)

    init34, truth34 = sequence.initialisation(true34.node_names, seed), sequence.true_nodes(34)
    raw, smoothed = _raw_and_published(
        true34, camera, config.fps, sequence.images('image'), init34, truth34
    )
    rows = {'true_model': _figures(smoothed), 'unfiltered': _figures(raw)}
    trackers: dict[str, tuple[Tracker, FaceModel]] = {
        'learned_model': (published(learned), learned),
        'baseline': (LKPnPTracker(true34, camera), true34),
        'nodes_19': (published(true19), true19),
    }
    trackers |= {
        name: (published(true34, ablation), true34) for name, ablation in ABLATIONS.items()
    }
    for name, (tracker, model) in trackers.items():
        rows[name] = _row(tracker, model, sequence, seed)
    draws = [
        _row(published(true34), true34, sequence, seed + CLICK_DRAW_STRIDE * draw)
        for draw in range(1, CLICK_DRAWS)
    ]
    rows[DRAWS_ROW] = _mean([rows['true_model'], *draws])
    photo, photo_nodes = photo_face_paths()
    photo_sequence = render_sequence(replace(config, texture=photo, texture_nodes=photo_nodes))
    rows['photo_texture'] = _row(published(true34), true34, photo_sequence, seed)
    rows['photo_baseline'] = _row(LKPnPTracker(true34, camera), true34, photo_sequence, seed)
    blurred = render_sequence(replace(config, motion_blur=True))
    rows['motion_blur'] = _row(published(true34), true34, blurred, seed)
    for quality in JPEG_QUALITIES:
        compressed = _jpeg(sequence, quality)
        rows[f'jpeg_quality_{quality}'] = _row(published(true34), true34, compressed, seed)
    small = render_sequence(replace(config, focal=config.focal / 2))
    rows['small_face'] = _row(published(true34, lens=small.reference), true34, small, seed)
    realistic = replace(config, population='realistic')
    realistic_sequence = render_sequence(realistic)
    models = {
        'realistic_true_model': true_face_model(FacePopulation('realistic', seed), 34),
        'realistic_packaged_model': load_model(default_model_path(34)),
    }
    for name, model in models.items():
        rows[name] = _row(published(model), model, realistic_sequence, seed)
    return rows


def _jpeg(sequence: RenderedSequence, quality: int) -> RenderedSequence:
    """The sequence with every image JPEG-compressed at ``quality`` (:func:`.jpeg_compressed`)."""
    frames = [
        replace(
            frame,
            images={name: jpeg_compressed(image, quality) for name, image in frame.images.items()},
        )
        for frame in sequence.frames
    ]
    return replace(sequence, frames=frames)


def _row(
    tracker: Tracker, model: FaceModel, sequence: RenderedSequence, click_seed: int
) -> dict[str, Any]:
    """Accuracy and median time of one tracker on a sequence, from one draw of the clicks."""
    init = sequence.initialisation(model.node_names, click_seed)
    truth = sequence.true_nodes(model.num_nodes)
    return _figures(evaluate_tracker(tracker, model, sequence.images('image'), truth, init))


def _figures(evaluation: TrackerEvaluation) -> dict[str, Any]:
    """A row's figures: the accuracy and the median time per frame."""
    return {**evaluation.accuracy.as_dict(), 'ms_median': evaluation.ms_median}


def _still(seed: int, frames: int) -> dict[str, Any]:
    """Jitter of the default tracker (true model) on a static head, published and raw."""
    config = replace(scene_config(Kind.MONO, WIDTH, HEIGHT, frames, seed), motion='static')
    sequence = render_sequence(config)
    model = true_face_model(FacePopulation(seed=seed), 34)
    camera = sequence.reference
    raw, published = _raw_and_published(
        model,
        camera,
        config.fps,
        sequence.images('image'),
        sequence.initialisation(model.node_names, seed),
        sequence.true_nodes(34),
    )
    accuracy = published.accuracy
    return {
        'tracked': accuracy.tracked,
        'frames': accuracy.frames,
        'angle_std_deg': list(published.angle_std_deg),
        'angle_std_unfiltered_deg': list(raw.angle_std_deg),
        'jitter_deg': accuracy.jitter_deg,
        'rotation_mae_deg': list(accuracy.rotation_mae_deg),
    }


def _raw_and_published(
    model: FaceModel,
    camera: PinholeCamera,
    fps: float,
    images: list[np.ndarray],
    init: Initialisation,
    truth: np.ndarray,
) -> tuple[TrackerEvaluation, TrackerEvaluation]:
    """The default tracker's raw and published (One Euro filtered) results, from one run.

    The filter smooths only the output, so filtering the raw results gives what the node
    publishes; the published row's CPU time per frame is the tracker's plus the filter's.
    """
    results, seconds = track_images(MonoTracker(model, camera), images, init)
    published, filter_seconds = filter_results(PoseFilter(camera), results, fps)
    return (
        evaluate_sequence(tracked_sequence(results, seconds), model, truth),
        evaluate_sequence(tracked_sequence(published, seconds + filter_seconds), model, truth),
    )


def _mean(per_seed: list[dict[str, Any]]) -> dict[str, Any]:
    """The mean over seeds (or draws) of every numeric figure (per axis for triples)."""
    mean: dict[str, Any] = {}
    for key, value in per_seed[0].items():
        if isinstance(value, int | float | list | tuple) and not isinstance(value, bool):
            mean[key] = np.mean([np.asarray(s[key], dtype=float) for s in per_seed], axis=0)
    return {key: value.tolist() for key, value in mean.items()}
