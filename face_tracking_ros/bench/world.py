"""The synthetic world the benchmarks run on: training meshes, a learned model, rendered frames.

The face model every tracker benchmark uses is learned (§3.3 alignment, §3.4 learner) from
meshes of the population's subjects 1, 2, ...; the rendered test sequences show subject 0, whom
the model has never seen. The initialisation is the simulated semi-automatic one: the first
frame's true nodes projected into the (left) image, with 1 px of click noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from face_tracking_ros.geometry.camera import PinholeCamera, StereoRig
from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.result import LearningResult
from face_tracking_ros.learning.seed import SeedConfig, learn_seed
from face_tracking_ros.learning.training_set import NEUTRAL_LABEL, TrainingSet
from face_tracking_ros.model.model_file import load_model, save_model
from face_tracking_ros.recognition.benchmark import BenchmarkConfig, synthetic_sequences
from face_tracking_ros.recognition.expression import (
    ExpressionTrainingConfig,
    train_expression_classifier,
)
from face_tracking_ros.synthetic.clicks import clicks_from_bag, simulated_clicks, write_init_file
from face_tracking_ros.synthetic.faces import ACTIVE_EXPRESSIONS, FacePopulation
from face_tracking_ros.synthetic.recording import bag_name, record
from face_tracking_ros.synthetic.scenes import Kind, SceneConfig, SequenceRenderer, SyntheticFrame
from face_tracking_ros.tracking.initialisation import Initialisation

REFERENCE_WIDTH, REFERENCE_FOCAL = 640, 600.0  # px; other sizes scale the focal length
CAMERA_DISTANCE = 0.6  # m, of the training meshes
HEAD_JITTER = np.radians(3.0)  # rad, rotation spread of the training meshes
NEUTRAL_SHARE = 0.4  # share of neutral training frames
NODE_NOISE = 0.0005  # m, per coordinate, of the training meshes
CLICK_NOISE_PX = 1.0
TEST_SUBJECT = 0


def training_set(
    population: FacePopulation,
    num_nodes: int,
    subjects: int,
    frames_per_subject: int,
    rng: np.random.Generator,
) -> TrainingSet:
    """Stereo-tracker-like training meshes: subjects 1..S, neutral and single-expression frames.

    Each frame is eq. 3 with the true bases (one random expression at a random intensity, or
    neutral), posed by eq. 1 with a random small rotation about a point 0.6 m ahead, plus
    Gaussian node noise. Each subject's frames form two sequences (first and second half).
    Vectorised: 10^6 frames take seconds.

    Args:
        population: the true population.
        num_nodes: 19 or 34.
        subjects: S >= 1, subjects 1..S (subject 0 is the test subject).
        frames_per_subject: frames F per subject.
        rng: random generator.

    Returns:
        The (S F, N, 3) camera-frame meshes with neutral flags and labels.
    """
    total = subjects * frames_per_subject
    subject_index = np.repeat(np.arange(subjects), frames_per_subject)
    neutral_faces = np.stack(
        [population.subject(s + 1).neutral_nodes[:num_nodes] for s in range(subjects)]
    )
    expression = rng.integers(len(ACTIVE_EXPRESSIONS), size=total)
    neutral = rng.uniform(size=total) < NEUTRAL_SHARE
    intensity = np.where(neutral, 0.0, rng.uniform(0.3, 1.0, total))
    basis = population.expression_basis_true.reshape(-1, 3, len(ACTIVE_EXPRESSIONS))
    displacement = basis[:num_nodes, :, expression].transpose(2, 0, 1)
    meshes = neutral_faces[subject_index] + intensity[:, None, None] * displacement
    meshes += rng.normal(scale=NODE_NOISE, size=meshes.shape)
    rotation = Rotation.from_rotvec(rng.normal(scale=HEAD_JITTER, size=(total, 3))).as_matrix()
    meshes = meshes @ np.swapaxes(rotation, 1, 2) + [0.0, 0.0, CAMERA_DISTANCE]
    labels = np.where(neutral, NEUTRAL_LABEL, np.asarray(ACTIVE_EXPRESSIONS)[expression])
    return TrainingSet(
        meshes=meshes,
        subject_index=subject_index,
        neutral=neutral,
        subject_ids=tuple(population.subject(s + 1).subject_id for s in range(subjects)),
        sequence_index=np.tile(np.arange(frames_per_subject) >= frames_per_subject // 2, subjects),
        labels=labels,
    )


def learned_model(
    num_nodes: int, seed: int, subjects: int = 11, frames: int = 200
) -> LearningResult:
    """The benchmarks' face model: §3.3 alignment then the §3.4 learner (p = 2, q = 5).

    Args:
        num_nodes: 19 or 34.
        seed: seed of the population and of the training draw.
        subjects: training subjects.
        frames: frames per subject.
    """
    population = FacePopulation(seed=seed)
    training = training_set(population, num_nodes, subjects, frames, np.random.default_rng(seed))
    return learn_seed(align_training_set(training), SeedConfig())


def scene_config(kind: Kind, width: int, height: int, frames: int, seed: int) -> SceneConfig:
    """A test scene of subject 0 moving freely at 30 fps; focal length scaled with the width."""
    return SceneConfig(
        kind=kind,
        frames=frames,
        fps=30.0,
        seed=seed,
        motion='free',
        width=width,
        height=height,
        focal=REFERENCE_FOCAL * width / REFERENCE_WIDTH,
    )


@dataclass(frozen=True)
class RenderedSequence:
    """Rendered frames of one test sequence with what a tracker needs to start.

    Attributes:
        config: the scene.
        frames: the frames with their truth.
        cameras: the cameras by name ('image', or 'left' and 'right').
    """

    config: SceneConfig
    frames: list[SyntheticFrame]
    cameras: dict[str, PinholeCamera]

    @property
    def reference(self) -> PinholeCamera:
        """The mono camera or the left one."""
        return next(iter(self.cameras.values()))

    def rig(self) -> StereoRig:
        """The stereo rig of a stereo scene."""
        return StereoRig(self.cameras['left'], self.cameras['right'])

    def images(self, name: str) -> list[np.ndarray]:
        """The images of one camera, in frame order."""
        return [frame.images[name] for frame in self.frames]

    def true_nodes(self, num_nodes: int) -> np.ndarray:
        """(F, N, 3) true nodes in the reference camera frame, m."""
        return np.stack([frame.truth.nodes_camera[:num_nodes] for frame in self.frames])

    def initialisation(self, node_names: tuple[str, ...], seed: int) -> Initialisation:
        """Simulated clicks on the first frame's true nodes in the reference camera."""
        nodes = self.frames[0].truth.nodes_camera[: len(node_names)]
        rng = np.random.default_rng(seed)
        return simulated_clicks(node_names, nodes, self.reference, CLICK_NOISE_PX, rng)


