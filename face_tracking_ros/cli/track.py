"""``face-tracking track BAG --out OUT``: track a recorded sequence, mono or stereo, offline.

The tracker is chosen from the bag's image topics (one: mono_tracker; a left and a right one:
stereo_tracker) and runs through :func:`face_tracking_ros.replay.replay_bag`, i.e. the node's own
code. When the bag holds synthetic truth, the accuracy against it is printed and, with
``--report``, written as JSON. The topic discovery and replay inputs
(:mod:`face_tracking_ros.pipelines.bag_inputs`) and the scoring
(:mod:`face_tracking_ros.pipelines.scoring`) are shared with ``face-tracking learn``.
"""

from __future__ import annotations

import argparse
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import asdict
import json
import math
from pathlib import Path

from face_tracking_ros.cli.replay import add_replay_options, parse_remaps, print_stats
from face_tracking_ros.errors import BagError, ConfigError
from face_tracking_ros.io.atomic import check_output_path, write_json_atomically
from face_tracking_ros.io.bags import bag_topics
from face_tracking_ros.io.conversions import COMPRESSED_IMAGE_TYPE, IMAGE_TYPE
from face_tracking_ros.io.series import holds_truth
from face_tracking_ros.pipelines.bag_inputs import (
    check_one_transport,
    check_stereo_topics,
    clicked_camera_topic,
    compressed_parameters,
    image_topics,
    input_remaps,
    is_stereo_bag,
    stereo_remaps,
    tracked_nodes,
)
from face_tracking_ros.pipelines.scoring import score_against_truth, score_stereo_against_truth
from face_tracking_ros.processing.base import Output
from face_tracking_ros.processing.node_configs import MonoNodeConfig, StereoNodeConfig
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.track_status import STATE_PORT
from face_tracking_ros.replay import ReplayStats, replay_bag, wire_replay
from face_tracking_ros.synthetic.clicks import (
    check_clicks_file,
    clicks_from_bag,
    write_init_file,
)
from face_tracking_ros.tracking.result import TrackStatus

STEREO = 'stereo_tracker'
NODE_CONFIGS = {'mono_tracker': MonoNodeConfig, STEREO: StereoNodeConfig}


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``track`` subcommand's options."""
    parser.description = (
        'Run the mono or stereo tracker (chosen from the image topics) over a bag, '
        'write its outputs to a new bag, and print the accuracy when the bag has truth.'
    )
    parser.add_argument('bag', type=Path, help='input bag: a rosbag2 directory or one .mcap file')
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
        help="synthetic bags: initialise from the first frame's true nodes with PX >= 0 pixels "
        'of click noise (the semi-automatic initialisation, simulated); writes OUT.init.json '
        '(replacing an init file there, never another file)',
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


def add_stereo_topic_options(parser: argparse._ActionsContainer) -> None:
    """The --left-topic, --right-topic, --left-info-topic and --right-info-topic options."""
    parser.add_argument(
        '--left-topic',
        help='stereo left image topic (default: the one whose name ends in left/image_raw, '
        "or left/image_raw/compressed, else the only one with the word 'left' and not 'right' in "
        'its name)',
    )
    parser.add_argument('--right-topic', help='stereo right image topic')
    parser.add_argument('--left-info-topic', help='stereo left camera_info topic')
    parser.add_argument('--right-info-topic', help='stereo right camera_info topic')


