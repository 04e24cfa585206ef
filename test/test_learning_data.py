"""Training-set pooling and validation, subspace tools, and the two-stage alignment of §3.3."""

from __future__ import annotations

from learning_population import mesh_sequences
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.geometry.procrustes import rigid_align
from face_tracking_ros.learning.alignment import align_training_set
from face_tracking_ros.learning.subspace import (
    fit_coefficients,
    principal_components,
    scatter,
    subspace_similarity,
)
from face_tracking_ros.learning.training_set import MeshSequence, TrainingSet
from face_tracking_ros.model.topology import Group, mesh_topology
from face_tracking_ros.synthetic.faces import FacePopulation


def _sequence(subject: str, frames: int = 4, nodes: int = 19, **changes) -> MeshSequence:
    fields = {
        'subject_id': subject,
        'meshes': np.tile(mesh_topology(nodes).reference_shape, (frames, 1, 1)),
        'neutral': np.arange(frames) < 2,
        'labels': tuple('neutral' if k < 2 else 'smile' for k in range(frames)),
        'source': f'{subject}.bag',
    }
    fields.update(changes)
    return MeshSequence(**fields)


def test_from_sequences_pools_subjects_and_sequences():
    training = TrainingSet.from_sequences(
        [_sequence('a'), _sequence('b', frames=3), _sequence('a', frames=5)]
    )
    assert training.subject_ids == ('a', 'b')
    assert training.subject_index.tolist() == [0] * 4 + [1] * 3 + [0] * 5
    assert training.sequence_index.tolist() == [0] * 4 + [0] * 3 + [1] * 5
    assert training.sequence_of_frame.tolist() == [0] * 4 + [2] * 3 + [1] * 5
    assert training.sequence_subject.tolist() == [0, 0, 1]
    assert training.labels is not None and training.labels[4] == 'neutral'
    assert training.flat().shape == (12, 57)
    assert training.num_subjects == 2 and training.num_nodes == 19


def test_labels_are_dropped_when_any_sequence_lacks_them():
    training = TrainingSet.from_sequences([_sequence('a'), _sequence('b', labels=None)])
    assert training.labels is None


def test_subject_means_and_without_subject():
    values = np.arange(12.0).reshape(6, 2)
    training = TrainingSet.from_sequences(
        [_sequence('a', frames=2), _sequence('b', frames=3), _sequence('c', frames=1, neutral=[1])]
    )
    assert np.allclose(training.subject_means(values), [[1, 2], [6, 7], [10, 11]])
    mask = np.array([1, 0, 0, 0, 1, 1], dtype=bool)
    assert np.allclose(training.subject_means(values, mask), [[0, 1], [8, 9], [10, 11]])
    reduced = training.without_subject(1)
    assert reduced.subject_ids == ('a', 'c')
    assert reduced.subject_sources == ('a.bag', 'c.bag')
    assert reduced.subject_index.tolist() == [0, 0, 1]
    assert np.array_equal(reduced.meshes, training.meshes[[0, 1, 5]])


@pytest.mark.parametrize(
    ('sequences', 'match'),
    [
        ([], r'no training sequences'),
        (
            [_sequence('a', meshes=np.full((4, 19, 3), np.nan))],
            r"subject 'a' \(a\.bag\): 4 meshes hold NaN or Inf, first at frame 0",
        ),
        ([_sequence('a', meshes=np.zeros((4, 20, 3)))], r"'a'.*20 nodes; supported: \(19, 34\)"),
        ([_sequence('a', meshes=np.zeros((0, 19, 3)))], r'non-empty \(F, N, 3\) stack'),
        (
            [_sequence('a'), _sequence('b', nodes=34)],
            r"different node counts \(subject 'a' \(a\.bag\): 19, subject 'b' \(b\.bag\): 34",
        ),
        (
            [_sequence('a', neutral=np.zeros(4, bool))],
            r"subject 'a' \(a\.bag\) has no neutral frames",
        ),
        ([_sequence('a', neutral=np.ones(3, bool))], r'3 neutral flags for 4 frames'),
        ([_sequence('a', labels=('neutral',))], r'1 label for 4 frames'),
    ],
)
def test_bad_sequences_are_named(sequences, match):
    with pytest.raises(InputError, match=match):
        TrainingSet.from_sequences(sequences)


def test_principal_components_match_svd_and_weights_act_as_repeats():
    rng = np.random.default_rng(0)
    vectors = rng.normal(size=(40, 6)) * np.array([5.0, 3.0, 2.0, 1.0, 0.5, 0.1])
    components = principal_components(vectors, 3)
    _, singular, vt = np.linalg.svd(vectors, full_matrices=False)
    assert np.allclose(components.variances, singular[:3] ** 2 / 40)
    assert subspace_similarity(components.basis, vt[:3].T) == pytest.approx(1.0, abs=1e-12)
    # The documented sign convention: each direction's largest-magnitude entry is positive.
    expected = vt[:3].T * np.sign(vt[:3].T[np.argmax(np.abs(vt[:3]), axis=1), np.arange(3)])
    np.testing.assert_allclose(components.basis, expected, atol=1e-9)
    assert np.all(components.basis[np.argmax(np.abs(components.basis), axis=0), np.arange(3)] > 0)
    assert np.allclose(components.explained, singular[:3] ** 2 / np.sum(singular**2))
    with pytest.raises(ConfigError, match=r'cannot keep 7 principal components of 40 vectors'):
        principal_components(vectors, 7)


