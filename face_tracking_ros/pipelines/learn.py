"""Learn a face model from bags and report its quality: ``face-tracking learn``, the learner node.

The steps of :func:`learn_from_bags`:

1. raw stereo bags are tracked into bags of 3-D meshes (:mod:`.stereo_meshes`), every one's
   initialisation found and tracking checked before minutes of tracking, and so are the
   subjects (too few for p), before any simulated clicks are written;
2. each bag's meshes are read, one sequence per subject (:mod:`.mesh_bags`), labelled by the
   bag's truth or by a truth bag of the same stamps;
3. the meshes are aligned (§3.3,
   :func:`~face_tracking_ros.learning.alignment.align_training_set`);
4. the model is learned by ``method`` (default ``joint``, issue 11; ``seed`` is the paper's
   §3.4) and every compared method, each evaluated by
   :func:`~face_tracking_ros.learning.evaluation.evaluate` (leave-one-subject-out, and against
   the true subspaces with ``truth_population``);
5. the model file, the JSON report and, with ``plots``, the PNG figures are written (Figure
   5-like sigma scatter per method, comparison, convergence).

Progress and the comparison table go to the ``say`` it is given, line by line: stdout for
``face-tracking learn``, the node's log for the learner node.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import replace
from pathlib import Path
import time
from typing import Any, NamedTuple

import numpy as np

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.atomic import write_json_atomically
from face_tracking_ros.io.bags import recording_name
from face_tracking_ros.io.provenance import other_source
from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.evaluation import (
    Evaluation,
    TrueSubspaces,
    comparison_table,
    evaluate,
    population_truth,
)
from face_tracking_ros.learning.methods import DEFAULT_EXPLAINED_VARIANCE, make_learner
from face_tracking_ros.learning.plots import (
    plot_comparison,
    plot_convergence,
    plot_sigma_scatter,
)
from face_tracking_ros.learning.result import LearningResult
from face_tracking_ros.learning.seed import check_subject_count
from face_tracking_ros.learning.training_set import MeshSequence, TrainingSet
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.model_file import save_model
from face_tracking_ros.pipelines.bag_reads import BagReads
from face_tracking_ros.pipelines.face_sizes import face_size_warning, subject_scales
from face_tracking_ros.pipelines.learn_options import (
    LearnOptions,
    check_options,
    truth_population,
)
from face_tracking_ros.pipelines.mesh_bags import (
    BagMeshes,
    bag_subjects,
    read_bag_meshes,
    subject_from_name,
)
from face_tracking_ros.pipelines.stereo_meshes import (
    RawBagTracking,
    checked_stereo_bags,
    mesh_bag,
    right_baseline,
    stereo_initialisations,
)
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.wording import counted

# LearnOptions fields that label the meshes of bags without truth (set: not None, not 0): the
# subject by the bag's name, the neutral frames by their index.
NO_TRUTH_LABELS = ('subject', 'subject_pattern', 'neutral_frames')


class _Labelling(NamedTuple):
    """What may label one bag's meshes (:func:`~.mesh_bags.bag_subjects`' arguments).

    Attributes:
        bag: the bag.
        truth: the bag whose truth labels its meshes (:func:`_truth_bags`), if any.
        truth_meshes: whether its meshes may be its own FaceTruth messages: it holds truth and
            is not tracked.
    """

    bag: Path
    truth: Path | None
    truth_meshes: bool


def learn_from_bags(options: LearnOptions, say: Callable[[str], None] = print) -> Path:
    """Read, align, learn, evaluate, write; return the model file written.

    Args:
        options: the bags, the method and its dimensions, the files to write.
        say: where the progress and the comparison table go: ``print`` (``face-tracking
            learn``) or a logger's ``info`` (the learner node).

    Raises:
        FaceTrackingError: for options, bags or files the run cannot use (ConfigError, BagError,
            InputError), naming what is wrong.
        KeyboardInterrupt: if the tracking of a raw stereo bag was interrupted.
    """
    reads = BagReads.once()  # each bag's topics and truth read once: checks, tracking, meshes
    trackings, truth_bags = _checked_before_tracking(options, reads)
    rng = np.random.default_rng(options.seed)
    mesh_bags = _mesh_bags(options, trackings, say, reads)
    bag_meshes = _read_meshes(options, mesh_bags, truth_bags, say, reads)
    _say_face_sizes(bag_meshes, trackings, say)
    training, align_seconds = _aligned_training_set(options, bag_meshes, rng, say)
    truth = _true_subspaces(options, training, bag_meshes)
    results: dict[str, LearningResult] = {}
    evaluations: dict[str, Evaluation] = {}
    report_methods: dict[str, Any] = {}
    for method in dict.fromkeys([options.method, *options.compare]):
        results[method], evaluations[method], report_methods[method] = _learn_and_evaluate(
            method, options, training, truth, say
        )
    for line in comparison_table(evaluations).splitlines():  # one log record a row, aligned
        say(line)
    saved = _save_model(options, results[options.method].model, say)
    plots = _plots(options.plots, training, results, evaluations) if options.plots else []
    report = {
        'model': str(saved),
        'method': options.method,
        'bags': [str(bag) for bag in options.bags],
        'subjects': list(training.subject_ids),
        'frames': len(training.meshes),
        'nodes': training.num_nodes,
        'align_seconds': align_seconds,
        'methods': report_methods,
        'plots': [str(path) for path in plots],
    }
    write_json_atomically(options.report, report)
    say(f'report written to {options.report}')
    return saved


def _checked_before_tracking(
    options: LearnOptions, reads: BagReads
) -> tuple[dict[Path, RawBagTracking], list[Path | None]]:
    """Check all that can be checked before any bag is tracked, then write the simulated clicks.

    The options, every raw stereo bag's tracking (:func:`~.stereo_meshes.checked_stereo_bags`),
    the truth bags' pairing (:func:`_check_truth_pairs`), then the subjects
    (:func:`_check_subjects`), reading the bags by ``reads``.

    Returns:
        The tracking of each raw stereo bag to track, by bag, planned by its checks and
        initialised (:func:`~.stereo_meshes.stereo_initialisations`), and the bag labelling
        each bag's meshes (:func:`_truth_bags`).
    """
    unlabelled = check_options(options, reads)
    raw = checked_stereo_bags(options, reads)
    truth_bags = _truth_bags(options, raw, unlabelled)
    _check_truth_pairs(options.bags, truth_bags)
    labellings = [
        _Labelling(bag, truth, bag not in raw and bag not in unlabelled)
        for bag, truth in zip(options.bags, truth_bags, strict=True)
    ]
    _check_no_truth_options(options, labellings, reads)
    named = options.truth is None and len(unlabelled) == len(options.bags)
    if raw or named:
        _check_subjects(options, labellings, reads)
    return stereo_initialisations(raw, options), truth_bags


def _truth_bags(
    options: LearnOptions, raw: Collection[Path], unlabelled: Collection[Path]
) -> list[Path | None]:
    """The bag labelling each bag's meshes: a raw stereo bag's own truth, else its ``truth`` bag.

    A raw stereo bag (of ``raw``, to be tracked) holding truth (not of ``unlabelled``) labels
    the meshes tracked from it; else the ``truth`` bag given for a bag labels its meshes, if any.
    """
    given = options.truth or [None] * len(options.bags)
    return [
        bag if bag in raw and bag not in unlabelled else truth
        for bag, truth in zip(options.bags, given, strict=True)
    ]


def _check_subjects(options: LearnOptions, labellings: list[_Labelling], reads: BagReads) -> None:
    """Refuse too few subjects for p before any bag is tracked, where the bags say who they are.

    Each bag's subjects are those its meshes will have (:func:`~.mesh_bags.bag_subjects`): its
    truth's, read by ``reads`` without its images or meshes, else the one its name gives.
    They are counted (by :func:`_checked_before_tracking`) when a raw stereo bag is to be
    tracked, or when all come from the bags' names (no bag holds truth, and no ``truth`` bags);
    else (bags of meshes and truth only) the learners count them once the meshes are read
    (:func:`~face_tracking_ros.learning.seed.check_dimensions`, the same message), after the
    meshes' own checks.

    Raises:
        ConfigError: if fewer than p + 1 subjects (2 when ``explained_variance`` chooses p), or
            a bag's name that ``subject_pattern`` does not match.
        BagError, InputError: for truth the reading of the meshes would refuse.
    """
    subjects = [bag_subjects(b.bag, options, b.truth, b.truth_meshes, reads) for b in labellings]
    if not all(subjects):  # a truth bag naming none: refused when the meshes are read
        return
    count = len(set().union(*subjects))
    check_subject_count(count, options.p if options.explained_variance is None else None)


def _check_no_truth_options(
    options: LearnOptions, labellings: list[_Labelling], reads: BagReads
) -> None:
    """Refuse the options that label bags without truth when truth labels every bag's meshes.

    ``subject`` and ``subject_pattern`` name the subject of a bag whose meshes no truth labels
    (:func:`~.mesh_bags.subject_from_name`), ``neutral_frames`` its neutral frames; where every
    bag's meshes are labelled by truth (its own, or its ``truth`` bag's), they would be ignored,
    and the truth's subject ids and expression labels are the ones learned (a synthetic
    subject's id names its true sigma).

    Raises:
        ConfigError: naming the options given and why they cannot apply.
        BagError: for a bag of truth without the mesh topic.
    """
    given = [field for field in NO_TRUTH_LABELS if getattr(options, field)]
    if not given or any(
        subject_from_name(b.bag, options, b.truth, b.truth_meshes, reads) for b in labellings
    ):
        return
    msg = (
        f'{", ".join(map(options.named, given))}: for bags without truth, and truth labels every '
        "bag's meshes (its own or a truth bag's): learn keeps the truth's subject ids and "
        'neutral labels'
    )
    raise ConfigError(msg)


def _mesh_bags(
    options: LearnOptions,
    trackings: dict[Path, RawBagTracking],
    say: Callable[[str], None],
    reads: BagReads,
) -> list[Path]:
    """Each bag's bag of meshes.

    The bag itself, or for a raw stereo bag (one of ``trackings``, checked and initialised) its
    tracking (:func:`~.stereo_meshes.mesh_bag`, scored against its truth read by ``reads``).

    Raises:
        BagError: if the tracker produced no mesh from a raw stereo bag.
    """
    return [
        mesh_bag(trackings[bag], options, say, reads) if bag in trackings else bag
        for bag in options.bags
    ]


def _check_truth_pairs(bags: Sequence[Path], truth_bags: Sequence[Path | None]) -> None:
    """Check that a given bag of meshes recording the bag it was tracked from has that as truth.

    A raw stereo bag records no source: the meshes tracked from it here are labelled by the
    truth bag given for it (matched by header stamp), which is never the raw bag itself.

    Raises:
        ConfigError: naming the first mesh bag paired with another bag's truth.
    """
    for mesh, truth in zip(bags, truth_bags, strict=True):
        source = other_source(mesh, truth) if truth is not None else None
        if source is not None:
            msg = (
                f'--truth pairs {mesh} with {truth}, but it was tracked from {source}: give '
                'the truth bags in the order of the mesh bags'
            )
            raise ConfigError(msg)


def _read_meshes(
    options: LearnOptions,
    mesh_bags: Sequence[Path],
    truth_bags: Sequence[Path | None],
    say: Callable[[str], None],
    reads: BagReads,
) -> list[BagMeshes]:
    """The meshes of every bag, one entry per bag and subject; named after the given bags.

    Truth (labels, and meshes of FaceTruth) is read by ``reads``.
    """
    return [
        item
        for bag, mesh, truth_bag in zip(options.bags, mesh_bags, truth_bags, strict=True)
        for item in read_bag_meshes(mesh, options, truth_bag, recording_name(bag), say, reads)
    ]


def _say_face_sizes(
    bag_meshes: Sequence[BagMeshes],
    trackings: dict[Path, RawBagTracking],
    say: Callable[[str], None],
) -> None:
    """``say`` a warning if the subjects' faces are too large or small together (a baseline off).

    :func:`~.face_sizes.face_size_warning`, naming the baselines of the raw stereo bags tracked
    (their right camera_infos are read only then).
    """
    scales = subject_scales([item.sequence for item in bag_meshes])
    warning = face_size_warning(scales, lambda: _right_baselines(trackings))
    if warning is not None:
        say(warning)


def _right_baselines(trackings: dict[Path, RawBagTracking]) -> dict[Path, tuple[float, float]]:
    """By raw stereo bag tracked, its right camera's P[0,3] and baseline (:func:`right_baseline`).

    Bags without a right camera_info are left out.
    """
    baselines = {bag: right_baseline(tracking) for bag, tracking in trackings.items()}
    return {bag: found for bag, found in baselines.items() if found is not None}


def _aligned_training_set(
    options: LearnOptions,
    bag_meshes: Sequence[BagMeshes],
    rng: np.random.Generator,
    say: Callable[[str], None],
) -> tuple[TrainingSet, float]:
    """The training set aligned (§3.3), ``add_noise`` drawn from ``rng``; the seconds it took."""
    sequences = [item.sequence for item in bag_meshes]
    if options.add_noise > 0.0:
        sequences = [_with_noise(sequence, options.add_noise, rng) for sequence in sequences]
    training = TrainingSet.from_sequences(sequences)
    say(
        f'read {counted(len(training.meshes), "mesh", "meshes")} of {training.num_nodes} '
        f'nodes, {counted(training.num_subjects, "subject")}, '
        f'{counted(int(training.neutral.sum()), "neutral frame")}'
    )
    start = time.perf_counter()
    aligned = align_training_set(training)
    return aligned, time.perf_counter() - start


def _with_noise(sequence: MeshSequence, noise: float, rng: np.random.Generator) -> MeshSequence:
    """The sequence with white node noise of standard deviation ``noise`` metres."""
    noisy = sequence.meshes + rng.normal(scale=noise, size=sequence.meshes.shape)
    return replace(sequence, meshes=noisy)


def _true_subspaces(
    options: LearnOptions, training: TrainingSet, bag_meshes: Sequence[BagMeshes]
) -> TrueSubspaces | None:
    """The population's true subspaces for ``truth_population``, or None.

    Raises:
        ConfigError: for a subject id that is not synthetic, or a population whose subjects
            are not the bags' (another true sigma).
    """
    preset = truth_population(options)
    if preset is None:
        return None
    population = FacePopulation(*preset)
    indices = [_synthetic_index(subject) for subject in training.subject_ids]
    for item in bag_meshes:
        subject = item.sequence.subject_id
        expected = population.subject(_synthetic_index(subject)).sigma_true
        given = item.sigma if item.sigma is not None else np.empty(0)
        if len(given) and not (expected.shape == given.shape and np.allclose(expected, given)):
            msg = (
                f'--truth-population {options.truth_population}: its {subject} is not the one '
                'of the bags (another true sigma): give the --population and --seed that synth '
                'rendered them with'
            )
            raise ConfigError(msg)
    alphas = [item.alpha for item in bag_meshes]
    alpha = None if any(a is None for a in alphas) else np.concatenate(alphas)
    return population_truth(population, training.num_nodes, indices, alpha, options.truth_samples)


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


def _learn_and_evaluate(
    method: str,
    options: LearnOptions,
    training: TrainingSet,
    truth: TrueSubspaces | None,
    say: Callable[[str], None],
) -> tuple[LearningResult, Evaluation, dict[str, Any]]:
    """Learn by ``method`` from the aligned ``training`` set and evaluate the model.

    p is ``options.p``, or chosen for ``explained_variance`` when given.

    Returns:
        The learning result, its evaluation and the method's entry of the report.
    """
    share = options.explained_variance
    p = options.p if share is None else None
    learner = make_learner(method, p, options.q, share or DEFAULT_EXPLAINED_VARIANCE)
    start = time.perf_counter()
    result = learner(training)
    learn_seconds = time.perf_counter() - start
    say(f'{method}: learned in {learn_seconds:.3f} s, evaluating (leave one subject out)')
    evaluation, loo, _ = evaluate(training, learner, result, truth)
    if loo.skipped:
        say(f'{method}: no leave-one-subject-out figures: {loo.skipped}')
    entry = {
        **evaluation.as_dict(),
        'learn_seconds': learn_seconds,
        'history': result.history.tolist(),
        'loo_per_subject': {
            'subjects': list(training.subject_ids),
            'shape_similarity': loo.shape_similarity.tolist(),
            'action_similarity': loo.action_similarity.tolist(),
            'mean_variation_percent': loo.mean_variation_percent.tolist(),
            'neutral_rms_mm': loo.neutral_rms_mm.tolist(),
            'p': [int(dim) if np.isfinite(dim) else None for dim in loo.p],
        },
    }
    return result, evaluation, entry


def _save_model(options: LearnOptions, model: FaceModel, say: Callable[[str], None]) -> Path:
    """Write the model, its metadata naming the bags it was learned from; return its path."""
    metadata = {**model.metadata, 'bags': [str(bag) for bag in options.bags]}
    saved = save_model(replace(model, metadata=metadata), options.out)
    say(f'model ({options.method}, p={model.p}, q={model.q}) written to {saved}')
    return saved


def _plots(
    directory: Path,
    training: TrainingSet,
    results: dict[str, LearningResult],
    evaluations: dict[str, Evaluation],
) -> list[Path]:
    """Write the PNG figures of the report into ``directory`` (made if missing)."""
    directory.mkdir(parents=True, exist_ok=True)
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