def render_sequence(config: SceneConfig) -> RenderedSequence:
    """Render the test subject's first sequence of a scene."""
    renderer = SequenceRenderer(config, TEST_SUBJECT)
    return RenderedSequence(config, list(renderer.frames(0)), renderer.cameras)


def model_file(work_dir: Path, num_nodes: int, seed: int) -> Path:
    """The learned model saved as a model file under ``work_dir`` (written once, then reused)."""
    path = Path(work_dir) / f'model_{num_nodes}_seed{seed}.npz'
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        save_model(learned_model(num_nodes, seed).model, path)
    return path


def recorded_bag(work_dir: Path, config: SceneConfig) -> tuple[Path, Path]:
    """The test sequence of a scene recorded as a bag, and its simulated-clicks init file.

    Both are written once under ``work_dir/bags`` (the rendering is deterministic), then reused.

    Returns:
        ``(bag directory, init file)``.
    """
    kind = Kind(config.kind).value
    scene_dir = (
        Path(work_dir)
        / 'bags'
        / (f'{kind}_{config.width}x{config.height}_{config.frames}f_seed{config.seed}')
    )
    bag = scene_dir / bag_name(TEST_SUBJECT, 0)
    init_file = scene_dir / 'init.json'
    if not init_file.is_file():
        if not bag.exists():
            record(config, scene_dir)
        write_init_file(clicks_from_bag(bag, CLICK_NOISE_PX, config.seed), init_file)
    return bag, init_file


def classifier_file(work_dir: Path, seed: int, subjects: int = 4) -> Path:
    """An expression classifier for the 34-node benchmark model (written once, then reused).

    Trained like ``face-tracking train-expressions`` on the recognition benchmark's training
    scripts of subjects 0..``subjects``-1 (true nodes with tracking noise, fitted to the model).
    """
    path = Path(work_dir) / f'expressions_34_seed{seed}.npz'
    if not path.is_file():
        model = load_model(model_file(work_dir, 34, seed))
        config = BenchmarkConfig(seed=seed, subjects=subjects, duration=10.0)
        sequences = synthetic_sequences(
            FacePopulation(seed=seed),
            model,
            range(subjects),
            1,
            True,
            config,
            np.random.default_rng(seed),
        )
        train_expression_classifier(sequences, ExpressionTrainingConfig()).save(path)
    return path