def test_scatter_in_blocks_matches_the_direct_sum():
    rng = np.random.default_rng(2)
    count = 150_000  # more than one block of rows
    vectors = rng.normal(size=(count, 3)) + np.array([4.0, -2.0, 1.0])
    weights = rng.uniform(0.1, 2.0, count)
    about = np.array([3.0, -1.0, 0.5])
    centred = vectors - about
    direct = (centred * weights[:, None]).T @ centred
    assert np.allclose(scatter(vectors, weights, about=about), direct, rtol=1e-12)
    centres = np.array([about, -about])
    which = rng.integers(2, size=count)
    offset = vectors - centres[which]
    by_row = scatter(vectors, about=centres, about_index=which)
    assert np.allclose(by_row, offset.T @ offset, rtol=1e-12)


def test_subspace_similarity_values():
    basis = np.eye(5)[:, :2]
    rotated = basis @ Rotation.from_euler('z', 0.3).as_matrix()[:2, :2]
    assert subspace_similarity(basis, rotated) == pytest.approx(1.0)
    assert subspace_similarity(basis, 3.0 * basis[:, ::-1]) == pytest.approx(1.0)
    assert subspace_similarity(basis, np.eye(5)[:, 2:]) == pytest.approx(0.0)
    tilted = np.stack([np.cos(0.4) * np.eye(5)[0] + np.sin(0.4) * np.eye(5)[3], np.eye(5)[1]], 1)
    assert subspace_similarity(basis, tilted) == pytest.approx((np.cos(0.4) ** 2 + 1.0) / 2.0)
    assert subspace_similarity(basis[:, :1], np.eye(5)[:, :3]) == pytest.approx(1.0)
    assert subspace_similarity(np.eye(5)[:, :3], basis[:, :1]) == pytest.approx(1.0 / 3.0)


def test_fit_coefficients_recovers_non_orthogonal_coefficients():
    rng = np.random.default_rng(1)
    bases = rng.normal(size=(30, 4))
    coefficients = rng.normal(size=(7, 4))
    assert np.allclose(fit_coefficients(bases, coefficients @ bases.T), coefficients)
    origin = rng.normal(size=30)
    shifted = coefficients @ bases.T + origin
    assert np.allclose(fit_coefficients(bases, shifted, origin=origin), coefficients)
    assert not np.allclose(fit_coefficients(bases, shifted), coefficients)


@pytest.fixture(scope='module')
def noiseless_sequences() -> tuple[list[MeshSequence], FacePopulation]:
    population = FacePopulation('realistic')
    sequences, _ = mesh_sequences(population, 34, subjects=4, frames=120, noise=0.0)
    return sequences, population


def test_alignment_is_rigid_per_frame_and_puts_neutrals_together(noiseless_sequences):
    sequences, population = noiseless_sequences
    training = TrainingSet.from_sequences(sequences)
    aligned = align_training_set(training)
    # Each frame only moved rigidly.
    assert np.all(rigid_align(training.meshes, aligned.meshes).rms < 1e-12)
    for s in range(training.num_subjects):
        subject = population.subject(s)
        neutral_frames = aligned.meshes[(aligned.subject_index == s) & aligned.neutral]
        # Neutral frames of a subject coincide, and are its true neutral face moved rigidly.
        assert np.abs(neutral_frames - neutral_frames[0]).max() < 1e-9
        assert rigid_align(subject.neutral_nodes, neutral_frames[0]).rms < 1e-9
    # Stage 2: the subjects' neutrals are a generalised-Procrustes fixed point (each neutral is
    # already best aligned to their mean), and the mean is in the face frame.
    topology = mesh_topology(34)
    weights = topology.alignment_weights()
    neutrals = aligned.subject_means(aligned.flat(), aligned.neutral).reshape(-1, 34, 3)
    mean = neutrals.mean(axis=0)
    fit = rigid_align(neutrals, mean, weights)
    assert np.allclose(fit.rotation, np.eye(3), atol=1e-7)
    assert np.allclose(fit.t, 0.0, atol=1e-8)
    assert np.allclose(mean[topology.group_mask(Group.EYE)].mean(axis=0), 0.0, atol=1e-12)
    truth_pose = rigid_align(population.mean_shape.reshape(34, 3), mean, weights)
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(truth_pose.rotation).as_rotvec())) < 1.0
