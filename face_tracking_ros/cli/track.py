"""``face-tracking track BAG --out OUT``: track a recorded sequence, mono or stereo, offline.

The tracker is chosen from the bag's image topics (one: mono_tracker; a left and a right one:
stereo_tracker) and runs through :func:`face_tracking_ros.replay.replay_bag`, i.e. the node's own
code. When the bag holds synthetic truth, the accuracy against it is printed and, with
``--report``, written as JSON.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Mapping
import contextlib
from dataclasses import asdict
import json
from pathlib import Path
from typing import Protocol

import numpy as np

from face_tracking_ros.cli.replay import add_replay_options, parse_remaps, print_stats
from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import BagError, ConfigError, InputError
from face_tracking_ros.geometry.camera import PinholeCamera, StereoRig
from face_tracking_ros.io.bags import bag_topics, read_messages
from face_tracking_ros.io.conversions import camera_from_info
from face_tracking_ros.io.series import has_truth, load_states, load_truth
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.processing.mono import COMPRESSED_IMAGE, IMAGE, MonoNodeConfig
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.stereo import COMPRESSED as STEREO_COMPRESSED
from face_tracking_ros.processing.stereo import (
    LEFT_IMAGE,
    LEFT_INFO,
    RIGHT_IMAGE,
    RIGHT_INFO,
    StereoNodeConfig,
)
from face_tracking_ros.replay import bag_spelling, replay_bag
from face_tracking_ros.synthetic.clicks import clicks_from_bag, write_init_file
from face_tracking_ros.tracking.accuracy import (
    TrackingAccuracy,
    drift_window,
    tracking_accuracy,
)
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.tracking.stereo import StereoTrackerConfig
from face_tracking_ros.tracking.stereo_evaluation import StereoEvaluation, evaluate_stereo

IMAGE_TYPE = 'sensor_msgs/msg/Image'
COMPRESSED_TYPE = 'sensor_msgs/msg/CompressedImage'
CAMERA_INFO_TYPE = 'sensor_msgs/msg/CameraInfo'
NODE_CONFIGS = {'mono_tracker': MonoNodeConfig, 'stereo_tracker': StereoNodeConfig}


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``track`` subcommand."""
    parser = subparsers.add_parser(
        'track',
        help='track the face in a recorded bag (mono or stereo) and score it against truth',
        description='Run the mono or stereo tracker (chosen from the image topics) over a bag, '
        'write its outputs to a new bag, and print the accuracy when the bag has truth.',
    )
    parser.add_argument('bag', type=Path, help='input rosbag2 directory')
    parser.add_argument(
        '--model',
        type=Path,
        help='face model file (default: the packaged model for a mono bag; none for a stereo bag, '
        'whose tracker then gives meshes only: no pose, sigma or alpha)',
    )
    init = parser.add_mutually_exclusive_group()
    init.add_argument('--init', type=Path, help='init file: node names -> pixel positions')
    init.add_argument(
        '--simulate-clicks',
        type=float,
        metavar='PX',
        help="synthetic bags: initialise from the first frame's true nodes with PX pixels of "
        'click noise (the semi-automatic initialisation, simulated); writes OUT.init.json',
    )
    init.add_argument(
        '--auto-init',
        action='store_true',
        help='find the face with the optional landmark detector (the auto_init parameter; '
        'pip install dlib-bin face_recognition_models)',
    )
    parser.add_argument('--image-topic', help='mono image topic (default: found by type)')
    parser.add_argument('--camera-info-topic', help='mono camera_info topic')
    add_stereo_topic_options(parser)
    parser.add_argument('--report', type=Path, help='write the accuracy as JSON')
    add_replay_options(parser)
    parser.set_defaults(func=run)


def image_topics(topics: Mapping[str, str]) -> tuple[list[str], bool]:
    """A bag's image topics (name -> type given) and whether they are compressed.

    Its Image topics if it has any, else its CompressedImage ones (a bag recorded through
    image_transport's compressed plugin).
    """
    raw = [topic for topic, kind in topics.items() if kind == IMAGE_TYPE]
    if raw:
        return raw, False
    return [topic for topic, kind in topics.items() if kind == COMPRESSED_TYPE], True