def choose_tracker(bag: Path, topics: dict[str, str], args: argparse.Namespace) -> str:
    """'stereo_tracker' if the bag has a left and a right image topic, else 'mono_tracker'.

    Raises:
        BagError: if the bag has no image topic.
        ConfigError: if it has several, none given, and not a left and a right one by name, or
            a left and a right one of different transports.
    """
    images = image_topics(topics)[0]
    if not images:
        msg = f'{bag}: no sensor_msgs/msg/Image or CompressedImage topic to track'
        raise BagError(msg)
    if args.image_topic:
        return 'mono_tracker'
    if args.left_topic or is_stereo_bag(topics):
        return STEREO
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
    """Track, summarise, and score against truth when there is some.

    Raises:
        ConfigError: for options out of range or that do not fit the bag (a negative
            ``--simulate-clicks``, an unusable ``--out`` or ``--report``, topics or parameters
            the tracker cannot use).
        BagError: if the bag is unreadable or has no image topics to track.
    """
    noise = args.simulate_clicks
    if noise is not None and not (math.isfinite(noise) and noise >= 0):
        msg = f'--simulate-clicks must be a finite number of pixels >= 0 (0: exact), got {noise}'
        raise ConfigError(msg)
    check_output_path(args.out, '--out', directory=True)
    if args.report is not None:
        check_output_path(args.report, '--report')
    topics = bag_topics(args.bag)
    node = choose_tracker(args.bag, topics, args)
    given = parse_remaps(args.remap)
    params, model_file, compressed = _parameters(args, node, topics, given)
    print(f'tracking {args.bag} with {node}')
    remaps = _remaps(args, node, topics, compressed, given)
    wanted = frozenset(args.want)
    if args.simulate_clicks is not None:  # a replay it refuses leaves no clicks written
        _, read = wire_replay(
            [node], args.bag, OverrideParameters.parse(params), remaps, wanted, topics
        )
        camera_info = clicked_camera_topic(read, node)
        params.append(f'init_file={_write_clicks(args, node, params, model_file, camera_info)}')
    statuses: Counter[int] = Counter()
    stats = replay_bag(
        [node],
        args.bag,
        args.out,
        OverrideParameters.parse(params),
        remaps,
        args.record_inputs,
        progress=not args.quiet,
        on_output=_status_counter(statuses),
        wanted=wanted,
        topics=topics,
    )
    print_stats(stats, args.out)
    if not statuses[TrackStatus.TRACKING]:
        print(_nothing_tracked(node, stats, topics))
        return 1
    scored = holds_truth(topics)
    if scored and stats.read_error:
        print('not scored against the truth: the bag is damaged (above)')
    elif scored:
        _score(args, node, model_file)
    return 1 if stats.interrupted or stats.read_error else 0


def _status_counter(statuses: Counter[int]) -> Callable[[Output, int], None]:
    """A replay's ``on_output`` that counts its ``face/state`` outputs by status into ``statuses``.

    What the track tracked, known as it is written: read back from the output bag, the states
    took 0.22 s of a 900-image track (read again to be scored).
    """

    def count(output: Output, _log_time: int) -> None:
        if output.topic == STATE_PORT.topic:
            statuses[int(output.msg.status)] += 1

    return count


def _nothing_tracked(node: str, stats: ReplayStats, topics: Mapping[str, str]) -> str:
    """Why ``node`` tracked no image: none on (one of) its image topics, or the summary above.

    Args:
        node: the tracker.
        stats: its replay over the bag.
        topics: the bag's topics (name -> type).
    """
    frame = 'pair' if node == STEREO else 'image'
    images = [
        topic
        for topic in stats.read_topics
        if topics[topic] in (IMAGE_TYPE, COMPRESSED_IMAGE_TYPE)
    ]
    empty = [topic for topic in images if not stats.inputs[stats.read_topics[topic]]]
    if not empty or stats.read_error or stats.interrupted:
        return f'no {frame} was tracked (the input problems or last_reason above say why)'
    fed = [topic for topic in images if topic not in empty]
    unpaired = f', so no image on {", ".join(fed)} had its pair' if fed else ''
    kind = 'image topic' if len(images) == 1 else 'image topics'
    return (
        f'no {frame} was tracked: the bag holds no message on {", ".join(empty)}, '
        f'{"the" if len(empty) == len(images) else "one of the"} {kind} the {node} '
        f'reads{unpaired}'
    )


def _parameters(
    args: argparse.Namespace, node: str, topics: dict[str, str], remaps: dict[str, str]
) -> tuple[list[str], Path | None, bool]:
    """The tracker's parameters (NAME=VALUE), model file (None: packaged) and image transport.

    The last is True if the tracker reads compressed images. The stereo tracker's inputs are
    checked here, ``remaps`` (``--remap``, parsed) over those found. Where the simulated clicks
    (``--simulate-clicks``) go is only checked here: :func:`_write_clicks` writes them once the
    replay is checked.

    Raises:
        ConfigError: if nothing would initialise the track, ``--out`` exists, or the clicks or
            ``--report`` would be written over an input or a file of another kind.
    """
    _check_given_once(args)
    given = (args.image_topic, args.left_topic)
    params = [*compressed_parameters(topics, given), *(args.param or [])]
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
    if node == STEREO:
        if args.camera_info_topic:
            msg = (
                f'--camera-info-topic {args.camera_info_topic} is for the mono tracker; the '
                'stereo tracker takes --left-info-topic and --right-info-topic'
            )
            raise ConfigError(msg)
        check_stereo_topics(args.bag, topics, args, node_config.compressed, remaps)
    inputs = [Path(path) for path in (args.init, model_file, node_config.init_file) if path]
    init_file = args.init
    if args.simulate_clicks is not None:
        init_file = _clicks_file(args.out)
        _check_clicks_file(init_file, inputs)
    _check_report(args.report, [*inputs, *([init_file] if init_file else [])])
    if args.init:
        params.append(f'init_file={args.init}')
    if args.auto_init:
        params.append('auto_init=true')
    return params, model_file, node_config.compressed


