"""Issue 5's stereo protocol: training sequences tracked as `face-tracking learn` tracks them.

Subjects 0..S-1 of the synthetic population each play one 380-frame training sequence (head
still, neutral start, then the expressions in turn) in front of the 640x480 stereo rig at 30 fps.
The stereo tracker runs over every sequence as ``face-tracking learn`` runs it on raw stereo bags
(``retroactive_depths``: the frame-1 node depths refined over the whole sequence, applied to
every pair), initialised from simulated clicks on the first left image: exact ones and, drawn
once per subject, ones with 1 px of noise, with the 34-node mesh, and exact ones with the
19-node mesh (no face edge). Each run is scored against the true nodes by
:func:`~face_tracking_ros.tracking.stereo_evaluation.evaluate_stereo` (node RMS, per group,
largest reprojection error, drift from frame 1 to the last, face-edge slip along the boundary).

Then the default learner (joint, p = 2, q = 5) learns a model from each set of meshes of one
mesh size (34 nodes: true, tracked from exact clicks, tracked from 1 px clicks; 19 nodes: true,
tracked from exact clicks), and each model is compared with the population's true subspaces of
that size (:func:`~face_tracking_ros.learning.evaluation.compare_with_truth`): the issue's target
is a model learned from tracked meshes within 0.01 of the similarity that the true meshes
reach.

More runs track recordings that differ from the renderer's exact pairs (:class:`Recording`),
and their meshes are not learned from: two of the 19-node mesh put a real rig's faults on the
right images (:class:`RigFault`: 15 % brighter, rows 0.3 px lower), tracked with the tracker's
gain and row-offset corrections (:mod:`~face_tracking_ros.tracking.camera_gain`,
:mod:`~face_tracking_ros.tracking.row_offset`) and without; three track both images
JPEG-compressed (:class:`JpegRecording`) as image_transport's compressed plugin records them:
at its default quality 95 with both mesh sizes, and at 75 with the 19-node mesh.

All of that runs on the default population, and again (exact clicks, both mesh sizes) on the
'realistic' one (:mod:`face_tracking_ros.synthetic.faces`): thirteen identity modes led by face
size, identity sharing directions with the expressions, the expressions scaled by 0.677. The
tracker's face-model term uses the packaged model, learned from the default population, so the
realistic runs track faces whose identity and expression variation that model never saw, as the
issue asks ("tune for faces in general"). The default population is also filmed at half the
image size and focal length (320x240, faces of about 60-70 px from temple to temple instead of
120-140), as a camera of that resolution or a face twice as far away shows it (exact clicks,
both mesh sizes, learned from too).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any, Protocol

import cv2
import numpy as np

from face_tracking_ros.bench.common import BenchOptions, jpeg_compressed
from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.evaluation import compare_with_truth, population_truth
from face_tracking_ros.learning.methods import make_learner
from face_tracking_ros.learning.training_set import MeshSequence, TrainingSet
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.synthetic.clicks import simulated_clicks
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.scenes import Kind, SceneConfig, SequenceRenderer
from face_tracking_ros.tracking.initialisation import Initialisation
from face_tracking_ros.tracking.stereo import StereoTracker
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig
from face_tracking_ros.tracking.stereo_evaluation import StereoEvaluation, evaluate_stereo

SUBJECTS, QUICK_SUBJECTS = 6, 3
FRAMES, QUICK_FRAMES = 380, 12
FPS = 30.0


class Recording(Protocol):
    """How a recording's pairs differ from the renderer's exact ones, and how to track them."""

    def pair(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The recorded pair of an exact one."""
        ...

    def configured(self, config: StereoTrackerConfig) -> StereoTrackerConfig:
        """The tracker's configuration for such recordings."""
        ...


