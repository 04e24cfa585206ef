"""Record synthetic sequences as rosbag2 (MCAP) bags with images, camera infos and ground truth.

One bag per (subject, sequence), named ``subject_SS_seq_QQ``. Topics (relative, as the nodes
subscribe to them):

- mono: ``image`` (sensor_msgs/Image), ``camera_info`` (sensor_msgs/CameraInfo);
- stereo: ``left/image_raw``, ``left/camera_info``, ``right/image_raw``, ``right/camera_info``
  (a rectified pair: the right P has ``P[0, 3] = -fx B``);
- both: ``truth/face`` (face_tracking_msgs/FaceTruth; frame_id is the reference camera's, nodes
  and pose in that camera's frame, alpha and sigma in the TRUE bases of
  :mod:`face_tracking_ros.synthetic.faces`).

Messages are built with the rosbags typestore (no ROS runtime) through
:mod:`face_tracking_ros.io.conversions`. Stamps come from the frame index and the frame rate, so
the same configuration writes byte-identical bags.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import BagWriter
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.scenes import SceneConfig, SequenceRenderer, SyntheticFrame

TRUTH_TOPIC = 'truth/face'

# Per camera name: (image topic, camera_info topic, optical frame id).
CAMERA_TOPICS = {
    'image': ('image', 'camera_info', 'camera_optical_frame'),
    'left': ('left/image_raw', 'left/camera_info', 'left_camera_optical_frame'),
    'right': ('right/image_raw', 'right/camera_info', 'right_camera_optical_frame'),
}


@dataclass(frozen=True)
class RecordedBag:
    """A written bag.

    Attributes:
        path: the bag directory.
        subject_id: its subject.
        sequence: its sequence index.
        frames: number of frames.
        bytes: total size of its files.
    """

    path: Path
    subject_id: str
    sequence: int
    frames: int
    bytes: int


def bag_name(subject_index: int, sequence_index: int) -> str:
    """Directory name of the bag of a (subject, sequence)."""
    return f'subject_{subject_index:02d}_seq_{sequence_index:02d}'


def record(
    config: SceneConfig,
    out_dir: Path,
    progress: Callable[[RecordedBag], None] | None = None,
    on_frame: Callable[[SyntheticFrame], None] | None = None,
) -> list[RecordedBag]:
    """Render every (subject, sequence) of a configuration into its own bag under ``out_dir``.

    Args:
        config: what to render.
        out_dir: directory receiving the bags (created if missing).
        progress: called after each bag is written.
        on_frame: called with every rendered frame (e.g. to collect a contact sheet).

    Raises:
        ConfigError: if a bag directory already exists.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    population = FacePopulation(config.population, config.seed)
    bags = []
    for subject_index in range(config.subjects):
        renderer = SequenceRenderer(config, subject_index, population)
        for sequence in range(config.sequences):
            path = out_dir / bag_name(subject_index, sequence)
            if path.exists():
                msg = f'bag {path} already exists; choose another --out or remove it'
                raise ConfigError(msg)
            count = write_sequence(path, renderer, sequence, on_frame)
            size = sum(f.stat().st_size for f in path.rglob('*') if f.is_file())
            bag = RecordedBag(path, renderer.subject.subject_id, sequence, count, size)
            bags.append(bag)
            if progress is not None:
                progress(bag)
    return bags


def write_sequence(
    path: Path,
    renderer: SequenceRenderer,
    sequence: int,
    on_frame: Callable[[SyntheticFrame], None] | None = None,
) -> int:
    """Render one sequence into a new bag at ``path``; returns the number of frames."""
    factory = RosbagsMessages(typestore())
    cameras = renderer.cameras
    names = mesh_topology(34).node_names
    count = 0
    with BagWriter(path) as bag:
        for frame in renderer.frames(sequence):
            for name, image in frame.images.items():
                image_topic, info_topic, frame_id = CAMERA_TOPICS[name]
                header = conversions.make_header(factory, frame.stamp_ns, frame_id)
                message = conversions.array_to_image(factory, header, image)
                bag.write(image_topic, conversions.IMAGE_TYPE, message, frame.stamp_ns)
                info = conversions.camera_to_info(factory, header, cameras[name])
                bag.write(info_topic, conversions.CAMERA_INFO_TYPE, info, frame.stamp_ns)
            reference = CAMERA_TOPICS[next(iter(cameras))][2]
            bag.write(
                TRUTH_TOPIC,
                conversions.TRUTH_TYPE,
                _truth_msg(factory, frame, reference, names),
                frame.stamp_ns,
            )
            if on_frame is not None:
                on_frame(frame)
            count += 1
    return count


def _truth_msg(
    factory: RosbagsMessages, frame: SyntheticFrame, frame_id: str, names: tuple[str, ...]
) -> object:
    """The FaceTruth message of a frame."""
    truth = frame.truth
    return factory.make(
        conversions.TRUTH_TYPE,
        header=conversions.make_header(factory, frame.stamp_ns, frame_id),
        subject_id=truth.subject_id,
        pose=conversions.pose_msg(factory, truth.omega, truth.t),
        omega=truth.omega.astype(float),
        alpha=truth.alpha.astype(float),
        sigma=truth.sigma.astype(float),
        node_names=list(names),
        nodes=conversions.array_to_points(factory, truth.nodes_camera),
        expression_label=truth.label,
        expression_intensity=float(truth.intensity),
    )