def is_stereo_bag(topics: Mapping[str, str]) -> bool:
    """True if a bag's topics (name -> type) hold a left and a right image stream."""
    images, _ = image_topics(topics)
    return any('left' in t for t in images) and any('right' in t for t in images)


def check_one_transport(bag: Path, topics: Mapping[str, str]) -> None:
    """Refuse a bag whose left and right images come one as Image, one as CompressedImage.

    Raises:
        ConfigError: naming the two topics: the stereo tracker takes one transport for both.
    """
    images = {t: kind for t, kind in topics.items() if kind in (IMAGE_TYPE, COMPRESSED_TYPE)}
    left = {kind for t, kind in images.items() if 'left' in t}
    right = {kind for t, kind in images.items() if 'right' in t}
    if left and right and not left & right:
        named = ', '.join(f'{t} ({kind.rpartition("/")[2]})' for t, kind in images.items())
        msg = (
            f'{bag}: its left and right images come by different transports ({named}): the '
            'stereo tracker takes both as Image or both as CompressedImage'
        )
        raise ConfigError(msg)


def compressed_parameters(
    topics: Mapping[str, str], given: Iterable[str | None] = ()
) -> list[str]:
    """``['compressed=true']`` when the images to track are CompressedImage, else ``[]``.

    Args:
        topics: the bag's topics (name -> type).
        given: the image topics given on the command line (None: not given); their type
            decides, else the bag's (compressed if it has CompressedImage topics only).
    """
    chosen = [topics.get(bag_spelling(topic, topics)) for topic in given if topic]
    if chosen:
        compressed = chosen[0] == COMPRESSED_TYPE
    else:
        images, only_compressed = image_topics(topics)
        compressed = only_compressed and bool(images)
    return ['compressed=true'] if compressed else []


def input_remaps(topics: Mapping[str, str | None]) -> dict[str, str]:
    """Processor input -> bag topic, of the topics given (input name -> bag topic, or None).

    An image input's topic serves its ``/compressed`` input too (``compressed=true``).
    """
    remaps = {port: topic for port, topic in topics.items() if topic}
    compressed = {raw: port for port, raw in STEREO_COMPRESSED.items()} | {IMAGE: COMPRESSED_IMAGE}
    return remaps | {compressed[port]: remaps[port] for port in compressed.keys() & remaps.keys()}


class StereoTopicOptions(Protocol):
    """Options naming the stereo topics: ``track``'s arguments, or ``learn``'s LearnOptions."""

    left_topic: str | None
    right_topic: str | None
    left_info_topic: str | None
    right_info_topic: str | None


def stereo_topics(args: StereoTopicOptions) -> dict[str, str | None]:
    """The stereo_tracker inputs given as --left-topic, --right-topic and their camera_info's."""
    return {
        LEFT_IMAGE: args.left_topic,
        RIGHT_IMAGE: args.right_topic,
        LEFT_INFO: args.left_info_topic,
        RIGHT_INFO: args.right_info_topic,
    }


def add_stereo_topic_options(parser: argparse._ActionsContainer) -> None:
    """The --left-topic, --right-topic, --left-info-topic and --right-info-topic options."""
    parser.add_argument('--left-topic', help='stereo left image topic (default: found by type)')
    parser.add_argument('--right-topic', help='stereo right image topic')
    parser.add_argument('--left-info-topic', help='stereo left camera_info topic')
    parser.add_argument('--right-info-topic', help='stereo right camera_info topic')


def tracked_nodes(node: str, params: list[str], model_file: Path | None) -> tuple[str, ...]:
    """The nodes the chosen tracker tracks: its mesh's (stereo), its model's (mono).

    Args:
        node: 'stereo_tracker' or 'mono_tracker'.
        params: its parameters (``tracker.num_nodes`` for stereo), NAME=VALUE.
        model_file: the mono tracker's model file; None: the packaged one.
    """
    if node == 'stereo_tracker':
        config = OverrideParameters.parse(params).config(StereoTrackerConfig, prefix='tracker.')
        return mesh_topology(config.num_nodes).node_names
    return load_model(model_file or default_model_path()).node_names


