"""Synthetic sequences: a subject, a head trajectory, an expression script, lights and cameras.

One sequence is identified by (seed, subject index, sequence index); everything in it (motion,
expressions, light, backdrop, occluders, sensor noise) is drawn from generators seeded by that
triple, so the same configuration always produces the same frames, bit for bit, and a subject
looks the same in every sequence.

Cameras: an ideal rectified stereo rig (the left camera is the reference frame; the right one
has ``P[0, 3] = -fx B``) or a single camera, sized and focused by the configuration. Frames are
stamped ``START_NS + round(index * 1e9 / fps)`` (no wall clock), and each frame carries the
truth: pose, true alpha and sigma, nodes in the face and camera frames, the expression label and
intensity, and which nodes each camera sees.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from enum import Enum, StrEnum
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.geometry.camera import PinholeCamera, StereoRig
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.synthetic.background import Backdrop
from face_tracking_ros.synthetic.faces import PRESETS, FacePopulation, Subject
from face_tracking_ros.synthetic.motion import ExpressionScript, HeadTrajectory, Motion
from face_tracking_ros.synthetic.render import (
    FacePose,
    FaceRenderer,
    Lighting,
    Occluder,
    Sensor,
)
from face_tracking_ros.synthetic.texture import (
    ENCODINGS,
    TextureAtlas,
    load_photo_texture,
    procedural_texture,
    require_file,
)

START_NS = 1_700_000_000 * 1_000_000_000  # stamp of frame 0, ns since the epoch
MAX_FPS = 120.0
MIN_BASELINE, MAX_BASELINE = 0.03, 0.30  # m: RealSense D4xx 0.05, ZED Mini 0.063, ZED 2 0.12
MAX_TOE_IN_DEG = 10.0
MIN_SIZE, MAX_SIZE = 32, 4096  # image width and height, px
MIN_FOV_DEG, MAX_FOV_DEG = 1.0, 170.0  # horizontal field of view 2 atan(W / 2 focal)
_EXPOSURE = 0.5  # exposure time as a fraction of the frame period (motion blur)
_BLUR_SAMPLES = 3
_LIGHT_SWAY = np.radians(15.0)  # amplitude of the moving light, rad


class Kind(StrEnum):
    """Camera set-up of a sequence."""

    STEREO = 'stereo'
    MONO = 'mono'


def focal_range(width: int) -> tuple[float, float]:
    """Focal lengths (px) from a horizontal field of view of MAX_FOV_DEG to one of MIN_FOV_DEG.

    The field of view of an image ``width`` px wide is 2 atan(width / 2 focal). Beyond this
    range no camera is simulated, and a focal length of 1e12 px shifted the stereo backdrop
    (by focal x baseline / depth px) so far that OpenCV's border reflection ran for hours.
    """
    low, high = (
        width / (2.0 * math.tan(math.radians(fov) / 2.0)) for fov in (MAX_FOV_DEG, MIN_FOV_DEG)
    )
    return low, high


@dataclass(frozen=True)
class SceneConfig:
    """Everything that defines a set of synthetic sequences.

    Attributes:
        kind: 'stereo' (rectified pair) or 'mono'.
        subjects: number of subjects, >= 1.
        sequences: sequences per subject, >= 1.
        frames: frames per sequence, >= 1.
        fps: frame rate, Hz, in (0, 120].
        seed: seed of the population and of every sequence, >= 0.
        population: population preset, 'default' or 'realistic'.
        motion: 'still' (training: head still, neutral start, expressions in turn), 'free'
            (test: free head motion, random expressions) or 'static' (head, neutral face and
            light fixed: only the sensor noise changes, for jitter).
        width: image width, px, in [MIN_SIZE, MAX_SIZE].
        height: image height, px, in [MIN_SIZE, MAX_SIZE].
        encoding: 'mono8' or 'rgb8'.
        focal: focal length fx = fy, px, in :func:`focal_range` of the width (a horizontal
            field of view of MAX_FOV_DEG down to MIN_FOV_DEG degrees).
        baseline: stereo baseline B, m, in [MIN_BASELINE, MAX_BASELINE] (0.03 to 0.30).
        texture: optional face photo used as every subject's texture.
        texture_nodes: JSON of that photo's node pixels (required with ``texture``).
        motion_blur: average poses over half the frame period.
        occlusion: pass an occluder (hand, mug) in front of the face once per sequence.
        distortion: plumb_bob coefficients (k1, k2, p1, p2, k3) of every camera; empty for
            none. Images are then raw (distorted) and CameraInfo carries D; P stays the
            rectified projection of the truth (eq. 2 after rectification).
        toe_in_deg: each camera turned by this angle about its vertical axis from its
            rectified frame, the left and right ones towards each other (a toed-in rig; the
            mono camera as the left one), in [0, MAX_TOE_IN_DEG]. Images are then raw and
            CameraInfo carries the rectification rotation R, as a calibrated rig's driver
            publishes them; P stays the same.
    """

    kind: Kind | str = Kind.STEREO
    subjects: int = 1
    sequences: int = 1
    frames: int = 30
    fps: float = 10.0
    seed: int = 0
    population: str = 'default'
    motion: Motion | str = Motion.STILL
    width: int = 640
    height: int = 480
    encoding: str = 'mono8'
    focal: float = 600.0
    baseline: float = 0.11
    texture: Path | None = None
    texture_nodes: Path | None = None
    motion_blur: bool = False
    occlusion: bool = False
    distortion: tuple[float, ...] = ()
    toe_in_deg: float = 0.0

    def __post_init__(self) -> None:
        """Validate every field; errors name the field and the accepted range."""
        object.__setattr__(self, 'kind', _enum(Kind, self.kind, 'kind'))
        object.__setattr__(self, 'motion', _enum(Motion, self.motion, 'motion'))
        for name in ('subjects', 'sequences', 'frames'):
            if getattr(self, name) < 1:
                msg = f'{name} must be >= 1, got {getattr(self, name)}'
                raise ConfigError(msg)
        if not 0.0 < self.fps <= MAX_FPS:
            msg = f'fps must be in (0, {MAX_FPS:g}], got {self.fps}'
            raise ConfigError(msg)
        if self.seed < 0:
            msg = f'seed must be >= 0, got {self.seed}'
            raise ConfigError(msg)
        if self.population not in PRESETS:
            msg = f'unknown population preset {self.population!r}; choose one of {PRESETS}'
            raise ConfigError(msg)
        if self.encoding not in ENCODINGS:
            msg = f'unknown image encoding {self.encoding!r}; choose one of {ENCODINGS}'
            raise ConfigError(msg)
        if not (MIN_SIZE <= self.width <= MAX_SIZE and MIN_SIZE <= self.height <= MAX_SIZE):
            msg = (
                f'size must be in [{MIN_SIZE}, {MAX_SIZE}] px a side, '
                f'got {self.width}x{self.height}'
            )
            raise ConfigError(msg)
        low, high = focal_range(self.width)
        if not low <= self.focal <= high:
            msg = (
                f'focal must be in [{math.ceil(10 * low) / 10}, {math.floor(high)}] px for an '
                f'image {self.width} px wide (a horizontal field of view of {MAX_FOV_DEG:g} down '
                f'to {MIN_FOV_DEG:g} degrees), got {self.focal}'
            )
            raise ConfigError(msg)
        if not MIN_BASELINE <= self.baseline <= MAX_BASELINE:
            msg = f'baseline must be in [{MIN_BASELINE}, {MAX_BASELINE}] m, got {self.baseline}'
            raise ConfigError(msg)
        if (self.texture is None) != (self.texture_nodes is None):
            msg = (
                'a texture photo needs its node positions: give both texture and texture_nodes '
                '(synth --texture and --texture-nodes)'
            )
            raise ConfigError(msg)
        if len(self.distortion) not in (0, 5) or not np.all(np.isfinite(self.distortion)):
            msg = f'distortion must be 5 finite plumb_bob coefficients, got {self.distortion}'
            raise ConfigError(msg)
        if not 0.0 <= self.toe_in_deg <= MAX_TOE_IN_DEG:
            msg = f'toe_in_deg must be in [0, {MAX_TOE_IN_DEG:g}], got {self.toe_in_deg}'
            raise ConfigError(msg)
        for name in ('texture', 'texture_nodes'):
            path = getattr(self, name)
            if path is not None:
                require_file(Path(path), name)

    @property
    def duration(self) -> float:
        """Length of a sequence, s."""
        return self.frames / self.fps

    def cameras(self) -> dict[str, PinholeCamera]:
        """The cameras by name: {'left', 'right'} for stereo, {'image'} for mono."""
        if self.kind is Kind.MONO:
            cameras = {'image': PinholeCamera.ideal(self.width, self.height, self.focal)}
        else:
            rig = StereoRig.ideal(self.width, self.height, self.focal, self.baseline)
            cameras = {'left': rig.left, 'right': rig.right}
        d = np.asarray(self.distortion or np.zeros(5), dtype=float)
        turn = np.radians(self.toe_in_deg)
        return {
            name: replace(camera, d=d, r=rodrigues(np.array([0.0, sign * turn, 0.0]))[0])
            for (name, camera), sign in zip(cameras.items(), (1.0, -1.0), strict=False)
        }

    def stamp_ns(self, index: int) -> int:
        """Stamp of frame ``index``, ns since the epoch."""
        return START_NS + round(index * 1e9 / self.fps)


@dataclass(frozen=True)
class FrameTruth:
    """Ground truth of one frame.

    Attributes:
        subject_id: the subject.
        omega: (3,) rotation vector of the face frame in the reference camera frame, rad.
        t: (3,) face-frame origin in the reference camera frame, m.
        sigma: (K,) true identity coefficients (true identity basis), m.
        alpha: (E,) true expression coefficients (intensities on the true expression basis).
        nodes_camera: (34, 3) nodes in the reference (left or only) camera frame, m.
        label: expression being played ('neutral' between expressions).
        intensity: its intensity in [0, 1].
        visible: per camera name, (34,) bool: nodes that camera sees clearly.
    """

    subject_id: str
    omega: np.ndarray
    t: np.ndarray
    sigma: np.ndarray
    alpha: np.ndarray
    nodes_camera: np.ndarray
    label: str
    intensity: float
    visible: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class SyntheticFrame:
    """One rendered frame with its truth.

    Attributes:
        index: frame index in the sequence.
        stamp_ns: acquisition stamp, ns since the epoch.
        images: per camera name, (H, W) or (H, W, 3) uint8 image.
        truth: the frame's ground truth.
    """

    index: int
    stamp_ns: int
    images: dict[str, np.ndarray]
    truth: FrameTruth


class SequenceRenderer:
    """Renders the sequences of one subject.

    Args:
        config: the scene configuration.
        population: the true face population (drawn from ``config.seed`` if None).
        subject_index: which subject.
    """

    def __init__(
        self, config: SceneConfig, subject_index: int, population: FacePopulation | None = None
    ) -> None:
        """Build the subject's texture and renderer (the slow part, done once per subject)."""
        self.config = config
        self.population = (
            FacePopulation(config.population, config.seed) if population is None else population
        )
        self.subject: Subject = self.population.subject(subject_index)
        self.cameras = config.cameras()
        self.renderer = FaceRenderer(_texture(config, self.subject), Sensor(), seed=config.seed)

    def frames(
        self,
        sequence_index: int,
        *,
        script: ExpressionScript | None = None,
        occluder_pass: tuple[float, float] | None = None,
    ) -> Iterator[SyntheticFrame]:
        """Render the frames of one sequence in order.

        Args:
            sequence_index: which sequence of the subject (its head path, light, backdrop...).
            script: expressions to make instead of the sequence's own (e.g. one expression held
                while the occluder passes).
            occluder_pass: (start, duration), s, of the occluder's pass instead of the
                sequence's own; the scene must have ``occlusion``.

        Raises:
            ConfigError: for a negative sequence index, or an occluder pass in a scene without
                occlusion or not positive in duration.
        """
        if sequence_index < 0:
            msg = f'sequence index must be >= 0, got {sequence_index}'
            raise ConfigError(msg)
        sequence = self._sequence(sequence_index)
        if script is not None:
            sequence = sequence._replace(script=script)
        if occluder_pass is not None:
            sequence = sequence._replace(occluder=self._passing(sequence, *occluder_pass))
        for index in range(self.config.frames):
            yield self._frame(sequence, index)

    def _sequence(self, sequence_index: int) -> _Sequence:
        """Draw one sequence's head path, expressions, light, occluder and backdrop."""
        config, subject = self.config, self.subject
        seeds = (config.seed, subject.index, sequence_index)
        rng = np.random.default_rng(seeds)
        offset = 0.5 * config.baseline if config.kind is Kind.STEREO else 0.0
        trajectory = HeadTrajectory.random(config.motion, rng, lateral_offset=offset)
        if config.motion is Motion.STILL:
            # Subjects start at different expressions, so short sequences cover them all.
            script = ExpressionScript.training(
                config.duration, first=subject.index + sequence_index
            )
        elif config.motion is Motion.FREE:
            script = ExpressionScript.random(config.duration, rng)
        else:
            script = ExpressionScript(segments=())
        light = _LightPath.random(rng)
        if config.motion is Motion.STATIC:
            light = replace(light, rate=0.0)
        occluder = _OccluderPass.random(rng, config) if config.occlusion else None
        backdrop = Backdrop.cluttered(config.width, config.height, int(rng.integers(2**31)))
        backgrounds = {
            name: backdrop.view(camera, config.encoding) for name, camera in self.cameras.items()
        }
        return _Sequence(seeds, trajectory, script, light, occluder, backgrounds)

    def _passing(self, sequence: _Sequence, start: float, duration: float) -> _OccluderPass:
        """The sequence's occluder passing from ``start`` for ``duration`` s.

        Raises:
            ConfigError: in a scene without occlusion, or for a duration not above zero.
        """
        if sequence.occluder is None:
            msg = 'an occluder pass needs a scene with occlusion (SceneConfig.occlusion)'
            raise ConfigError(msg)
        if not duration > 0.0:
            msg = f'an occluder pass must last more than 0 s, got {duration}'
            raise ConfigError(msg)
        return replace(sequence.occluder, start=start, duration=duration)

    def _frame(self, sequence: _Sequence, index: int) -> SyntheticFrame:
        """Render frame ``index`` of ``sequence`` in every camera, with its truth."""
        time = index / self.config.fps
        poses = [
            self._pose(sequence.trajectory, sequence.script, sample)
            for sample in self._instants(time)
        ]
        state = sequence.script.state(time)
        images, visible = {}, {}
        for number, (name, camera) in enumerate(self.cameras.items()):
            occluders = (
                () if sequence.occluder is None else sequence.occluder.at(time, camera, poses[0])
            )
            images[name], visible[name] = self.renderer.render_with_visibility(
                camera,
                poses,
                sequence.backgrounds[name],
                sequence.light.at(time),
                occluders,
                rng=np.random.default_rng((*sequence.seeds, index, number)),
            )
        pose = poses[len(poses) // 2]  # the frame's instant, mid-exposure
        truth = FrameTruth(
            subject_id=self.subject.subject_id,
            omega=pose.omega,
            t=pose.t,
            sigma=self.subject.sigma_true,
            alpha=state.alpha,
            nodes_camera=pose.camera_nodes(),
            label=state.label,
            intensity=state.intensity,
            visible=visible,
        )
        return SyntheticFrame(index, self.config.stamp_ns(index), images, truth)

    def _instants(self, time: float) -> list[float]:
        """Times of the poses averaged into one frame: one, or several over the exposure."""
        if not self.config.motion_blur:
            return [time]
        half = 0.5 * _EXPOSURE / self.config.fps
        return list(time + np.linspace(-half, half, _BLUR_SAMPLES))

    def _pose(self, trajectory: HeadTrajectory, script: ExpressionScript, time: float) -> FacePose:
        """The true face at an instant: eq. 3 with true bases, posed by eq. 1."""
        omega, t = trajectory.pose(time)
        nodes = self.population.nodes(self.subject, script.state(time).alpha)
        return FacePose(nodes=nodes, omega=omega, t=t)


class _Sequence(NamedTuple):
    """What one sequence draws before its frames (:meth:`SequenceRenderer._sequence`)."""

    seeds: tuple[int, int, int]  # (world, subject, sequence): each frame's noise seeds from them
    trajectory: HeadTrajectory
    script: ExpressionScript
    light: _LightPath
    occluder: _OccluderPass | None
    backgrounds: dict[str, np.ndarray]  # per camera


@dataclass(frozen=True)
class _LightPath:
    """A key light that sways slowly about a random direction from above and in front."""

    base: np.ndarray  # (3,) unit direction towards the light, camera frame
    rate: float  # Hz
    phase: float
    strength: float

    @classmethod
    def random(cls, rng: np.random.Generator) -> _LightPath:
        """A random light from the upper front, left or right."""
        azimuth, elevation = rng.uniform(-0.7, 0.7), rng.uniform(0.2, 0.7)
        base = np.array(
            [
                np.sin(azimuth) * np.cos(elevation),
                -np.sin(elevation),
                -np.cos(azimuth) * np.cos(elevation),
            ]
        )
        return cls(base, rng.uniform(0.02, 0.1), rng.uniform(0, 2 * np.pi), rng.uniform(0.6, 0.8))

    def at(self, time: float) -> Lighting:
        """The lighting at ``time`` s: the base direction turned about the camera's y axis."""
        angle = _LIGHT_SWAY * np.sin(2 * np.pi * self.rate * time + self.phase)
        c, s = np.cos(angle), np.sin(angle)
        direction = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ self.base
        return Lighting(direction=direction, diffuse=self.strength)


@dataclass(frozen=True)
class _OccluderPass:
    """An object (a hand, a mug) that crosses in front of the face once."""

    start: float  # s
    duration: float  # s
    height: float  # vertical offset from the face origin, m
    size: tuple[float, float]  # semi-axes, m
    colour: tuple[float, float, float]
    seed: int

    @classmethod
    def random(cls, rng: np.random.Generator, config: SceneConfig) -> _OccluderPass:
        """A pass during the middle of the sequence."""
        duration = min(1.5, 0.5 * config.duration)
        start = rng.uniform(0.25, 0.75) * config.duration - 0.5 * duration
        skin_or_object = (190.0, 140.0, 120.0) if rng.uniform() < 0.5 else (60.0, 70.0, 110.0)
        return cls(
            start=start,
            duration=duration,
            height=float(rng.uniform(0.0, 0.08)),
            size=(float(rng.uniform(0.03, 0.05)), float(rng.uniform(0.05, 0.08))),
            colour=skin_or_object,
            seed=int(rng.integers(2**31)),
        )

    def at(self, time: float, camera: PinholeCamera, pose: FacePose) -> tuple[Occluder, ...]:
        """The occluder as ``camera`` sees it at ``time`` (none outside the pass)."""
        progress = (time - self.start) / self.duration
        if not 0.0 <= progress <= 1.0:
            return ()
        depth = pose.t[2] - 0.15  # 15 cm in front of the face
        centre = np.array([pose.t[0] + (progress - 0.5) * 0.3, pose.t[1] + self.height, depth])
        pixel = camera.project(centre[None])[0]
        scale = camera.focal / depth
        axes = (self.size[0] * scale, self.size[1] * scale)
        return (Occluder((float(pixel[0]), float(pixel[1])), axes, 15.0, self.colour, self.seed),)


def _enum(kind: type[Enum], value: object, name: str) -> Enum:
    """Parse an enumeration value, raising ConfigError naming the field and the choices."""
    try:
        return kind(value)
    except ValueError:
        msg = f'unknown {name} {value!r}; choose one of {[member.value for member in kind]}'
        raise ConfigError(msg) from None


def _texture(config: SceneConfig, subject: Subject) -> TextureAtlas:
    """The subject's texture: the configured photo, or its procedural skin."""
    if config.texture is not None and config.texture_nodes is not None:
        return load_photo_texture(config.texture, config.texture_nodes, config.encoding)
    return procedural_texture(subject.appearance_seed, config.encoding)
