"""The learner node: learns a face model from recorded bags and publishes it, latched.

It runs the learning pipeline of ``face-tracking learn``
(:func:`face_tracking_ros.pipelines.learn.learn_from_bags`), with the node's parameters as its
options: bags of 3-D meshes (synthetic truth, FaceMesh or FaceState) or raw stereo image bags,
which it first tracks with the stereo tracker (every mesh with the frame-1 depths refined over
its whole track; ``tracker_params``). It writes the model file and the JSON report, then
publishes the model on ``face/model`` with transient-local durability, so trackers started later
still receive it, and keeps spinning. The pipeline's progress and comparison table go to the
node's log. The pipeline's messages name the node's parameters (:func:`parameter_named`), not
the command's options.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from face_tracking_msgs.msg import FaceModel as FaceModelMsg
from rclpy.node import Node

from face_tracking_ros.errors import ConfigError, check_fields, warnings_to
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import is_bag_directory
from face_tracking_ros.io.messages import RclpyMessages
from face_tracking_ros.learning.methods import METHODS
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.model.topology import SUPPORTED_NODE_COUNTS
from face_tracking_ros.nodes.graceful import Endless, run_until_stopped
from face_tracking_ros.nodes.processor_node import DECLARE_GIVEN, QOS_PROFILES, NodeParameters
from face_tracking_ros.pipelines.learn import learn_from_bags
from face_tracking_ros.pipelines.learn_options import LearnOptions
from face_tracking_ros.processing.base import QosClass
from face_tracking_ros.wording import counted


@dataclass(frozen=True)
class LearnerConfig:
    """Parameters of the learner node (the options of ``face-tracking learn``).

    Attributes:
        bags: bags to learn from (rosbag2 directories or .mcap files).
        bag_dir: a directory of bags to learn from (added to bags): its sub-directories that
            are bags (holding metadata.yaml or .mcap files) and its .mcap files; other
            sub-directories (such as the tracked meshes' directory of a report written there,
            named after it with _meshes) are skipped and named in the log.
        output: model file to write (.npz).
        report: JSON report to write; empty: the model file's name with .json.
        method: learning method: joint (default, issue 11), seed (§3.4) or seed-weighted (§4.3).
        p: dimension of the identity subspace (sigma).
        q: dimension of the expression subspace (alpha).
        nodes: mesh nodes, 19 or 34; 0: as in the bags.
        topic: mesh topic; empty: truth/face, face/mesh_raw or face/state, the first found.
        subject: subject id of every bag without truth (FaceMesh, FaceState, raw stereo
            images); empty: from each bag's name (subject_pattern; a .mcap file's without .mcap).
        subject_pattern: bags without truth: the subject id is the first group of this regular
            expression matched against the bag's name; empty: the whole name.
        neutral_frames: bags without truth (FaceMesh, FaceState, raw stereo images): the first
            K frames of each bag show the neutral face; required for them (0: not given).
        from_images: track the images of stereo bags even when they also hold truth meshes.
        init_dir: raw stereo bags: directory of init files <bag name>.yaml|.json.
        simulate_clicks: synthetic raw stereo bags: initialise from the first frame's true nodes
            with this many pixels of click noise; negative: off.
        auto_init: raw stereo bags without an init file in init_dir: find the face with the
            optional landmark detector (pip install dlib-bin face_recognition_models).
        left_topic: raw stereo bags: the left image topic (Image or CompressedImage); empty:
            the one whose name ends in left/image_raw (or left/image_raw/compressed), else the
            only image topic with the word 'left' and not 'right' in its name.
        right_topic: raw stereo bags: the right image topic; empty: found as the left one.
        left_info_topic: raw stereo bags: the left camera_info topic; empty: the one whose name
            ends in left/camera_info, else the only camera_info topic with the word 'left' and
            not 'right' in its name.
        right_info_topic: raw stereo bags: the right camera_info topic; empty: found as the
            left one.
        tracker_params: raw stereo bags: stereo_tracker parameters NAME=VALUE for their tracking,
            after the default retroactive_depths=true (each track's final depths on all its
            meshes).
        frame_id: frame_id of the published model's header (the face frame's name).
    """

    bags: tuple[str, ...] = ()
    bag_dir: str = ''
    output: str = 'face_model.npz'
    report: str = ''
    method: str = 'joint'
    p: int = 2
    q: int = 5
    nodes: int = 0
    topic: str = ''
    subject: str = ''
    subject_pattern: str = ''
    neutral_frames: int = 0
    from_images: bool = False
    init_dir: str = ''
    simulate_clicks: float = -1.0
    auto_init: bool = False
    left_topic: str = ''
    right_topic: str = ''
    left_info_topic: str = ''
    right_info_topic: str = ''
    tracker_params: tuple[str, ...] = ()
    frame_id: str = 'face'

    def __post_init__(self) -> None:
        """Check what ``face-tracking learn``'s options would refuse, before any work.

        Raises:
            ConfigError: naming the first parameter out of range.
        """
        checks = {
            'method': self.method in METHODS,
            'p': self.p >= 1,
            'q': self.q >= 1,
            'nodes': self.nodes in (0, *SUPPORTED_NODE_COUNTS),
            'neutral_frames': self.neutral_frames >= 0,
            'output': bool(self.output),
            'simulate_clicks': True,  # any finite value (negative: off)
        }
        check_fields(self, checks)


# LearnOptions fields whose parameter has another name; the meshes of raw stereo bags go beside
# the report (<report name>_meshes/): the node has no meshes_dir.
RENAMED = {'out': 'output', 'meshes_dir': 'report'}


def parameter_named(field: str) -> str:
    """How the node's messages name the option ``field`` of LearnOptions: 'parameter output'."""
    return f'parameter {RENAMED.get(field, field)}'


