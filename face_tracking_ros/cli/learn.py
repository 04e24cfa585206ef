"""``face-tracking learn``: learn a face model from bags of 3-D meshes and report its quality.

Input bags hold one of:

* ``face_tracking_msgs/FaceTruth`` (synthetic truth, default topic ``truth/face``): nodes in the
  camera frame, subject id and expression label per frame; frames labelled 'neutral' are the
  neutral frames of §3.4;
* ``face_tracking_msgs/FaceMesh`` or ``FaceState`` (a tracker's meshes): subject, label and
  alpha come from ``--truth`` bags (matched by header stamp) when given; otherwise the subject is
  ``--subject`` or the bag's directory name and the first ``--neutral-frames`` frames of each
  bag are taken as neutral;
* raw stereo images (left and right Image and CameraInfo): first tracked by the stereo tracker
  into FaceMesh bags (:func:`mesh_bag`), every mesh with the frame-1 depths refined over its
  whole track.

The meshes are aligned (§3.3), the model is learned by ``--method`` (default ``joint``, issue 11;
``seed`` is the paper's §3.4), the evaluation of :mod:`face_tracking_ros.learning.evaluation`
runs for every compared method, and the command writes the model file, a JSON report and, with
``--plots``, PNG figures (Figure 5-like sigma scatter per method, comparison, convergence).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass, replace
import json
from pathlib import Path
import re
import shutil
import time
from typing import Any

import numpy as np

from face_tracking_ros.cli.replay import print_stats
from face_tracking_ros.cli.track import (
    CAMERA_INFO_TYPE,
    add_stereo_topic_options,
    check_one_transport,
    compressed_parameters,
    image_topics,
    input_remaps,
    is_stereo_bag,
    score_stereo_against_truth,
    stereo_topics,
    tracked_nodes,
)
from face_tracking_ros.errors import BagError, ConfigError, FaceTrackingError, InputError
from face_tracking_ros.io.bags import bag_topics, read_messages
from face_tracking_ros.io.conversions import (
    TruthSample,
    points_to_array,
    stamp_to_ns,
    truth_from_msg,
)
from face_tracking_ros.io.provenance import Provenance, other_source
from face_tracking_ros.io.series import has_truth
from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.evaluation import (
    Evaluation,
    TrueSubspaces,
    comparison_table,
    evaluate,
    population_truth,
)
from face_tracking_ros.learning.methods import (
    DEFAULT_EXPLAINED_VARIANCE,
    DEFAULT_METHOD,
    METHODS,
    make_learner,
)
from face_tracking_ros.learning.plots import (
    plot_comparison,
    plot_convergence,
    plot_sigma_scatter,
)
from face_tracking_ros.learning.result import LearningResult
from face_tracking_ros.learning.training_set import MeshSequence, TrainingSet
from face_tracking_ros.model.model_file import save_model
from face_tracking_ros.model.topology import SUPPORTED_NODE_COUNTS
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.replay import bag_spelling, replay_bag
from face_tracking_ros.synthetic.clicks import clicks_from_bag, write_init_file
from face_tracking_ros.synthetic.faces import PRESETS, FacePopulation
from face_tracking_ros.tracking.result import TrackStatus

TRUTH_TYPE = 'face_tracking_msgs/msg/FaceTruth'
MESH_TYPES = ('face_tracking_msgs/msg/FaceMesh', 'face_tracking_msgs/msg/FaceState')
TRUTH_TOPIC = 'truth/face'
STATE_TOPIC = 'face/state'
TRACKED = int(TrackStatus.TRACKING)  # FaceState.STATUS_TRACKING
DEFAULT_TOPICS = (TRUTH_TOPIC, 'face/mesh_raw', STATE_TOPIC)
STEREO_PARAMS = 'retroactive_depths=true'  # learn from meshes with each track's final depths
TRACKER = 'stereo_tracker'


@dataclass(frozen=True)
class BagMeshes:
    """Meshes of one subject read from one bag.

    Attributes:
        sequence: the meshes, neutral flags and labels.
        alpha: (F, E) true alpha when the bag holds truth, else None.
        sigma: the subject's true sigma when the bag holds truth, else None.
    """

    sequence: MeshSequence
    alpha: np.ndarray | None
    sigma: np.ndarray | None = None


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``learn`` subcommand."""
    parser = subparsers.add_parser(
        'learn',
        help='learn a face model (mean shape, S, A, prior) from bags of 3-D meshes',
        description='Align 3-D training meshes (§3.3), learn mean shape, identity basis S, '
        'expression basis A and their Gaussian prior, evaluate the methods side by side '
        '(leave-one-subject-out, truth), write the model file, a JSON report and PNG plots.',
    )
    parser.add_argument('bags', nargs='+', type=Path, metavar='BAG', help='bags of meshes')
    parser.add_argument('--out', required=True, type=Path, help='model file to write (.npz)')
    parser.add_argument('--report', required=True, type=Path, help='JSON report to write')
    parser.add_argument('--nodes', type=int, choices=SUPPORTED_NODE_COUNTS, help='mesh nodes')
    parser.add_argument('--p', type=int, default=2, help='identity dimension (%(default)s)')
    parser.add_argument(
        '--explained-variance',
        type=float,
        help='choose p as the fewest identity modes explaining this share (overrides --p)',
    )
    parser.add_argument('--q', type=int, default=5, help='expression dimension (%(default)s)')
    parser.add_argument(
        '--method',
        choices=METHODS,
        default=DEFAULT_METHOD,
        help='learner whose model is written: joint (issue 11), seed (the paper, §3.4), '
        'seed-weighted (§4.3); default %(default)s',
    )
    parser.add_argument(
        '--compare',
        nargs='*',
        choices=METHODS,
        default=list(METHODS),
        help='methods to evaluate side by side (default: all; none: only --method)',
    )
    parser.add_argument('--plots', type=Path, help='directory receiving PNG figures')
    parser.add_argument('--topic', help=f'mesh topic (default: first of {DEFAULT_TOPICS})')
    parser.add_argument(
        '--subject',
        help='subject id of every bag without truth (FaceMesh, FaceState, raw stereo images)',
    )
    parser.add_argument(
        '--subject-pattern',
        metavar='REGEX',
        help='bags without truth: the subject id is the first group of REGEX matched against '
        "the bag's directory name (default: the whole name), e.g. '(.+)_\\d+' makes anna_1 "
        'and anna_2 two recordings of anna',
    )
    parser.add_argument(
        '--truth',
        nargs='+',
        type=Path,
        metavar='TRUTH_BAG',
        help='one bag per BAG, in the same order, whose truth/face messages label the meshes '
        'of the same stamp (subject, expression, alpha): e.g. the synthetic bags a tracker ran '
        'on (a mesh bag that records which bag it was tracked from must be paired with that one)',
    )
    parser.add_argument(
        '--neutral-frames',
        type=int,
        default=0,
        help='bags without truth (FaceMesh, FaceState, raw stereo images): the first K frames '
        'of each bag show the neutral face; required for them',
    )
    parser.add_argument(
        '--add-noise',
        type=float,
        default=0.0,
        help='white noise added to every node coordinate, m (e.g. 0.0005 for the issue-4 '
        'protocol on exact truth meshes); seeded by --seed',
    )
    parser.add_argument('--seed', type=int, default=0, help='seed of --add-noise')
    parser.add_argument(
        '--truth-population',
        metavar='PRESET[:SEED]',
        help=f'synthetic population of the bags ({", ".join(PRESETS)}) and the seed synth '
        'rendered them with (default 0): adds the comparison with the true subspaces to the '
        'report',
    )
    parser.add_argument(
        '--truth-samples',
        type=int,
        default=2000,
        help='population faces drawn to estimate the true identity axes (%(default)s)',
    )
    stereo = parser.add_argument_group(
        'raw stereo bags', 'bags of left/right images are first tracked by the stereo tracker'
    )
    stereo.add_argument(
        '--from-images',
        action='store_true',
        help='track the images of stereo bags even when they also hold truth meshes',
    )
    stereo.add_argument(
        '--init-dir',
        type=Path,
        help='directory of init files <bag name>.yaml|.json (node name -> left-image pixels)',
    )
    stereo.add_argument(
        '--simulate-clicks',
        type=float,
        metavar='PX',
        help="synthetic bags: initialise from the first frame's true nodes with PX pixels of "
        'click noise (written to --init-dir, default: <meshes dir>_clicks/)',
    )
    stereo.add_argument(
        '--auto-init',
        action='store_true',
        help='bags without an init file in --init-dir: find the face with the optional landmark '
        'detector (pip install dlib-bin face_recognition_models)',
    )
    add_stereo_topic_options(stereo)
    stereo.add_argument(
        '--meshes-dir',
        type=Path,
        help='where the tracked mesh bags go (default: <report name>_meshes/ beside the report)',
    )
    stereo.add_argument(
        '--tracker-param',
        action='append',
        metavar='NAME=VALUE',
        help='a stereo_tracker parameter, as the node declares it; repeatable. Default: '
        f"{STEREO_PARAMS} (each track's final depths on all its meshes)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    """Read, align, learn, evaluate, write."""
    _check_arguments(args)
    initialisations = {  # every raw bag's, before minutes of tracking
        bag: _initialisation(bag, args)
        for bag in args.bags
        if needs_tracking(bag, bag_topics(bag), args)
    }
    rng = np.random.default_rng(args.seed)
    truth_bags = args.truth or [None] * len(args.bags)
    mesh_bags = [mesh_bag(bag, args, initialisations.get(bag)) for bag in args.bags]
    truth_bags = [
        bag if mesh is not bag and has_truth(bag) else truth
        for bag, mesh, truth in zip(args.bags, mesh_bags, truth_bags, strict=True)
    ]
    _check_truth_pairs(mesh_bags, truth_bags)
    bag_meshes = [
        item
        for bag, mesh, truth_bag in zip(args.bags, mesh_bags, truth_bags, strict=True)
        for item in read_bag_meshes(mesh, args, truth_bag, bag.name)
    ]
    sequences = [item.sequence for item in bag_meshes]
    if args.add_noise > 0.0:
        sequences = [_with_noise(sequence, args.add_noise, rng) for sequence in sequences]
    training = TrainingSet.from_sequences(sequences)
    print(
        f'read {len(training.meshes)} meshes of {training.num_nodes} nodes, '
        f'{training.num_subjects} subjects, {int(training.neutral.sum())} neutral frames'
    )
    start = time.perf_counter()
    aligned = align_training_set(training)
    align_seconds = time.perf_counter() - start
    truth = _truth(args, aligned, bag_meshes)
    share = args.explained_variance
    p = args.p if share is None else None
    methods = list(dict.fromkeys([args.method, *args.compare]))
    results: dict[str, LearningResult] = {}
    evaluations: dict[str, Evaluation] = {}
    report_methods: dict[str, Any] = {}
    for method in methods:
        learner = make_learner(method, p, args.q, share or DEFAULT_EXPLAINED_VARIANCE)
        start = time.perf_counter()
        results[method] = learner(aligned)
        learn_seconds = time.perf_counter() - start
        print(f'{method}: learned in {learn_seconds:.3f} s, evaluating (leave one subject out)')
        evaluation, loo, _ = evaluate(aligned, learner, results[method], truth)
        if loo.skipped:
            print(f'{method}: no leave-one-subject-out figures: {loo.skipped}')
        evaluations[method] = evaluation
        report_methods[method] = {
            **evaluation.as_dict(),
            'learn_seconds': learn_seconds,
            'history': results[method].history.tolist(),
            'loo_per_subject': {
                'subjects': list(aligned.subject_ids),
                'shape_similarity': loo.shape_similarity.tolist(),
                'action_similarity': loo.action_similarity.tolist(),
                'mean_variation_percent': loo.mean_variation_percent.tolist(),
                'neutral_rms_mm': loo.neutral_rms_mm.tolist(),
                'p': [int(dim) if np.isfinite(dim) else None for dim in loo.p],
            },
        }
    print(comparison_table(evaluations))
    model = results[args.method].model
    metadata = {**model.metadata, 'bags': [str(bag) for bag in args.bags]}
    saved = save_model(replace(model, metadata=metadata), args.out)
    print(f'model ({args.method}, p={model.p}, q={model.q}) written to {saved}')
    plots = _plots(args.plots, aligned, results, evaluations) if args.plots else []
    report = {
        'model': str(saved),
        'method': args.method,
        'bags': [str(bag) for bag in args.bags],
        'subjects': list(aligned.subject_ids),
        'frames': len(aligned.meshes),
        'nodes': aligned.num_nodes,
        'align_seconds': align_seconds,
        'methods': report_methods,
        'plots': [str(path) for path in plots],
    }
    _write_json(args.report, report)
    print(f'report written to {args.report}')


def mesh_bag(bag: Path, args: argparse.Namespace, initialisation: str | None = None) -> Path:
    """The bag of 3-D meshes to learn from: ``bag`` itself, or its stereo tracking.

    A raw stereo bag (left and right images, Image or CompressedImage, found by their names or
    given as ``--left-topic`` and ``--right-topic``; no mesh topic, or any stereo bag with
    ``--from-images``) is first tracked by the stereo tracker (eq. 4, 5) through offline replay
    of the stereo_tracker node's own code, into ``--meshes-dir``; it is initialised from
    ``--init-dir/<bag name>.{yaml,json}``, ``--auto-init`` or, for synthetic bags,
    ``--simulate-clicks``. By default every mesh carries the frame-1 depths refined over its
    whole track (the processor's ``retroactive_depths``); ``--tracker-param`` overrides it.
    ``initialisation`` is that stereo_tracker parameter when already known
    (:func:`_initialisation`). Meshes an earlier run tracked from the same inputs are re-used
    (:func:`_tracked_before`).

    Raises:
        ConfigError: for a raw stereo bag without a way to initialise it, or one that
            :func:`needs_tracking` refuses.
        BagError: if the tracker produced no mesh (the input problems named).
    """
    topics = bag_topics(bag)
    if not needs_tracking(bag, topics, args):
        return bag  # meshes (or nothing: read_bag_meshes names the missing topic)
    initialisation = initialisation or _initialisation(bag, args)
    out = _meshes_dir(args) / bag.name
    compressed = compressed_parameters(topics, [args.left_topic])
    params = OverrideParameters.parse(
        [STEREO_PARAMS, *compressed, *(args.tracker_param or []), initialisation]
    )
    remaps = input_remaps(stereo_topics(args))
    if _tracked_before(out, Provenance.of(bag, [TRACKER], params.overrides, remaps)):
        return out
    print(f'{bag}: raw stereo images: tracking them into {out}')
    stats = replay_bag([TRACKER], bag, out, params, remaps, progress=False)
    if stats.interrupted:  # the meshes so far stay, and a later run tracks the bag again
        raise KeyboardInterrupt
    print_stats(stats, out)
    if not stats.outputs['face/mesh_raw']:
        shutil.rmtree(out)  # nothing to learn from, and a later run must track it again
        problems = '; '.join(f'{count}x {error}' for error, count in stats.errors.items())
        msg = f'{bag}: the stereo tracker produced no mesh ({problems or "no input problem"})'
        if stats.errors and all('no calibration' in error for error in stats.errors):
            infos = [topic for topic, kind in topics.items() if kind == CAMERA_INFO_TYPE]
            msg += (
                '; give the camera_info topics with --left-info-topic and --right-info-topic '
                f'(the bag has {", ".join(infos) or "none"})'
            )
        raise BagError(msg)
    if has_truth(bag):
        _print_score(bag, out)
    return out


def _print_score(bag: Path, out: Path) -> None:
    """Print how the meshes tracked into ``out`` compare with the truth in ``bag``."""
    try:
        evaluation = score_stereo_against_truth(bag, out)
    except FaceTrackingError as error:  # e.g. camera_info topics not named left / right
        print(f'{out}: not scored against the truth of {bag}: {error}')
        return
    print(f'{out} against the truth of {bag}: {evaluation.report()}')


def needs_tracking(bag: Path, topics: dict[str, str], args: argparse.Namespace) -> bool:
    """Whether ``bag`` (of ``topics``) is a raw stereo bag that :func:`mesh_bag` tracks.

    Raises:
        ConfigError: for a bag of images whose stereo pair is not found by name (and not given)
            while there are no meshes to learn from or ``--from-images`` asks for tracking, or
            for two raw stereo bags of one name.
    """
    has_meshes = args.topic or _mesh_topic(topics, args) is not None
    if not (is_stereo_bag(topics) or args.left_topic):
        images, _ = image_topics(topics)
        if args.from_images or (images and not has_meshes):
            check_one_transport(bag, topics)
            msg = (
                f'{bag}: no stereo pair found by name among its image topics '
                f'({", ".join(images) or "none"}): the left and right topics need "left" and '
                '"right" in their names, else give --left-topic, --right-topic, '
                '--left-info-topic and --right-info-topic'
            )
            raise ConfigError(msg)
        return False
    if has_meshes and not args.from_images:
        return False
    namesakes = [other for other in args.bags if other.name == bag.name and other != bag]
    if namesakes:
        msg = (
            f'{bag} and {namesakes[0]} are both named {bag.name}: the init files and tracked '
            'meshes of raw stereo bags are named after the bag, so rename one (--subject-pattern '
            'can still give both the same subject)'
        )
        raise ConfigError(msg)
    return True


def _tracked_before(out: Path, inputs: Provenance) -> bool:
    """Whether ``out`` holds meshes an earlier run tracked from these inputs, to re-use.

    An earlier tracking of the same bag from other inputs, one that did not finish, or one
    whose bag was never closed (no metadata.yaml: the process was killed) is removed, to be
    tracked again.

    Raises:
        ConfigError: if ``out`` exists but is not such a tracking (not ours to remove).
    """
    if not out.exists():
        return False
    files = list(out.iterdir()) if out.is_dir() else []
    if files and all(file.suffix == '.mcap' for file in files):  # a writer killed before closing
        print(f'{out}: an earlier run was stopped before it closed the bag: tracking again')
        shutil.rmtree(out)
        return False
    earlier = Provenance.read(out)
    if earlier is None or earlier.source != inputs.source:
        msg = (
            f'{out} exists and is not a tracking of {inputs.source} by learn: remove it or give '
            'another --meshes-dir'
        )
        raise ConfigError(msg)
    if earlier.complete and earlier.same_inputs(inputs):
        print(f'{out}: re-using the meshes an earlier run tracked from the same inputs')
        return True
    why = 'did not finish' if earlier.same_inputs(inputs) else 'tracked it from other inputs'
    print(f'{out}: an earlier run {why}: tracking again')
    shutil.rmtree(out)
    return False


def _check_truth_pairs(mesh_bags: Sequence[Path], truth_bags: Sequence[Path | None]) -> None:
    """Check that a mesh bag recording the bag it was tracked from has that one as its truth.

    Raises:
        ConfigError: naming the first mesh bag paired with another bag's truth.
    """
    for mesh, truth in zip(mesh_bags, truth_bags, strict=True):
        source = other_source(mesh, truth) if truth is not None else None
        if source is not None:
            msg = (
                f'--truth pairs {mesh} with {truth}, but it was tracked from {source}: give '
                'the truth bags in the order of the mesh bags'
            )
            raise ConfigError(msg)


def _meshes_dir(args: argparse.Namespace) -> Path:
    """Where tracked mesh bags of raw stereo bags go."""
    return args.meshes_dir or args.report.parent / f'{args.report.stem}_meshes'


def _initialisation(bag: Path, args: argparse.Namespace) -> str:
    """The stereo_tracker parameter that initialises a raw stereo bag's track.

    Its init file from --init-dir, else one of simulated clicks (--simulate-clicks), else the
    landmark detector (--auto-init).
    """
    if args.init_dir is not None:
        for suffix in ('.yaml', '.yml', '.json'):
            candidate = args.init_dir / f'{bag.name}{suffix}'
            if candidate.is_file():
                return f'init_file={candidate}'
    if args.simulate_clicks is not None:
        meshes = _meshes_dir(args)
        directory = args.init_dir or meshes.with_name(f'{meshes.name}_clicks')
        directory.mkdir(parents=True, exist_ok=True)
        path = directory / f'{bag.name}.json'
        nodes = tracked_nodes('stereo_tracker', args.tracker_param or [], None)
        clicks = clicks_from_bag(bag, args.simulate_clicks).only(nodes)
        return f'init_file={write_init_file(clicks, path)}'
    if args.auto_init:
        return 'auto_init=true'
    if args.init_dir is None:
        where = 'with --init-dir'
    elif args.init_dir.is_dir():
        where = f'in --init-dir {args.init_dir}, which has none'
    else:
        where = f'in --init-dir {args.init_dir}, which is not a directory'
    msg = (
        f'{bag} holds raw stereo images: give its initialisation {where} (a {bag.name}.yaml '
        'node-name -> pixel file), --auto-init (the optional landmark detector) or, for '
        'synthetic bags, --simulate-clicks'
    )
    raise ConfigError(msg)


def read_bag_meshes(
    bag: Path, args: argparse.Namespace, truth_bag: Path | None = None, name: str = ''
) -> list[BagMeshes]:
    """The meshes of one bag, one entry per subject found in it.

    Args:
        bag: a bag of FaceTruth, FaceMesh or FaceState messages.
        args: the command's arguments (topic, subject, neutral frames, nodes).
        truth_bag: for mesh bags, a bag whose ``truth/face`` messages give the subject, label and
            alpha of the mesh with the same header stamp (e.g. the synthetic bag a tracker ran on).
        name: the name the subject id is taken from without truth (:func:`subject_of`); empty:
            the bag's (the raw bag's, for the meshes tracked from it).

    Raises:
        BagError: if a bag lacks the topic, holds no message on it, or the truth bag has no
            truth for a mesh's stamp.
        InputError: naming the bag, topic and message index of a malformed message.
    """
    topics = bag_topics(bag)
    topic = _mesh_topic(topics, args)
    if topic is None:
        wanted = args.topic or ' or '.join(DEFAULT_TOPICS)
        msg = f'{bag}: no topic {wanted} in bag (topics: {", ".join(sorted(topics)) or "none"})'
        raise BagError(msg)
    msgtype = topics[topic]
    if msgtype != TRUTH_TYPE and msgtype not in MESH_TYPES:
        msg = f'{bag}: topic {topic} has type {msgtype}; expected FaceTruth, FaceMesh or FaceState'
        raise BagError(msg)
    truth = _truth_by_stamp(truth_bag) if truth_bag is not None else {}
    # A FaceState says itself whether it was tracked; a FaceMesh by its bag's face/state.
    untracked = _untracked_stamps(bag, topics) if msgtype == MESH_TYPES[0] else set()
    frames: dict[str, list[tuple[int, np.ndarray, str | None, np.ndarray | None]]] = {}
    true_sigma: dict[str, np.ndarray] = {}
    skipped = 0
    for index, message in enumerate(read_messages(bag, [topic])):
        try:
            stamp_ns, nodes, sample = mesh_from_message(message.msg, msgtype)
        except InputError as error:
            msg = f'{bag}: {topic} message {index}: {error}'
            raise InputError(msg) from None
        state_untracked = msgtype == MESH_TYPES[1] and message.msg.status != TRACKED
        if stamp_ns in untracked or state_untracked:
            skipped += 1
            continue
        if truth_bag is not None:
            sample = truth.get(stamp_ns)
            if sample is None:
                msg = f'{truth_bag}: no {TRUTH_TOPIC} message stamped {stamp_ns} ns for {bag}'
                raise BagError(msg)
        subject = sample.subject_id if sample else subject_of(name or bag.name, args)
        frames.setdefault(subject, []).append(
            (index, nodes, sample.label if sample else None, sample.alpha if sample else None)
        )
        if sample:
            true_sigma.setdefault(subject, sample.sigma)
    if skipped:
        print(f'{bag}: {skipped} frames the tracker did not track (initialising or lost) left out')
    if not frames:
        msg = (
            f'{bag}: none of the {skipped} frames on {topic} was tracked'
            if skipped
            else f'{bag}: no message on {topic}'
        )
        raise BagError(msg)
    return [
        _bag_meshes(bag, topic, subject, items, args, true_sigma.get(subject))
        for subject, items in frames.items()
    ]


def subject_of(name: str, args: argparse.Namespace) -> str:
    """The subject id of a bag without truth: ``--subject``, else from its name.

    The first group of ``--subject-pattern`` matched against the name (the whole name without
    a pattern).

    Raises:
        ConfigError: if the pattern does not match the name, or has no group.
    """
    if args.subject:
        return args.subject
    if not args.subject_pattern:
        return name
    match = re.fullmatch(args.subject_pattern, name)
    if match is None or not match.groups():
        msg = (
            f'--subject-pattern {args.subject_pattern!r} does not match the bag name {name!r} '
            'with a group (e.g. (.+)_\\d+)'
        )
        raise ConfigError(msg)
    return match.group(1)


def _mesh_topic(topics: dict[str, str], args: argparse.Namespace) -> str | None:
    """The bag's mesh topic: ``--topic``, else the first of DEFAULT_TOPICS it has.

    As the bag spells it (a recorder's names are absolute: '/face/mesh_raw'); None if it has none.
    """
    wanted = [args.topic] if args.topic else DEFAULT_TOPICS
    spelt = [bag_spelling(name, topics) for name in wanted]
    return next((name for name in spelt if name in topics), None)


def _untracked_stamps(bag: Path, topics: dict[str, str]) -> set[int]:
    """Header stamps of the frames a tracker's output bag says it did not track.

    Its face/state messages whose status is not TRACKING: the mesh of such a frame is none
    (zeros before the first initialisation) or the last one tracked, not the face.
    """
    state_topic = bag_spelling(STATE_TOPIC, topics)
    if topics.get(state_topic) != MESH_TYPES[1]:
        return set()
    return {
        stamp_to_ns(message.msg.header.stamp)
        for message in read_messages(bag, [state_topic])
        if message.msg.status != TRACKED
    }


def mesh_from_message(msg: Any, msgtype: str) -> tuple[int, np.ndarray, TruthSample | None]:
    """Header stamp (ns), (N, 3) nodes (m) and, for FaceTruth, the truth of one mesh message.

    A candidate for :mod:`face_tracking_ros.io.conversions`.

    Raises:
        InputError: naming the field of a NaN or malformed value.
    """
    if msgtype == TRUTH_TYPE:
        truth = truth_from_msg(msg)
        return truth.stamp_ns, truth.nodes, truth
    field = 'FaceMesh.points' if msgtype == MESH_TYPES[0] else 'FaceState.nodes'
    points = msg.points if msgtype == MESH_TYPES[0] else msg.nodes
    return stamp_to_ns(msg.header.stamp), points_to_array(points, field), None


def _truth_by_stamp(truth_bag: Path) -> dict[int, TruthSample]:
    """The truth samples of a bag by header stamp."""
    samples = (truth_from_msg(item.msg) for item in read_messages(truth_bag, [TRUTH_TOPIC]))
    return {sample.stamp_ns: sample for sample in samples}


def _bag_meshes(
    bag: Path,
    topic: str,
    subject: str,
    items: list[tuple[int, np.ndarray, str | None, np.ndarray | None]],
    args: argparse.Namespace,
    sigma: np.ndarray | None,
) -> BagMeshes:
    """One subject's meshes of a bag; neutral frames from labels, else the first K frames.

    ``items`` are (message index, nodes, label, alpha); the first K are by message index.
    ``sigma`` is the subject's true sigma, if the bag holds truth.
    """
    counts = {len(nodes) for _, nodes, _, _ in items}
    if len(counts) > 1:
        msg = f'{bag}: {topic} meshes of subject {subject!r} have node counts {sorted(counts)}'
        raise InputError(msg)
    meshes = _select_nodes(
        np.array([nodes for _, nodes, _, _ in items]), args.nodes, f'{bag}: {topic}'
    )
    if items[0][2] is None:
        neutral = np.array([index for index, _, _, _ in items]) < args.neutral_frames
        if neutral.all():
            print(
                f'{bag}: --neutral-frames {args.neutral_frames} covers all its {len(items)} '
                'frames: all are taken as neutral, none shows an expression'
            )
        return BagMeshes(MeshSequence(subject, meshes, neutral, None, str(bag)), None)
    labels = tuple(str(label) for _, _, label, _ in items)
    alpha = np.array([alpha for _, _, _, alpha in items])
    return BagMeshes(MeshSequence.labelled(subject, meshes, labels, str(bag)), alpha, sigma)


def _check_arguments(args: argparse.Namespace) -> None:
    """Range checks the parser cannot express."""
    if args.p < 1 or args.q < 1:
        msg = f'--p and --q must be >= 1, got p={args.p}, q={args.q}'
        raise ConfigError(msg)
    if args.explained_variance is not None and not 0.0 < args.explained_variance <= 1.0:
        msg = f'--explained-variance must be in (0, 1], got {args.explained_variance}'
        raise ConfigError(msg)
    if args.neutral_frames < 0 or not args.add_noise >= 0.0 or args.truth_samples < 10:
        msg = '--neutral-frames and --add-noise must not be negative, --truth-samples >= 10'
        raise ConfigError(msg)
    if args.subject_pattern is not None:
        try:
            re.compile(args.subject_pattern)
        except re.error as error:
            msg = f'--subject-pattern {args.subject_pattern!r}: not a regular expression: {error}'
            raise ConfigError(msg) from None
    if args.truth is not None and len(args.truth) != len(args.bags):
        msg = f'--truth names {len(args.truth)} bag(s) for {len(args.bags)} input bag(s)'
        raise ConfigError(msg)
    if args.plots is not None and not args.plots.is_dir():
        msg = f'--plots {args.plots} is not a directory'
        raise ConfigError(msg)
    if args.out.resolve() == args.report.resolve():
        msg = f'--out and --report are both {args.out}: the report would overwrite the model'
        raise ConfigError(msg)
    for option, path in (('--out', args.out), ('--report', args.report)):
        if not path.parent.is_dir():
            msg = f'{option} {path}: no directory {path.parent} to write it in'
            raise ConfigError(msg)
    unlabelled = [bag for bag in args.bags if not has_truth(bag)]
    if unlabelled and args.truth is None and args.neutral_frames == 0:
        msg = (
            f'{unlabelled[0]}: no truth says which frames show the neutral face; give '
            '--neutral-frames K, the first K frames of each bag (the learner node: neutral_frames)'
        )
        raise ConfigError(msg)


def _select_nodes(meshes: np.ndarray, num_nodes: int | None, where: str) -> np.ndarray:
    """Keep the first ``num_nodes`` nodes (the 19-node mesh is a prefix of the 34-node one)."""
    if meshes.shape[1] not in SUPPORTED_NODE_COUNTS:
        msg = f'{where}: meshes have {meshes.shape[1]} nodes; supported: {SUPPORTED_NODE_COUNTS}'
        raise InputError(msg)
    if num_nodes is None:
        return meshes
    if num_nodes > meshes.shape[1]:
        msg = f'{where}: --nodes {num_nodes} but the meshes have only {meshes.shape[1]} nodes'
        raise ConfigError(msg)
    return meshes[:, :num_nodes]


def _with_noise(sequence: MeshSequence, noise: float, rng: np.random.Generator) -> MeshSequence:
    """The sequence with white node noise of standard deviation ``noise`` metres."""
    noisy = sequence.meshes + rng.normal(scale=noise, size=sequence.meshes.shape)
    return MeshSequence(
        sequence.subject_id, noisy, sequence.neutral, sequence.labels, sequence.source
    )


def _truth(
    args: argparse.Namespace, training: TrainingSet, bag_meshes: Sequence[BagMeshes]
) -> TrueSubspaces | None:
    """The population's true subspaces for ``--truth-population``, or None."""
    if not args.truth_population:
        return None
    preset, _, seed = args.truth_population.partition(':')
    if preset not in PRESETS or (seed and not seed.isdigit()):
        msg = f'--truth-population must be PRESET[:SEED] with PRESET in {PRESETS}'
        raise ConfigError(msg)
    population = FacePopulation(preset, int(seed or 0))
    indices = [_synthetic_index(subject) for subject in training.subject_ids]
    for item in bag_meshes:
        subject = item.sequence.subject_id
        expected = population.subject(_synthetic_index(subject)).sigma_true
        given = item.sigma if item.sigma is not None else np.empty(0)
        if len(given) and not (expected.shape == given.shape and np.allclose(expected, given)):
            msg = (
                f'--truth-population {args.truth_population}: its {subject} is not the one of '
                f'the bags (another true sigma): give the --population and --seed that synth '
                'rendered them with'
            )
            raise ConfigError(msg)
    alphas = [item.alpha for item in bag_meshes]
    alpha = None if any(a is None for a in alphas) else np.concatenate(alphas)
    return population_truth(population, training.num_nodes, indices, alpha, args.truth_samples)


def _synthetic_index(subject: str) -> int:
    """The population index of a synthetic subject id ('subject_07' -> 7).

    Raises:
        ConfigError: for another id.
    """
    number = subject.removeprefix('subject_')
    if not number.isdigit():
        msg = f'subject {subject!r} is not a synthetic subject id (subject_NN)'
        raise ConfigError(msg)
    return int(number)


def _plots(
    directory: Path,
    training: TrainingSet,
    results: dict[str, LearningResult],
    evaluations: dict[str, Evaluation],
) -> list[Path]:
    """Write the PNG figures of the report."""
    paths = [
        plot_sigma_scatter(
            result.frame_sigma,
            training.subject_index,
            training.subject_ids,
            directory / f'sigma_{method}.png',
            title=f'sigma of every training frame, {method} model (cf. seed Figure 5)',
        )
        for method, result in results.items()
    ]
    paths.append(plot_comparison(evaluations, directory / 'comparison.png'))
    paths.append(plot_convergence(results, directory / 'convergence.png'))
    return paths


def _write_json(path: Path, report: dict[str, Any]) -> None:
    """Write the report; NaN (a figure that does not apply) becomes null."""
    path.write_text(json.dumps(_json_safe(report), indent=2) + '\n')


def _json_safe(value: Any) -> Any:
    """Replace NaN floats by None in nested dicts and lists."""
    if isinstance(value, dict):
        return {key: _json_safe(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(item) for item in value]
    if isinstance(value, float) and np.isnan(value):
        return None
    return value
