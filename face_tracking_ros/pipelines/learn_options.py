"""What to learn from and how: the options of ``face-tracking learn`` and of the learner node.

Both front ends fill one :class:`LearnOptions` (the command from its flags, the node from its
parameters) and hand it to :func:`~.learn.learn_from_bags`; :func:`check_options` refuses what
the pipeline cannot run, before any work. The messages name an option as its front end does
(:attr:`LearnOptions.named`): by its ``face-tracking learn`` flag, or as the node's parameter.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
import re

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.atomic import check_output_path, check_replaceable
from face_tracking_ros.io.bags import check_distinct_bags
from face_tracking_ros.io.series import holds_truth
from face_tracking_ros.learning.methods import DEFAULT_METHOD, METHODS
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.pipelines.bag_reads import AFRESH, BagReads
from face_tracking_ros.pipelines.option_flags import option_flag
from face_tracking_ros.synthetic.faces import PRESETS
from face_tracking_ros.wording import counted


@dataclass(frozen=True)
class LearnOptions:
    """The options of one learning run; the defaults are ``face-tracking learn``'s.

    Attributes:
        bags: bags of meshes (FaceTruth, FaceMesh, FaceState) or of raw stereo images.
        out: model file to write (.npz).
        report: JSON report to write.
        nodes: mesh nodes (19 or 34: the first nodes of the bags' meshes); None: as in the bags.
        p: dimension of the identity subspace (sigma, the columns of S).
        explained_variance: choose p as the fewest identity modes explaining this share of the
            variance (overrides ``p``); None: ``p``.
        q: dimension of the expression subspace (alpha, the columns of A).
        method: learner whose model is written
            (:data:`~face_tracking_ros.learning.methods.METHODS`).
        compare: methods evaluated side by side with ``method``.
        plots: directory receiving PNG figures (made if missing); None: no figures.
        topic: mesh topic; None: the first of :data:`~.mesh_bags.DEFAULT_TOPICS` found.
        subject: subject id of every bag without truth; None: from the bag's name
            (:func:`~face_tracking_ros.io.bags.recording_name`).
        subject_pattern: bags without truth: the subject id is the first group of this regular
            expression matched against the bag's name; None: the whole name.
        truth: one bag per bag of ``bags``, in the same order, whose truth/face messages label
            the meshes of the same stamp (subject, expression, alpha); None: no such bags.
        neutral_frames: bags without truth: the first K frames of each bag show the neutral face.
        add_noise: white noise added to every node coordinate, m (0: none).
        seed: seed of that noise.
        truth_population: PRESET[:SEED] of the synthetic population the bags were rendered from
            (adds the comparison with the true subspaces to the report); None: unknown.
        truth_samples: population faces drawn to estimate the true identity axes.
        from_images: track the images of stereo bags even when they also hold truth meshes.
        init_dir: raw stereo bags: directory of init files <bag name>.yaml|.json; None: none.
        simulate_clicks: synthetic raw stereo bags: initialise from the first frame's true nodes
            with this many pixels of click noise; None: off.
        auto_init: raw stereo bags without an init file: find the face with the optional
            landmark detector.
        left_topic: raw stereo bags: the left image topic; None: the one whose name ends in
            left/image_raw (or left/image_raw/compressed), else the only image topic with
            the word 'left' and not 'right' in its name.
        right_topic: raw stereo bags: the right image topic; None: found as the left one.
        left_info_topic: raw stereo bags: the left camera_info topic; None: found as the left
            image (its name ending in left/camera_info, else by the word 'left').
        right_info_topic: raw stereo bags: the right camera_info topic; None: found so.
        meshes_dir: where the meshes tracked from raw stereo bags go; None: <report name>_meshes/
            beside the report.
        tracker_params: stereo_tracker parameters NAME=VALUE for tracking raw stereo bags, after
            :data:`~.stereo_meshes.STEREO_PARAMS`.
        named: how a message names the option of a field (e.g. ``'out'``): its
            ``face-tracking learn`` flag (:func:`option_flag`), or the learner node's parameter.
    """

    bags: tuple[Path, ...]
    out: Path
    report: Path
    nodes: int | None = None
    p: int = 2
    explained_variance: float | None = None
    q: int = 5
    method: str = DEFAULT_METHOD
    compare: tuple[str, ...] = METHODS
    plots: Path | None = None
    topic: str | None = None
    subject: str | None = None
    subject_pattern: str | None = None
    truth: tuple[Path, ...] | None = None
    neutral_frames: int = 0
    add_noise: float = 0.0
    seed: int = 0
    truth_population: str | None = None
    truth_samples: int = 2000
    from_images: bool = False
    init_dir: Path | None = None
    simulate_clicks: float | None = None
    auto_init: bool = False
    left_topic: str | None = None
    right_topic: str | None = None
    left_info_topic: str | None = None
    right_info_topic: str | None = None
    meshes_dir: Path | None = None
    tracker_params: tuple[str, ...] = ()
    named: Callable[[str], str] = option_flag


def check_options(options: LearnOptions, reads: BagReads = AFRESH) -> list[Path]:
    """Refuse options the pipeline cannot run: values out of range, then bags and files.

    Returns:
        The bags without truth (each bag's topics read by ``reads`` for it).

    Raises:
        ConfigError: naming the first option at fault.
    """
    _check_values(options)
    return _check_bags_and_files(options, reads)


def _check_values(options: LearnOptions) -> None:
    """Range checks argparse cannot express; the truth population's and subject pattern's form.

    A subject pattern beside ``subject`` is refused: ``subject`` names every bag without truth.
    """
    if options.p < 1 or options.q < 1:
        msg = f'--p and --q must be >= 1, got p={options.p}, q={options.q}'
        raise ConfigError(msg)
    share = options.explained_variance
    if share is not None and not 0.0 < share <= 1.0:
        msg = f'--explained-variance must be in (0, 1], got {share}'
        raise ConfigError(msg)
    if options.neutral_frames < 0 or not options.add_noise >= 0.0 or options.truth_samples < 10:
        msg = '--neutral-frames and --add-noise must not be negative, --truth-samples >= 10'
        raise ConfigError(msg)
    truth_population(options)
    if options.subject_pattern is not None:
        try:
            re.compile(options.subject_pattern)
        except re.error as error:
            named = options.named('subject_pattern')
            msg = f"{named} '{options.subject_pattern}': not a regular expression: {error}"
            raise ConfigError(msg) from None
        if options.subject:
            named = options.named('subject_pattern')
            msg = f'{named}: {options.named("subject")} names every bag without truth'
            raise ConfigError(msg)


def subject_of(name: str, options: LearnOptions) -> str:
    """The subject id of a bag without truth: ``options.subject``, else from its name.

    The first group of ``options.subject_pattern`` matched against the name (the whole name
    without a pattern).

    Raises:
        ConfigError: if the pattern does not match the name, or has no group.
    """
    if options.subject:
        return options.subject
    if not options.subject_pattern:
        return name
    match = re.fullmatch(options.subject_pattern, name)
    if match is None or not match.groups():
        msg = (
            f"{options.named('subject_pattern')} '{options.subject_pattern}' does not match the "
            f'bag name {name!r} with a group (e.g. (.+)_\\d+)'
        )
        raise ConfigError(msg)
    return match.group(1)


def truth_population(options: LearnOptions) -> tuple[str, int] | None:
    """The preset and seed of ``options.truth_population`` (PRESET[:SEED], seed 0 if not given).

    None if it is not given.

    Raises:
        ConfigError: if it is not PRESET[:SEED] with PRESET in
            :data:`~face_tracking_ros.synthetic.faces.PRESETS`.
    """
    if not options.truth_population:
        return None
    preset, _, seed = options.truth_population.partition(':')
    if preset not in PRESETS or (seed and not seed.isdigit()):
        msg = f'--truth-population must be PRESET[:SEED] with PRESET in {PRESETS}'
        raise ConfigError(msg)
    return preset, int(seed or 0)


def _check_bags_and_files(options: LearnOptions, reads: BagReads) -> list[Path]:
    """The truth bags pair with the bags, the outputs can be written, the neutral frames known.

    Returns:
        The bags without truth (each bag's topics read by ``reads`` for it).
    """
    check_distinct_bags(options.bags)
    if options.truth is not None and len(options.truth) != len(options.bags):
        truth, bags = counted(len(options.truth), 'bag'), counted(len(options.bags), 'input bag')
        msg = f'--truth names {truth} for {bags}'
        raise ConfigError(msg)
    if options.plots is not None:  # made if missing, as track's --out
        check_output_path(options.plots, options.named('plots'), directory=True)
    out, report = options.named('out'), options.named('report')
    if options.out.resolve() == options.report.resolve():
        msg = f'{out} and {report} are both {options.out}: the report would overwrite the model'
        raise ConfigError(msg)
    for option, path in ((out, options.out), (report, options.report)):
        check_output_path(path, option, parent_made=False)
    check_replaceable(options.out, out, 'a face model', load_model)
    unlabelled = [bag for bag in options.bags if not holds_truth(reads.topics(bag))]
    if unlabelled and options.truth is None and options.neutral_frames == 0:
        msg = (
            f'{unlabelled[0]}: no truth says which frames show the neutral face; give '
            f'{options.named("neutral_frames")} K, the first K frames of each bag'
        )
        raise ConfigError(msg)
    return unlabelled