def choose_tracker(bag: Path, args: argparse.Namespace) -> str:
    """'stereo_tracker' if the bag has a left and a right image topic, else 'mono_tracker'.

    Raises:
        BagError: if the bag has no image topic.
        ConfigError: if it has several, none given, and not a left and a right one by name, or
            a left and a right one of different transports.
    """
    topics = bag_topics(bag)
    images = image_topics(topics)[0]
    if not images:
        msg = f'{bag}: no sensor_msgs/msg/Image or CompressedImage topic to track'
        raise BagError(msg)
    if args.image_topic:
        return 'mono_tracker'
    if args.left_topic or is_stereo_bag(topics):
        return 'stereo_tracker'
    check_one_transport(bag, topics)
    if len(images) > 1:
        msg = (
            f'{bag}: image topics {", ".join(images)}, none named left or right: give one with '
            '--image-topic (mono tracker) or a pair with --left-topic, --right-topic, '
            '--left-info-topic and --right-info-topic (stereo tracker)'
        )
        raise ConfigError(msg)
    return 'mono_tracker'


def run(args: argparse.Namespace) -> int:
    """Track, summarise, and score against truth when there is some."""
    node = choose_tracker(args.bag, args)
    params, model_file = _parameters(args, node)
    print(f'tracking {args.bag} with {node}')
    options = {'image': args.image_topic, 'camera_info': args.camera_info_topic}
    remaps = {**parse_remaps(args.remap), **input_remaps({**options, **stereo_topics(args)})}
    stats = replay_bag(
        [node],
        args.bag,
        args.out,
        OverrideParameters.parse(params),
        remaps,
        args.record_inputs,
        progress=not args.quiet,
        wanted=frozenset(args.want),
    )
    print_stats(stats, args.out)
    states = load_states(args.out).status if stats.outputs['face/state'] else np.empty(0)
    if not np.any(states == TrackStatus.TRACKING):
        print('no image was tracked (the input problems or last_reason above say why)')
        return 1
    scored = has_truth(args.bag)
    if scored and stats.read_error:
        print('not scored against the truth: the bag is damaged (above)')
    elif scored:
        _score(args, node, model_file)
    return 1 if stats.interrupted or stats.read_error else 0


def _parameters(args: argparse.Namespace, node: str) -> tuple[list[str], Path | None]:
    """The tracker's parameters (NAME=VALUE) and its model file (None: the packaged one).

    The simulated clicks (``--simulate-clicks``) are written beside ``--out`` for the model's
    nodes, and given as ``init_file``.

    Raises:
        ConfigError: if nothing would initialise the track, or ``--out`` exists.
    """
    given = (args.image_topic, args.left_topic)
    params = [*compressed_parameters(bag_topics(args.bag), given), *(args.param or [])]
    if args.model:
        params.append(f'model_file={args.model}')
    node_config = OverrideParameters.parse(params).config(NODE_CONFIGS[node])
    model_file = Path(node_config.model_file) if node_config.model_file else None  # or --param
    given_init = node_config.init_file or node_config.auto_init
    if not (args.init or args.simulate_clicks is not None or args.auto_init or given_init):
        msg = (
            "nothing initialises the track: give the first image's node positions with --init "
            'FILE, --auto-init (the optional landmark detector) or, for synthetic bags, '
            '--simulate-clicks PX'
        )
        raise ConfigError(msg)
    if args.out.exists():
        msg = f'--out {args.out} exists: give a new directory for the tracked bag'
        raise ConfigError(msg)
    init_file = args.init
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if args.simulate_clicks is not None:
        init_file = args.out.parent / f'{args.out.name}.init.json'
        clicks = clicks_from_bag(args.bag, args.simulate_clicks)
        write_init_file(clicks.only(tracked_nodes(node, params, model_file)), init_file)
    if init_file:
        params.append(f'init_file={init_file}')
    if args.auto_init:
        params.append('auto_init=true')
    return params, model_file


def _score(args: argparse.Namespace, node: str, model_file: Path | None) -> None:
    """Print the accuracy of the tracked bag against the truth, and write it to ``--report``."""
    if node == 'stereo_tracker':
        evaluation = score_stereo_against_truth(args.bag, args.out)
        print(evaluation.report())
        report = asdict(evaluation)
    else:
        accuracy = score_against_truth(args.bag, args.out, model_file)
        print(format_accuracy(accuracy))
        report = accuracy.as_dict()
    if args.report:
        args.report.write_text(json.dumps(report, indent=2))