@dataclass(frozen=True)
class RigFault:
    """What a real rig adds to the renderer's exact one, on the right images (a Recording).

    Attributes:
        gain: the right camera's gain relative to the left.
        row_offset_px: how far below the calibration's rows the right image shows the scene.
        corrected: track with the tracker's gain and row-offset corrections (its default).
    """

    gain: float
    row_offset_px: float
    corrected: bool

    def right_image(self, image: np.ndarray) -> np.ndarray:
        """The right image with the fault: (H, W) float32 grey levels, saturating at 255."""
        height, width = image.shape
        shift = np.float32([[1.0, 0.0, 0.0], [0.0, 1.0, self.row_offset_px]])
        moved = cv2.warpAffine(
            image.astype(np.float32) * self.gain,
            shift,
            (width, height),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
        return np.minimum(moved, 255.0)

    def pair(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The left image as it is, the right one with the fault."""
        return left, self.right_image(right)

    def configured(self, config: StereoTrackerConfig) -> StereoTrackerConfig:
        """``config`` with the gain and row-offset corrections on or off (``corrected``)."""
        corrected = self.corrected
        return replace(config, gain_compensation=corrected, row_offset_correction=corrected)


@dataclass(frozen=True)
class JpegRecording:
    """Both images JPEG-compressed at ``quality`` (a Recording).

    As the stereo_tracker gets image_transport's compressed topics (:func:`.jpeg_compressed`).
    """

    quality: int

    def pair(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Both images compressed."""
        return jpeg_compressed(left, self.quality), jpeg_compressed(right, self.quality)

    def configured(self, config: StereoTrackerConfig) -> StereoTrackerConfig:
        """``config`` as it is."""
        return config


FAULT = RigFault(gain=1.15, row_offset_px=0.3, corrected=True)


@dataclass(frozen=True)
class Scene:
    """The training sequences of one population, filmed at one image scale.

    Attributes:
        population: population preset ('default' or 'realistic').
        scale: of the 640x480 images and their focal length (600 px).
        prefix: of the scene's learning entries in the results.
    """

    population: str
    scale: float = 1.0
    prefix: str = ''


SCENES = {
    'default': Scene('default'),
    'realistic': Scene('realistic', prefix='realistic_'),
    'half_size': Scene('default', 0.5, 'half_size_'),
}
WIDTH, HEIGHT, FOCAL = 640, 480, 600.0  # px, at scale 1

# run: (scene, click noise px, N, recording: None for the exact pairs); the runs of the scenes
# other than the default are named after them.
RUNS: dict[str, tuple[str, float, int, Recording | None]] = {
    'exact_clicks': ('default', 0.0, 34, None),
    'clicks_1px': ('default', 1.0, 34, None),
    'nodes_19': ('default', 0.0, 19, None),
    'nodes_19_rig_fault_corrected': ('default', 0.0, 19, FAULT),
    'nodes_19_rig_fault_uncorrected': ('default', 0.0, 19, replace(FAULT, corrected=False)),
    'exact_clicks_jpeg_95': ('default', 0.0, 34, JpegRecording(95)),
    'nodes_19_jpeg_95': ('default', 0.0, 19, JpegRecording(95)),
    'nodes_19_jpeg_75': ('default', 0.0, 19, JpegRecording(75)),
    'realistic_exact_clicks': ('realistic', 0.0, 34, None),
    'realistic_nodes_19': ('realistic', 0.0, 19, None),
    'half_size_exact_clicks': ('half_size', 0.0, 34, None),
    'half_size_nodes_19': ('half_size', 0.0, 19, None),
}


def run(options: BenchOptions) -> dict[str, Any]:
    """Every subject's figures per run, their pooled figures, and the learned models.

    Returns:
        ``{'scene': str, 'runs': {run: {'subjects': [...], 'pooled': {...}}},
        'learning': {'<prefix><N>_nodes': {meshes: {...}}}}`` (prefix: a :class:`Scene`'s;
        meshes: 'true', 'exact_clicks' or 'clicks_<noise>px'); lengths in mm, reprojection in
        px.
    """
    evaluations: dict[str, list[StereoEvaluation]] = {}
    learning: dict[str, dict[str, Any]] = {}
    for name, scene in SCENES.items():
        runs = {run: spec[1:] for run, spec in RUNS.items() if spec[0] == name}
        tracked = _population(_scene(options, scene), runs, evaluations)
        for key, models in tracked.items():
            learning[scene.prefix + key] = models
    configs = [_scene(options, scene) for scene in SCENES.values()]
    return {
        'scene': f'stereo, {configs[0].subjects} subjects x {configs[0].frames} frames at '
        f'{FPS:g} fps, head still, expressions; '
        + ', '.join(f'{c.population} population at {c.width}x{c.height}' for c in configs),
        'runs': {
            run: {
                'subjects': [evaluation.in_mm() for evaluation in items],
                'pooled': _pooled(items),
            }
            for run, items in evaluations.items()
        },
        'learning': learning,
    }


def _scene(options: BenchOptions, scene: Scene) -> SceneConfig:
    """The training scene of the protocol's subjects of a :class:`Scene`."""
    return SceneConfig(
        kind=Kind.STEREO,
        subjects=QUICK_SUBJECTS if options.quick else SUBJECTS,
        frames=QUICK_FRAMES if options.quick else FRAMES,
        fps=FPS,
        seed=options.seed,
        motion='still',
        population=scene.population,
        width=round(WIDTH * scene.scale),
        height=round(HEIGHT * scene.scale),
        focal=FOCAL * scene.scale,
    )


def _population(
    scene: SceneConfig,
    runs: dict[str, tuple[float, int, Recording | None]],
    evaluations: dict[str, list[StereoEvaluation]],
) -> dict[str, dict[str, Any]]:
    """Track every subject of one population per run; the models learned per mesh size.

    Args:
        scene: the population's training scene.
        runs: {run: (click noise px, N, recording)}.
        evaluations: {run: evaluations}, every subject's appended here.

    Returns:
        {'<N>_nodes': {meshes: comparison with the population's true subspaces}}.
    """
    sizes = sorted({num_nodes for _, num_nodes, _ in runs.values()}, reverse=True)
    sequences: dict[int, dict[str, list[MeshSequence]]] = {n: {'true': []} for n in sizes}
    alpha = []
    for subject in range(scene.subjects):
        renderer = SequenceRenderer(scene, subject)
        frames = list(renderer.frames(0))
        rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
        truth = np.stack([frame.truth.nodes_camera for frame in frames])
        labels = tuple(frame.truth.label for frame in frames)
        alpha.append(np.stack([frame.truth.alpha for frame in frames]))
        subject_id = frames[0].truth.subject_id
        for num_nodes, by_meshes in sequences.items():
            true = MeshSequence.labelled(subject_id, truth[:, :num_nodes], labels)
            by_meshes['true'].append(true)
        pairs = [(frame.images['left'], frame.images['right']) for frame in frames]
        for run, (noise, num_nodes, recording) in runs.items():
            topology = mesh_topology(num_nodes)
            rng = np.random.default_rng([scene.seed, subject])
            nodes = truth[:, :num_nodes]
            clicks = simulated_clicks(topology.node_names, nodes[0], rig.left, noise, rng)
            meshes, status = _tracked(rig, pairs, clicks, num_nodes, recording)
            evaluation = evaluate_stereo(meshes, nodes, rig, topology, status)
            evaluations.setdefault(run, []).append(evaluation)
            if recording is not None:
                continue
            tracked = MeshSequence.labelled(subject_id, meshes, labels)
            clicks_name = f'clicks_{noise:g}px' if noise else 'exact_clicks'
            sequences[num_nodes].setdefault(clicks_name, []).append(tracked)
    population = FacePopulation(scene.population, scene.seed)
    true_alpha, learner = np.concatenate(alpha), make_learner()
    learning = {}
    for num_nodes, by_meshes in sequences.items():
        subspaces = population_truth(population, num_nodes, range(scene.subjects), true_alpha)
        learning[f'{num_nodes}_nodes'] = {
            name: asdict(
                compare_with_truth(
                    learner(align_training_set(TrainingSet.from_sequences(items))).model,
                    subspaces,
                )
            )
            for name, items in by_meshes.items()
        }
    return learning


def _tracked(
    rig: StereoRig,
    pairs: list,
    clicks: Initialisation,
    num_nodes: int,
    recording: Recording | None,
) -> tuple[np.ndarray, np.ndarray]:
    """(F, N, 3) meshes and (F,) statuses of a sequence tracked as learn tracks raw bags.

    With a recording, its pairs and its configuration of the tracker.
    """
    config = StereoTrackerConfig(num_nodes=num_nodes, refine_depths=True)
    if recording is not None:
        pairs = [recording.pair(left, right) for left, right in pairs]
        config = recording.configured(config)
    tracker = StereoTracker(rig, config)
    tracker.reset(clicks)
    results = tracker.with_final_depths([tracker.step(left, right) for left, right in pairs])
    return np.stack([r.nodes_cam for r in results]), np.array([int(r.status) for r in results])


def _pooled(evaluations: list[StereoEvaluation]) -> dict[str, Any]:
    """Figures over all subjects: RMS of the RMS figures, largest of the largest ones, mm / px."""

    def rms(values: list[float]) -> float:
        return 1000.0 * float(np.sqrt(np.mean(np.square(values))))

    groups, nodes = evaluations[0].node_rms_by_group, evaluations[0].node_rms_by_node
    return {
        'node_rms_mm': rms([e.node_rms for e in evaluations]),
        'node_rms_by_group_mm': {
            group: rms([e.node_rms_by_group[group] for e in evaluations]) for group in groups
        },
        'node_rms_by_node_mm': {
            node: rms([e.node_rms_by_node[node] for e in evaluations]) for node in nodes
        },
        'max_reprojection_px': max(e.max_reprojection for e in evaluations),
        'drift_mm': rms([e.drift for e in evaluations]),
        'max_drift_mm': 1000.0 * max(e.max_drift for e in evaluations),
        'boundary_slip_mm': 1000.0 * max(e.boundary_slip for e in evaluations),
        'tracked_fraction': min(e.tracked_fraction for e in evaluations),
    }
