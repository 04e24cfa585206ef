"""Learner time against the number of training meshes and of subjects (issue 9).

Training meshes come from :func:`.world.training_set` (34 nodes). For each size the §3.3
alignment, the §3.4 learner (:func:`learn_seed`) and the joint learner (:func:`learn_joint`, the
default of ``face-tracking learn``) are timed separately, against the number of meshes and against
the number of subjects at a fixed number of meshes. The scaling exponent of each stage is the slope
of log(time) against log(meshes) (1 = linear, the target).
"""

from __future__ import annotations

from collections.abc import Callable
import time
from typing import Any

import numpy as np

from face_tracking_ros.bench.common import BenchOptions
from face_tracking_ros.bench.world import training_set
from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.joint import learn_joint
from face_tracking_ros.learning.result import LearningResult
from face_tracking_ros.learning.seed import learn_seed
from face_tracking_ros.learning.training_set import TrainingSet
from face_tracking_ros.synthetic.faces import FacePopulation

NUM_NODES = 34
SUBJECTS = 10
MESHES = (10**3, 10**4, 10**5, 10**6)
QUICK_MESHES = (10**3, 10**4)
SUBJECT_COUNTS, QUICK_SUBJECT_COUNTS = (5, 10, 20, 50), (5, 10)
SUBJECT_MESHES, QUICK_SUBJECT_MESHES = 20_000, 2_000
LEARNERS: dict[str, Callable[[TrainingSet], LearningResult]] = {
    'seed': learn_seed,
    'joint': learn_joint,
}


def run(options: BenchOptions) -> dict[str, Any]:
    """Time alignment and both learners against the number of meshes and of subjects.

    Returns:
        ``{'meshes': [rows], 'meshes_exponent': {...}, 'subjects': [rows]}``; every row gives
        the sizes, the seconds of each stage and the learner's iterations.
    """
    population = FacePopulation(seed=options.seed)
    rng = np.random.default_rng(options.seed)
    by_meshes = [
        _timed_row(population, SUBJECTS, meshes, LEARNERS, rng)
        for meshes in (QUICK_MESHES if options.quick else MESHES)
    ]
    subject_meshes = QUICK_SUBJECT_MESHES if options.quick else SUBJECT_MESHES
    by_subjects = [
        _timed_row(population, subjects, subject_meshes, LEARNERS, rng)
        for subjects in (QUICK_SUBJECT_COUNTS if options.quick else SUBJECT_COUNTS)
    ]
    sizes = np.log([row['meshes'] for row in by_meshes])
    exponents = {
        stage: float(np.polyfit(sizes, np.log([row[stage] for row in by_meshes]), 1)[0])
        for stage in ('align_s', *(f'{name}_s' for name in LEARNERS))
    }
    return {'meshes': by_meshes, 'meshes_exponent': exponents, 'subjects': by_subjects}


def _timed_row(
    population: FacePopulation,
    subjects: int,
    meshes: int,
    learners: dict[str, Callable[[TrainingSet], LearningResult]],
    rng: np.random.Generator,
) -> dict[str, Any]:
    """Seconds of the alignment and of each learner on one training set."""
    training = training_set(population, NUM_NODES, subjects, meshes // subjects, rng)
    start = time.perf_counter()
    aligned = align_training_set(training)
    row: dict[str, Any] = {
        'meshes': len(training.meshes),
        'subjects': subjects,
        'align_s': time.perf_counter() - start,
    }
    for name, learner in learners.items():
        start = time.perf_counter()
        result = learner(aligned)
        row[f'{name}_s'] = time.perf_counter() - start
        row[f'{name}_iterations'] = result.iterations
    return row
