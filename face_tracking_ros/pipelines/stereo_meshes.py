"""Raw stereo bags to bags of 3-D meshes: the stereo tracking step of learning.

A raw stereo bag (left and right images, Image or CompressedImage, found by their names or given
as ``left_topic`` and ``right_topic``; no mesh topic, or any stereo bag with ``from_images``) is
tracked by the stereo tracker (eq. 4, 5) through offline replay of the stereo_tracker node's own
code, into ``meshes_dir``, before it is learned from. By default every mesh carries the frame-1
depths refined over its whole track (the processor's ``retroactive_depths``); ``tracker_params``
override it. Meshes an earlier run tracked from the same inputs are re-used. Every raw bag's
tracking is checked and planned once (:class:`RawBagTracking`) before any is tracked and before
any simulated clicks are written (:func:`checked_stereo_bags`), so that a refused run leaves
nothing behind (its tracker's parameters are worked out once, by :func:`raw_bag_parameters`);
the plans are then completed with their initialisations (:func:`stereo_initialisations`) and
tracked (:func:`mesh_bag`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
import shutil

from face_tracking_ros.errors import BagError, ConfigError, FaceTrackingError
from face_tracking_ros.io.bags import recording_name
from face_tracking_ros.io.conversions import camera_from_info
from face_tracking_ros.io.provenance import Provenance, replay_source
from face_tracking_ros.io.series import holds_truth, read_converted, truth_series
from face_tracking_ros.pipelines.bag_inputs import (
    STEREO_FIELDS,
    check_one_transport,
    check_stereo_topics,
    clicked_camera_topic,
    compressed_parameters,
    image_topics,
    is_stereo_bag,
    stereo_remaps,
    tracked_nodes,
)
from face_tracking_ros.pipelines.bag_reads import AFRESH, BagReads
from face_tracking_ros.pipelines.learn_options import LearnOptions
from face_tracking_ros.pipelines.mesh_bags import TRUTH_TOPIC, mesh_topic
from face_tracking_ros.pipelines.scoring import score_stereo_against_truth
from face_tracking_ros.processing.node_configs import RIGHT_INFO, StereoNodeConfig
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.track_counts import NO_REASON
from face_tracking_ros.replay import ReplayStats, fed_topic, replay_bag, wire_replay
from face_tracking_ros.synthetic.clicks import (
    check_clicks_file,
    clicks_from_bag,
    write_init_file,
)

STEREO_PARAMS = 'retroactive_depths=true'  # learn from meshes with each track's final depths
TRACKER = 'stereo_tracker'
# LearnOptions fields used only to track raw stereo bags (set: not None, False or empty).
TRACKING_FIELDS = (
    'init_dir',
    'simulate_clicks',
    'auto_init',
    *STEREO_FIELDS.values(),
    'meshes_dir',
    'tracker_params',
)


@dataclass(frozen=True)
class TrackerParameters:
    """The stereo tracker's parameters for a raw stereo bag, but its initialisation.

    Worked out once per bag, by :func:`raw_bag_parameters`, which parses them.

    Attributes:
        overrides: its parameters, name -> value text: :data:`STEREO_PARAMS`, the image
            transport's, then ``tracker_params``, parsed.
        compressed: its ``compressed`` parameter (it reads the bag's images as CompressedImage).
    """

    overrides: dict[str, str]
    compressed: bool


@dataclass(frozen=True)
class RawBagTracking:
    """The tracking of one raw stereo bag, planned by its checks (:func:`checked_stereo_bags`).

    Attributes:
        bag: the raw stereo bag.
        topics: its topics (name -> type).
        out: where its meshes go (:func:`_tracked_meshes`).
        tracker_params: the stereo tracker's parameters but its initialisation, name -> value
            text (:attr:`TrackerParameters.overrides`).
        remaps: the tracker's input -> bag topic.
        left_info: the camera_info topic the tracker reads for its left camera (the one the
            simulated clicks are in); None: none.
        right_info: the camera_info topic it reads for its right camera (the baseline's);
            None: none.
        initialisation: the stereo_tracker parameter initialising the track, name -> value
            text; None: simulated clicks, not written yet (:func:`stereo_initialisations` adds
            them).
    """

    bag: Path
    topics: dict[str, str]
    out: Path
    tracker_params: dict[str, str]
    remaps: dict[str, str]
    left_info: str | None
    right_info: str | None
    initialisation: dict[str, str] | None

    def params(self) -> OverrideParameters:
        """The stereo tracker's parameters: :attr:`tracker_params`, then the initialisation."""
        return _parameters(self.tracker_params, self.initialisation)


def mesh_bag(
    tracking: RawBagTracking,
    options: LearnOptions,
    say: Callable[[str], None] = print,
    reads: BagReads = AFRESH,
) -> Path:
    """The bag of 3-D meshes tracked from a raw stereo bag, as planned: ``tracking.out``.

    ``tracking`` is one of :func:`stereo_initialisations` (checked, then initialised): the bag
    is tracked into ``tracking.out`` without checking it again, with its ``tracker_params``
    and initialisation. Its inputs (:class:`~face_tracking_ros.io.provenance.Provenance`, which
    hashes the files the parameters name: the init file) are taken here, just before it is
    tracked; meshes an earlier run tracked from the same inputs are re-used
    (:func:`_tracked_before`). What it does, the replay's summary and the score against the
    bag's truth (read by ``reads``: learn reads each bag's once a run) go to ``say``, line by
    line.

    Raises:
        ConfigError: if ``tracking.out`` exists but is not a tracking of the bag by learn (put
            there since the checks).
        BagError: if the tracker produced no mesh (the input problems named).
        KeyboardInterrupt: if the tracking was interrupted (the meshes so far stay, and a later
            run tracks the bag again).
    """
    params = tracking.params()
    inputs = Provenance.of(tracking.bag, [TRACKER], params.overrides, tracking.remaps)
    if _tracked_before(tracking.out, inputs, options.named('meshes_dir'), say):
        return tracking.out
    _track(tracking, params, say)
    if holds_truth(tracking.topics):
        say(_score_line(tracking.bag, tracking.out, reads))
    return tracking.out


def checked_stereo_bags(
    options: LearnOptions, reads: BagReads = AFRESH
) -> dict[Path, RawBagTracking]:
    """The tracking of each raw stereo bag to track, by bag, checked and planned.

    Its initialisation is the stereo_tracker parameter of its init file or of ``auto_init``;
    None for simulated clicks, which :func:`stereo_initialisations` writes. Every check that can
    refuse a bag's tracking (:func:`raw_bag_parameters`, :func:`_planned_tracking`) runs for every
    bag first, and writes nothing: a run refused before :func:`stereo_initialisations` leaves
    no clicks behind. Each bag's topics are read by ``reads``.

    Raises:
        ConfigError: for a raw stereo bag without a way to initialise it, or one that
            :func:`raw_bag_parameters` or :func:`_planned_tracking` refuses.
        BagError: for a bag that cannot be read.
    """
    topics = {bag: reads.topics(bag) for bag in options.bags}
    parameters = {bag: raw_bag_parameters(bag, topics[bag], options) for bag in options.bags}
    raw = {bag: found for bag, found in parameters.items() if found is not None}
    if not raw:
        _check_no_tracking_options(options)
    given = {bag: _given_initialisation(bag, options) for bag in raw}
    return {
        bag: _planned_tracking(bag, topics[bag], raw[bag], options, init)
        for bag, init in given.items()
    }


def _check_no_tracking_options(options: LearnOptions) -> None:
    """Refuse options of the tracking of raw stereo bags when no bag is tracked.

    Every bag holds meshes (a synthetic stereo bag's truth among them), which learn reads; an
    init directory or simulated clicks given for its images were ignored, and the model learned
    from the truth.

    Raises:
        ConfigError: naming the options and what the bags hold.
    """
    given = [field for field in TRACKING_FIELDS if getattr(options, field) not in (None, ())]
    given = [field for field in given if getattr(options, field) is not False]  # 0 clicks: set
    if given:
        msg = (
            f'{", ".join(options.named(field) for field in given)}: for raw stereo bags, and no '
            f'bag is tracked: each holds meshes, which learn reads (truth, FaceMesh or '
            f'FaceState); {options.named("from_images")} tracks the images of stereo bags'
        )
        raise ConfigError(msg)


def stereo_initialisations(
    checked: dict[Path, RawBagTracking], options: LearnOptions
) -> dict[Path, RawBagTracking]:
    """Each raw stereo bag's planned tracking, by bag, with the parameter initialising its track.

    The one its checks found (:func:`checked_stereo_bags`), else the bag's simulated clicks,
    written here: all are drawn before any is written (:func:`_write_clicks`).

    Raises:
        BagError: for a bag whose clicks cannot be simulated (no truth, no camera_info).
    """
    clicked = [tracking for tracking in checked.values() if tracking.initialisation is None]
    written = _write_clicks(clicked, options)
    return {
        bag: replace(tracking, initialisation=tracking.initialisation or written[bag])
        for bag, tracking in checked.items()
    }


def _planned_tracking(
    bag: Path,
    topics: dict[str, str],
    parameters: TrackerParameters,
    options: LearnOptions,
    initialisation: dict[str, str] | None,
) -> RawBagTracking:
    """The tracking of a raw stereo bag, after every check it runs before it writes anything.

    Those of :func:`~face_tracking_ros.replay.wire_replay` (the tracker parameters, the
    initialisation's file or detector, the topics), the one of :func:`_tracked_before` (its
    meshes directory is not another's) and, for simulated clicks, that of their file
    (:func:`~face_tracking_ros.synthetic.clicks.check_clicks_file`: not a user's file).

    Args:
        bag: the raw stereo bag.
        topics: its topics (name -> type).
        parameters: its stereo tracker's parameters, but the initialisation
            (:func:`raw_bag_parameters`).
        options: the learning run's options.
        initialisation: its stereo_tracker initialisation parameter (name -> value text);
            None: none yet (the simulated clicks, written once all is checked).

    Raises:
        BagError, ConfigError: naming what the tracking would refuse.
    """
    if initialisation is None:
        check_clicks_file(_clicks_file(bag, options), f'{options.named("simulate_clicks")}:')
    params = _parameters(parameters.overrides, initialisation)
    remaps = stereo_remaps(topics, options, parameters.compressed)
    _, read = wire_replay([TRACKER], bag, params, remaps, frozenset(), topics)
    out = _tracked_meshes(bag, options)
    _earlier_tracking(out, replay_source(bag), options.named('meshes_dir'))
    left_info = clicked_camera_topic(read, TRACKER)
    right_info = fed_topic(read, RIGHT_INFO)
    return RawBagTracking(
        bag, topics, out, parameters.overrides, remaps, left_info, right_info, initialisation
    )


def right_baseline(tracking: RawBagTracking) -> tuple[float, float] | None:
    """The right camera's P[0,3] (-fx B) and baseline B (m) of a raw stereo bag; None: none.

    From the first camera_info on :attr:`RawBagTracking.right_info`.

    Raises:
        BagError: if the bag cannot be read.
        InputError: for a camera_info that is not a calibration, naming the bag and topic.
    """
    if tracking.right_info is None:
        return None
    first = next(read_converted(tracking.bag, tracking.right_info, camera_from_info), None)
    if first is None:
        return None
    p = first[1].p
    return float(p[0, 3]), -float(p[0, 3]) / float(p[0, 0])


def _parameters(
    tracker_params: Mapping[str, str], initialisation: Mapping[str, str] | None
) -> OverrideParameters:
    """The stereo tracker's parameters: ``tracker_params``, then ``initialisation`` (if any).

    Both are parsed already (name -> value text): an initialisation parameter overrides one of
    ``tracker_params`` of its name, as it would given after them on a command line.
    """
    return OverrideParameters({**tracker_params, **(initialisation or {})})


def raw_bag_parameters(
    bag: Path, topics: dict[str, str], options: LearnOptions
) -> TrackerParameters | None:
    """The stereo tracker's parameters for ``bag`` (of ``topics``), a raw stereo bag; else None.

    A raw stereo bag is one that :func:`mesh_bag` tracks; the tracker's parameters (but the
    initialisation, found later) are parsed here, once for the bag.

    Raises:
        ConfigError: for a bag of images whose stereo pair is not found by name (and not given)
            while there are no meshes to learn from or ``--from-images`` asks for tracking,
            for two raw stereo bags of one name, or for stereo topics the tracker cannot pair
            (:func:`~.bag_inputs.check_stereo_topics`).
    """
    has_meshes = options.topic or mesh_topic(topics, options) is not None
    if not (is_stereo_bag(topics) or options.left_topic):
        images, _ = image_topics(topics)
        if options.from_images or (images and not has_meshes):
            check_one_transport(bag, topics)
            left, right, left_info, right_info = map(options.named, STEREO_FIELDS.values())
            msg = (
                f'{bag}: no stereo pair found by name among its image topics '
                f'({", ".join(images) or "none"}): the left and right topics need the words '
                f'"left" and "right" in their names, else give {left}, {right}, {left_info} and '
                f'{right_info}'
            )
            raise ConfigError(msg)
        return None
    if has_meshes and not options.from_images:
        return None
    name = recording_name(bag)
    namesakes = [other for other in options.bags if recording_name(other) == name and other != bag]
    if namesakes:
        msg = (
            f'{bag} and {namesakes[0]} are both named {name}: the init files and tracked '
            f'meshes of raw stereo bags are named after the bag, so rename one '
            f'({options.named("subject_pattern")} can still give both the same subject)'
        )
        raise ConfigError(msg)
    transport = compressed_parameters(topics, [options.left_topic])
    params = OverrideParameters.parse([STEREO_PARAMS, *transport, *options.tracker_params])
    compressed = params.config(StereoNodeConfig).compressed
    check_stereo_topics(bag, topics, options, compressed, named=options.named)
    return TrackerParameters(params.overrides, compressed)


def _given_initialisation(bag: Path, options: LearnOptions) -> dict[str, str] | None:
    """The stereo_tracker parameter that initialises a raw stereo bag's track; None: clicks.

    Its init file from --init-dir, else None for simulated clicks (--simulate-clicks, to be
    written by :func:`_write_clicks`), else the landmark detector (--auto-init).

    Raises:
        ConfigError: if none of them is given.
    """
    if options.init_dir is not None:
        for suffix in ('.yaml', '.yml', '.json'):
            candidate = options.init_dir / f'{recording_name(bag)}{suffix}'
            if candidate.is_file():
                return {'init_file': str(candidate)}
    if options.simulate_clicks is not None:
        return None
    if options.auto_init:
        return {'auto_init': 'true'}
    init_dir = options.named('init_dir')
    if options.init_dir is None:
        where = f'with {init_dir}'
    elif options.init_dir.is_dir():
        where = f'in {init_dir} {options.init_dir}, which has none'
    else:
        where = f'in {init_dir} {options.init_dir}, which is not a directory'
    msg = (
        f'{bag} holds raw stereo images: give its initialisation {where} (a '
        f'{recording_name(bag)}.yaml node-name -> pixel file), {options.named("auto_init")} '
        f'(the optional landmark detector) or, for synthetic bags, '
        f'{options.named("simulate_clicks")}'
    )
    raise ConfigError(msg)


def _write_clicks(
    trackings: list[RawBagTracking], options: LearnOptions
) -> dict[Path, dict[str, str]]:
    """Write the simulated clicks of the bags of ``trackings``, each in its tracker's left camera.

    They go to --init-dir (default <meshes dir>_clicks/), in the camera_info the tracker reads
    as its left one (:attr:`RawBagTracking.left_info`). Every bag's clicks are drawn before any
    are written (a bag without truth writes none).

    Returns:
        By bag, the stereo_tracker parameter that initialises its track from its clicks.

    Raises:
        BagError: for a bag whose clicks cannot be simulated (no truth, no camera_info).
    """
    if not trackings:
        return {}
    nodes = tracked_nodes(TRACKER, list(options.tracker_params), None)
    clicks = {
        tracking.bag: clicks_from_bag(
            tracking.bag,
            options.simulate_clicks,
            camera_info=tracking.left_info,
            topics=tracking.topics,
        ).only(nodes)
        for tracking in trackings
    }
    written: dict[Path, dict[str, str]] = {}
    for bag, init in clicks.items():
        path = _clicks_file(bag, options)
        path.parent.mkdir(parents=True, exist_ok=True)
        written[bag] = {'init_file': str(write_init_file(init, path))}
    return written


def _clicks_file(bag: Path, options: LearnOptions) -> Path:
    """Where the simulated clicks of ``bag`` go: <--init-dir or meshes dir_clicks>/<bag>.json."""
    meshes = _meshes_dir(options)
    directory = options.init_dir or meshes.with_name(f'{meshes.name}_clicks')
    return directory / f'{recording_name(bag)}.json'


def _track(
    tracking: RawBagTracking, params: OverrideParameters, say: Callable[[str], None]
) -> None:
    """Track a raw stereo bag as planned, with ``params``, and ``say`` what it did.

    Raises:
        BagError: if the tracker produced no mesh (``tracking.out`` is removed).
        KeyboardInterrupt: if the tracking was interrupted.
    """
    bag, out = tracking.bag, tracking.out
    say(f'{bag}: raw stereo images: tracking them into {out}')
    stats = replay_bag(
        [TRACKER], bag, out, params, tracking.remaps, progress=False, topics=tracking.topics
    )
    if stats.interrupted:  # the meshes so far stay, and a later run tracks the bag again
        raise KeyboardInterrupt
    for line in stats.summary(out):
        say(line)
    if not stats.outputs['face/mesh_raw']:
        shutil.rmtree(out)  # nothing to learn from, and a later run must track it again
        raise _no_mesh_error(bag, stats)


def _no_mesh_error(bag: Path, stats: ReplayStats) -> BagError:
    """The error of a tracking that produced no mesh: its input problems, else its last reason.

    The last reason says what went wrong with good inputs (e.g. images that never paired).
    (Camera_info topics not found are refused before, by :func:`raw_bag_parameters`.)
    """
    problems = '; '.join(f'{count}x {error}' for error, count in stats.errors.items())
    if not problems:
        reason = stats.status.get(TRACKER, {}).get('last_reason', NO_REASON)
        problems = 'no input problem' + (f'; last_reason: {reason}' if reason != NO_REASON else '')
    msg = f'{bag}: the stereo tracker produced no mesh ({problems})'
    return BagError(msg)


def _score_line(bag: Path, out: Path, reads: BagReads) -> str:
    """How the meshes tracked into ``out`` compare with the truth in ``bag``, in one line.

    The truth is that of its ``truth/face``, read by ``reads``, which labels the meshes.
    """
    try:
        truth = truth_series(reads.truth(bag, TRUTH_TOPIC), f'{bag}: topic {TRUTH_TOPIC}')
        evaluation = score_stereo_against_truth(bag, out, truth)
    except FaceTrackingError as error:  # e.g. camera_info topics not named left / right
        return f'{out}: not scored against the truth of {bag}: {error}'
    return f'{out} against the truth of {bag}: {evaluation.report()}'


def _tracked_before(
    out: Path, inputs: Provenance, meshes_dir: str, say: Callable[[str], None]
) -> bool:
    """Whether ``out`` holds meshes an earlier run tracked from these inputs, to re-use.

    An earlier tracking of the same bag from other inputs, one that did not finish, or one
    whose bag was never closed (no metadata.yaml: the process was killed) is removed, to be
    tracked again; which of these it is goes to ``say``.

    Args:
        out: where the bag's meshes go.
        inputs: what they are tracked from.
        meshes_dir: the option that says where meshes go (named in the message).
        say: where the message goes.

    Raises:
        ConfigError: if ``out`` exists but is not such a tracking (not ours to remove).
    """
    earlier = _earlier_tracking(out, inputs.source, meshes_dir)
    if earlier is None:
        if out.exists():
            say(f'{out}: an earlier run was stopped before it closed the bag: tracking again')
            shutil.rmtree(out)
        return False
    if earlier.complete and earlier.same_inputs(inputs):
        say(f'{out}: re-using the meshes an earlier run tracked from the same inputs')
        return True
    why = 'did not finish' if earlier.same_inputs(inputs) else 'tracked it from other inputs'
    say(f'{out}: an earlier run {why}: tracking again')
    shutil.rmtree(out)
    return False


def _earlier_tracking(out: Path, source: str, meshes_dir: str) -> Provenance | None:
    """What an earlier tracking of ``source`` into ``out`` by learn was made from.

    ``source`` is the bag as its replay records it
    (:func:`~face_tracking_ros.io.provenance.replay_source`). None if ``out`` does not exist or
    holds only MCAP files (a writer killed before closing).

    Raises:
        ConfigError: if ``out`` exists but is not such a tracking (not ours to remove), naming
            ``meshes_dir``, the option that says where meshes go, and the bag it was tracked
            from if it says (the same recording given as its directory and as its MCAP file
            are two inputs: a directory may hold more files).
    """
    if not out.exists():
        return None
    files = list(out.iterdir()) if out.is_dir() else []
    if files and all(file.suffix == '.mcap' for file in files):
        return None
    earlier = Provenance.read(out)
    if earlier is None or earlier.source != source:
        recorded = '' if earlier is None else f' (it was tracked from {earlier.source})'
        msg = (
            f'{out} exists and is not a tracking of {source} by learn{recorded}: remove it '
            f'or give another {meshes_dir}'
        )
        raise ConfigError(msg)
    return earlier


def _meshes_dir(options: LearnOptions) -> Path:
    """Where tracked mesh bags of raw stereo bags go."""
    return options.meshes_dir or options.report.parent / f'{options.report.stem}_meshes'


def _tracked_meshes(bag: Path, options: LearnOptions) -> Path:
    """The bag of meshes tracked from the raw stereo bag ``bag``: named after its recording."""
    return _meshes_dir(options) / recording_name(bag)