def _clicks_file(out: Path) -> Path:
    """Where the simulated clicks of a track into ``out`` go: OUT.init.json beside it."""
    return out.parent / f'{out.name}.init.json'


def _write_clicks(
    args: argparse.Namespace,
    node: str,
    params: list[str],
    model_file: Path | None,
    camera_info: str | None,
) -> Path:
    """Write the simulated clicks (``--simulate-clicks``) of the tracker's nodes; their file.

    Args:
        args: the command's arguments.
        node: the tracker.
        params: its parameters (NAME=VALUE).
        model_file: its model file; None: the packaged one.
        camera_info: the camera_info topic the tracker reads for the camera it is initialised
            in (the stereo tracker's left one).
    """
    clicks = clicks_from_bag(args.bag, args.simulate_clicks, camera_info=camera_info)
    path = _clicks_file(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)  # as --out's
    return write_init_file(clicks.only(tracked_nodes(node, params, model_file)), path)


def _remaps(
    args: argparse.Namespace,
    node: str,
    topics: dict[str, str],
    compressed: bool,
    remaps: dict[str, str],
) -> dict[str, str]:
    """Tracker input -> bag topic: ``remaps`` (``--remap``, parsed), then the topic options.

    The stereo tracker's inputs not given are found by side (:func:`stereo_remaps`).
    """
    if node == STEREO:
        return stereo_remaps(topics, args, compressed, remaps)
    options = {'image': args.image_topic, 'camera_info': args.camera_info_topic}
    return {**remaps, **input_remaps(options, compressed)}


def _check_given_once(args: argparse.Namespace) -> None:
    """Refuse an init file or model given both by its option and by ``--param``.

    One of the two would be used without a word (the later one).

    Raises:
        ConfigError: naming both.
    """
    overrides = OverrideParameters.parse(args.param).overrides
    init = (
        '--init' if args.init else '--simulate-clicks' if args.simulate_clicks is not None else ''
    )
    options = {'init_file': init, 'model_file': '--model' if args.model else ''}
    for name, option in options.items():
        if option and name in overrides:
            msg = f'{option} and --param {name}={overrides[name]} both give the {name}: give one'
            raise ConfigError(msg)


def _check_clicks_file(path: Path, inputs: list[Path]) -> None:
    """Refuse to write the simulated clicks over an input or a file that is not an init file.

    An init file there (an earlier run's clicks) is replaced, as ``learn`` replaces a model.

    Raises:
        ConfigError: naming the file: it would be written over.
    """
    _refuse_input(path, f'--simulate-clicks: {path} (where the clicks go)', inputs)
    check_clicks_file(path, '--simulate-clicks:')


def _refuse_input(path: Path, named: str, inputs: list[Path]) -> None:
    """Refuse to write ``path`` (``named`` so in the message) if it is one of ``inputs``.

    Raises:
        ConfigError: it would be written over.
    """
    if any(path.resolve() == given.resolve() for given in inputs):
        msg = f'{named} is an input of this track (model or init file): not written over'
        raise ConfigError(msg)


def _check_report(report: Path | None, inputs: list[Path]) -> None:
    """Refuse a ``--report`` that is an input (the model, the init file) or not a JSON file.

    Raises:
        ConfigError: naming the file: it would be written over.
    """
    if report is None:
        return
    _refuse_input(report, f'--report {report}', inputs)
    if report.is_file():
        try:
            json.loads(report.read_text())
        except (UnicodeDecodeError, ValueError):
            msg = f'--report {report} exists and is not a JSON report: not written over'
            raise ConfigError(msg) from None


def _score(args: argparse.Namespace, node: str, model_file: Path | None) -> None:
    """Print the accuracy of the tracked bag against the truth, and write it to ``--report``."""
    if node == STEREO:
        evaluation = score_stereo_against_truth(args.bag, args.out)
        print(evaluation.report())
        report = asdict(evaluation)
    else:
        accuracy = score_against_truth(args.bag, args.out, model_file)
        print(accuracy.report())
        report = accuracy.as_dict()
    if args.report:
        args.report.parent.mkdir(parents=True, exist_ok=True)  # as --out's
        write_json_atomically(args.report, report)