def score_stereo_against_truth(bag: Path, out: Path) -> StereoEvaluation:
    """Stereo-tracked meshes in ``out`` against the truth in ``bag`` (issue 5's figures).

    The errors are over the frames from the first tracked one on: before it there is no
    estimate (the published nodes are zeros); a frame lost later counts with the last estimate,
    which is what the node publishes.

    Raises:
        BagError: if no frame was tracked.
    """
    states, truth = load_states(out), load_truth(bag)
    est, ref = _matching_frames(states.stamps, truth.stamps, bag, out)
    tracked = states.status[est] == TrackStatus.TRACKING
    if not tracked.any():
        msg = f'{out}: no frame was tracked'
        raise BagError(msg)
    since = int(np.argmax(tracked))
    est, ref = est[since:], ref[since:]
    nodes = states.nodes[est]
    return evaluate_stereo(
        nodes,
        truth.nodes[ref][:, : nodes.shape[1]],
        stereo_rig(bag),
        mesh_topology(nodes.shape[1]),
        states.status[est],
    )


def stereo_rig(bag: Path) -> StereoRig:
    """The rig of a stereo bag, from the first valid left and right camera_info.

    Raises:
        BagError: if the bag lacks them.
        InputError: if they do not form a rectified rig.
    """
    cameras: dict[str, PinholeCamera | None] = {
        topic: None for topic, kind in bag_topics(bag).items() if kind == CAMERA_INFO_TYPE
    }
    for message in read_messages(bag, topics=list(cameras)):
        if cameras[message.topic] is None:
            with contextlib.suppress(InputError):  # e.g. an all-zero K: the tracker skips it too
                cameras[message.topic] = camera_from_info(message.msg)
        if all(cameras.values()):
            break
    left = next((c for t, c in cameras.items() if 'left' in t and c is not None), None)
    right = next((c for t, c in cameras.items() if 'right' in t and c is not None), None)
    if left is None or right is None:
        msg = f'{bag}: no valid left and right camera_info to build the stereo rig'
        raise BagError(msg)
    return StereoRig(left, right)


def _matching_frames(
    stamps: np.ndarray, truth_stamps: np.ndarray, bag: Path, out: Path
) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the output frames and of the truth frames with the same stamps.

    Raises:
        BagError: if no output frame has a truth frame of the same stamp.
    """
    index = {int(stamp): i for i, stamp in enumerate(truth_stamps)}
    rows = [(i, index[int(s)]) for i, s in enumerate(stamps) if int(s) in index]
    if not rows:
        msg = f'{out}: no output frame has a truth frame of the same stamp in {bag}'
        raise BagError(msg)
    est, ref = np.array(rows).T
    return est, ref


def score_against_truth(bag: Path, out: Path, model_file: Path | None) -> TrackingAccuracy:
    """Accuracy of the mono FaceState outputs in ``out`` against the truth in ``bag``."""
    model = load_model(model_file or default_model_path())
    states, truth = load_states(out), load_truth(bag)
    est, ref = _matching_frames(states.stamps, truth.stamps, bag, out)
    return tracking_accuracy(
        model,
        states.status[est],
        states.omega[est],
        states.t[est],
        states.alpha[est],
        states.nodes[est],
        truth.nodes[ref][:, : model.num_nodes],
    )


def format_accuracy(accuracy: TrackingAccuracy) -> str:
    """A short table of the accuracy figures."""
    rotation = ' / '.join(f'{v:.2f}' for v in accuracy.rotation_mae_deg)
    translation = ' / '.join(f'{v:.2f}' for v in accuracy.translation_mae_mm)
    window = drift_window(accuracy.tracked)
    drift = f'drift (last {window} - first {window}):'
    return '\n'.join(
        [
            f'frames {accuracy.frames}: tracked {accuracy.tracked}, lost {accuracy.lost}',
            f'rotation MAE about x / y / z:    {rotation} deg',
            f'translation MAE in x / y / z:    {translation} mm',
            f'3-D node RMS:                    {accuracy.node_rms_mm:.2f} mm',
            f'alpha RMS (% of range):          {accuracy.alpha_rms_percent:.1f} %',
            f'{drift:<33}{accuracy.drift_deg:+.3f} deg',
            f'jitter (frame-to-frame):         {accuracy.jitter_deg:.3f} deg',
        ]
    )