def _bags_in(bag_dir: Path, say: Callable[[str], None]) -> list[Path]:
    """The bags in ``bag_dir``, by name: its bag sub-directories and .mcap files.

    A sub-directory is a bag by :func:`~face_tracking_ros.io.bags.is_bag_directory`; the
    others (the tracked meshes of a run whose report was written in ``bag_dir``, a plots
    directory, lost+found) are skipped and named to ``say``, once.

    Raises:
        ConfigError: if it is not a directory, is itself a bag (holds metadata.yaml), cannot be
            listed, or holds no bag (naming the sub-directories skipped).
    """
    if not bag_dir.is_dir():
        kind = 'not a directory' if bag_dir.exists() else 'no such directory'
        msg = f'parameter bag_dir: {bag_dir}: {kind} (expected a directory of bags)'
        raise ConfigError(msg)
    try:  # a directory one may not read or enter (its permissions) raises on each of these
        is_bag = (bag_dir / 'metadata.yaml').is_file()
        entries = [] if is_bag else sorted(bag_dir.iterdir())
        directories = [path for path in entries if path.is_dir()]
    except OSError as error:
        msg = f'parameter bag_dir: {bag_dir}: cannot list it: {error.strerror or error}'
        raise ConfigError(msg) from None
    if is_bag:
        msg = (
            f'parameter bag_dir: {bag_dir} is a bag itself, not a directory of bags: give it in '
            'the bags parameter'
        )
        raise ConfigError(msg)
    is_bag_by_name = {path.name: is_bag_directory(path) for path in directories}
    skipped = [name for name, bag in is_bag_by_name.items() if not bag]
    # A sub-directory by the bag rule, any other entry by its name.
    bags = [path for path in entries if is_bag_by_name.get(path.name, path.suffix == '.mcap')]
    not_bags, names = 'sub-directories without metadata.yaml or .mcap files', ', '.join(skipped)
    if not bags:
        why = f'{not_bags}: {names}' if skipped else 'no sub-directory, no .mcap file'
        msg = f'parameter bag_dir: {bag_dir} holds no bags ({why})'
        raise ConfigError(msg)
    if skipped:
        say(f'parameter bag_dir: {bag_dir}: skipped {names} ({not_bags})')
    return bags


def learn_options(config: LearnerConfig, say: Callable[[str], None] = print) -> LearnOptions:
    """The learning pipeline's options from the node's parameters.

    An empty string (or 0 nodes, a negative simulate_clicks) leaves the option unset; the
    options the node does not declare keep ``face-tracking learn``'s defaults, but compare,
    which is empty: only ``method`` is learned and evaluated. The sub-directories of bag_dir
    that are no bags go to ``say``.

    Raises:
        ConfigError: if no bag is given, or bag_dir is not a directory of bags.
    """
    bags = [Path(bag) for bag in config.bags]
    if config.bag_dir:
        bags += _bags_in(Path(config.bag_dir), say)
    if not bags:
        msg = 'no bags to learn from: set the bags or bag_dir parameter'
        raise ConfigError(msg)
    output = Path(config.output)
    return LearnOptions(
        bags=tuple(bags),
        out=output,
        report=Path(config.report) if config.report else output.with_suffix('.json'),
        nodes=config.nodes or None,
        p=config.p,
        q=config.q,
        method=config.method,
        compare=(),
        topic=config.topic or None,
        subject=config.subject or None,
        subject_pattern=config.subject_pattern or None,
        neutral_frames=config.neutral_frames,
        from_images=config.from_images,
        init_dir=Path(config.init_dir) if config.init_dir else None,
        simulate_clicks=config.simulate_clicks if config.simulate_clicks >= 0 else None,
        auto_init=config.auto_init,
        left_topic=config.left_topic or None,
        right_topic=config.right_topic or None,
        left_info_topic=config.left_info_topic or None,
        right_info_topic=config.right_info_topic or None,
        tracker_params=config.tracker_params,
        named=parameter_named,
    )


class LearnerNode(Endless, Node):
    """Learns once at start-up, then serves the model on ``face/model`` (latched)."""

    def __init__(self) -> None:
        """Declare the parameters, learn, write the files and publish the model."""
        super().__init__('learner', **DECLARE_GIVEN)
        parameters = NodeParameters(self)
        config = parameters.config(LearnerConfig)
        parameters.warn_unknown()
        options = learn_options(config, say=self.get_logger().info)
        self.get_logger().info(
            f'learning from {counted(len(options.bags), "bag")} by {options.method} '
            f'(p={options.p}, q={options.q}) into {options.out} and {options.report}'
        )
        with warnings_to(self.get_logger().warning):  # a damaged bag read in part
            saved = learn_from_bags(options, say=self.get_logger().info)
        model = load_model(saved)
        factory = RclpyMessages()
        stamp_ns = self.get_clock().now().nanoseconds
        header = conversions.make_header(factory, stamp_ns, config.frame_id)
        self._model_publisher = self.create_publisher(
            FaceModelMsg, 'face/model', QOS_PROFILES[QosClass.LATCHED]
        )
        self._model_publisher.publish(conversions.model_to_msg(factory, header, model))
        self.get_logger().info(
            f'published {saved} (method {model.method}, {model.num_nodes} nodes, '
            f'p={model.p}, q={model.q}) on face/model, latched'
        )


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run face_tracking_ros learner``."""
    run_until_stopped('learner', LearnerNode, args, interrupt_start=True)


if __name__ == '__main__':
    main()
