"""The training set's face-size warning (a stereo baseline off by a factor) on the populations."""

from __future__ import annotations

import itertools

import numpy as np

from face_tracking_ros.learning.training_set import MeshSequence
from face_tracking_ros.pipelines.face_sizes import face_size_warning, subject_scales
from face_tracking_ros.synthetic.faces import FacePopulation


def _warned(sets: list[list[MeshSequence]], factor: float) -> int:
    """How many of ``sets`` warn with every mesh ``factor`` times its size (a baseline k B)."""
    scaled = [[_scaled(sequence, factor) for sequence in group] for group in sets]
    return sum(face_size_warning(subject_scales(group), dict) is not None for group in scaled)


def _scaled(sequence: MeshSequence, factor: float) -> MeshSequence:
    return MeshSequence(sequence.subject_id, factor * sequence.meshes, sequence.neutral)


def test_sets_of_three_adults_are_told_from_a_baseline_25_percent_off() -> None:
    """Sets of 3 neutral faces (60 of each population and seed 0-2, both meshes): 240 sets.

    None warns as it is; every one warns at 1.25 and at 0.8 times its size. Measured on 300 000
    random sets of 3 of each population (seeds 0-5): 2e-4 warn too large, 1e-3 too small, 1.9e-3
    at 1.25 pass (:mod:`face_tracking_ros.pipelines.face_sizes`).
    """
    sets = []
    for preset, seed, num_nodes in itertools.product(('default', 'realistic'), range(3), (19, 34)):
        population = FacePopulation(preset, seed)
        sequences = [
            MeshSequence(
                f'subject_{index}',
                population.nodes(population.subject(index), {})[None, :num_nodes],
                np.ones(1, dtype=bool),
            )
            for index in range(60)
        ]
        sets += [sequences[start : start + 3] for start in range(0, 60, 3)]
    assert len(sets) == 240
    assert _warned(sets, 1.0) == 0
    assert _warned(sets, 1.25) == len(sets)
    assert _warned(sets, 0.8) == len(sets)
    two = [group[:2] for group in sets]  # too few subjects to judge
    assert _warned(two, 1.25) == 0
