"""Weighted rigid Procrustes and generalised Procrustes against known transforms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.procrustes import (
    generalized_procrustes,
    rigid_align,
    rigid_rotation,
)
from face_tracking_ros.model.topology import Group, mesh_topology


def _random_poses(rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
    rotations = Rotation.from_rotvec(rng.normal(scale=0.4, size=(count, 3))).as_matrix()
    translations = rng.normal(scale=0.1, size=(count, 3))
    return rotations, translations


def test_recovers_known_transform_exactly():
    rng = np.random.default_rng(0)
    face = mesh_topology(34).reference_shape
    rotations, translations = _random_poses(rng, 5)
    moved = np.einsum('fab,nb->fna', rotations, face) + translations[:, None, :]
    result = rigid_align(face, moved)
    assert np.allclose(result.rotation, rotations, atol=1e-12)
    assert np.allclose(result.t, translations, atol=1e-12)
    assert np.allclose(result.aligned, moved, atol=1e-12)
    assert np.all(result.rms < 1e-12)


def test_identical_meshes_give_identity_transform():
    face = mesh_topology(19).reference_shape
    result = rigid_align(face, face)
    assert np.allclose(result.rotation, np.eye(3), atol=1e-14)
    assert np.allclose(result.t, 0.0, atol=1e-14)


def test_weighted_rotation_matches_scipy_align_vectors():
    rng = np.random.default_rng(1)
    topology = mesh_topology(34)
    weights = topology.alignment_weights()
    source = topology.reference_shape + rng.normal(scale=0.004, size=(34, 3))
    rotation, _ = _random_poses(rng, 1)
    target = source @ rotation[0].T + 0.02 + rng.normal(scale=0.004, size=(34, 3))
    result = rigid_align(source, target, weights)
    w = weights / weights.sum()
    centred_source = source - w @ source
    centred_target = target - w @ target
    expected, _ = Rotation.align_vectors(centred_target, centred_source, weights=weights)
    assert np.allclose(result.rotation, expected.as_matrix(), atol=1e-10)
    assert np.allclose(result.t, w @ target - result.rotation @ (w @ source), atol=1e-12)


def test_reflected_target_still_gives_a_rotation():
    """The best rotation, not merely a rotation: d flips the smallest singular direction."""
    face = mesh_topology(34).reference_shape
    mirrored = face * np.array([-1.0, 1.0, 1.0])
    result = rigid_align(face, mirrored)
    assert np.allclose(np.linalg.det(result.rotation), 1.0)
    assert np.allclose(result.rotation @ result.rotation.T, np.eye(3), atol=1e-12)
    # scipy's Kabsch excludes reflections too; its root sum of squared distances gives the RMS
    # over the 34 equally weighted nodes (measured 28.6 mm: a mirror image is no rotation).
    centred_face, centred_mirror = face - face.mean(axis=0), mirrored - mirrored.mean(axis=0)
    expected, rssd = Rotation.align_vectors(centred_mirror, centred_face)
    assert np.allclose(result.rotation, expected.as_matrix(), atol=1e-12)
    assert result.rms == pytest.approx(rssd / np.sqrt(34), rel=1e-12)
    assert result.rms > 0.01


def test_zero_weight_nodes_do_not_move_the_alignment():
    rng = np.random.default_rng(2)
    topology = mesh_topology(34)
    face = topology.reference_shape
    weights = topology.alignment_weights()
    mouth = topology.group_mask(Group.MOUTH)
    weights[mouth] = 0.0
    rotations, translations = _random_poses(rng, 1)
    target = face @ rotations[0].T + translations[0]
    target[mouth] += rng.normal(scale=0.02, size=(int(mouth.sum()), 3))
    result = rigid_align(face, target, weights)
    assert np.allclose(result.rotation, rotations[0], atol=1e-12)
    assert np.allclose(result.t, translations[0], atol=1e-12)
    # The RMS is weighted too: the moved mouth nodes are 11 mm or more off (15 mm RMS over all
    # 34 nodes), yet count nothing.
    assert np.linalg.norm(result.aligned - target, axis=1)[mouth].min() > 0.01
    assert result.rms < 1e-12


def test_batched_equals_pairwise():
    rng = np.random.default_rng(3)
    sources = rng.normal(scale=0.05, size=(4, 19, 3))
    targets = rng.normal(scale=0.05, size=(4, 19, 3))
    batched = rigid_align(sources, targets)
    for k in range(4):
        single = rigid_align(sources[k], targets[k])
        assert np.allclose(batched.rotation[k], single.rotation, atol=1e-12)
        assert np.allclose(batched.rms[k], single.rms, atol=1e-12)


def test_rigid_rotation_is_rigid_aligns_rotation_to_the_bit():
    rng = np.random.default_rng(3)
    source = rng.normal(size=(4, 34, 3))
    target = source @ Rotation.random(4, random_state=3).as_matrix() + rng.normal(size=(4, 1, 3))
    weights = mesh_topology(34).alignment_weights()
    for pair in ((source[0], target[0]), (source, target)):
        assert np.array_equal(rigid_rotation(*pair, weights), rigid_align(*pair, weights).rotation)
    with pytest.raises(InputError, match='NaN'):
        rigid_rotation(np.full((3, 3), np.nan), source[0, :3])


def test_generalized_procrustes_aligns_moved_copies_to_the_reference():
    rng = np.random.default_rng(4)
    topology = mesh_topology(34)
    face = topology.reference_shape
    rotations, translations = _random_poses(rng, 30)
    noise = rng.normal(scale=0.0005, size=(30, 34, 3))
    meshes = np.einsum('fab,fnb->fna', rotations, face + noise) + translations[:, None, :]
    result = generalized_procrustes(meshes, topology.alignment_weights(), reference=face)
    assert result.converged
    assert result.iterations <= 10
    # Every aligned mesh is its noisy copy of the face, up to the noise level.
    assert np.abs(result.aligned - (face + noise)).max() < 0.002
    assert np.sqrt(np.mean(np.sum((result.mean - face) ** 2, axis=1))) < 0.0003
    undone = np.einsum('fab,fnb->fna', result.rotation, meshes) + result.t[:, None, :]
    assert np.allclose(undone, result.aligned, atol=1e-12)


def test_generalized_procrustes_keeps_the_mean_in_the_reference_pose():
    """Each pass aligns the mean back onto the reference, so the mean's pose cannot drift.

    With noise as large as an expression (20 mm) the mean's shape differs from the reference;
    its best rigid transform onto it is the identity (measured 1e-8 degrees; a mean left where
    the meshes' alignment put it drifts 0.044 degrees and 8 um).
    """
    rng = np.random.default_rng(8)
    topology = mesh_topology(34)
    face, weights = topology.reference_shape, topology.alignment_weights()
    rotations, translations = _random_poses(rng, 5)
    noisy = face + rng.normal(scale=0.02, size=(5, 34, 3))
    meshes = np.einsum('fab,fnb->fna', rotations, noisy) + translations[:, None, :]
    result = generalized_procrustes(meshes, weights, reference=face)
    assert result.converged
    gauge = rigid_align(result.mean, face, weights)
    assert gauge.rms > 0.005
    np.testing.assert_allclose(gauge.rotation, np.eye(3), rtol=0, atol=1e-7)
    np.testing.assert_allclose(gauge.t, 0.0, rtol=0, atol=1e-9)


def test_generalized_procrustes_defaults_to_first_mesh_gauge():
    rng = np.random.default_rng(5)
    face = mesh_topology(19).reference_shape
    rotations, translations = _random_poses(rng, 6)
    meshes = np.einsum('fab,nb->fna', rotations, face) + translations[:, None, :]
    result = generalized_procrustes(meshes)
    assert np.allclose(result.mean, meshes[0], atol=1e-9)
    assert np.allclose(result.aligned, meshes[0], atol=1e-9)


@pytest.mark.parametrize(
    ('source', 'target', 'weights', 'match'),
    [
        (np.zeros((19, 2)), np.zeros((19, 3)), None, r'source must have shape'),
        (np.zeros((19, 3)), np.zeros((34, 3)), None, r'source has 19 nodes but target has 34'),
        (np.full((19, 3), np.nan), np.zeros((19, 3)), None, r'source holds NaN'),
        (np.zeros((19, 3)), np.full((19, 3), np.inf), None, r'target holds NaN or Inf'),
        (np.zeros((19, 3)), np.zeros((19, 3)), -np.ones(19), r'non-negative'),
        (np.zeros((19, 3)), np.zeros((19, 3)), np.ones(18), r'weights must be 19'),
        (np.zeros((19, 3)), np.zeros((19, 3)), np.eye(19)[0] + np.eye(19)[1], r'at least 3'),
    ],
)
def test_rigid_align_rejects_bad_input(source, target, weights, match):
    with pytest.raises(InputError, match=match):
        rigid_align(source, target, weights)


def test_generalized_procrustes_rejects_a_single_mesh_without_stack():
    with pytest.raises(InputError, match=r'non-empty \(F, N, 3\) stack'):
        generalized_procrustes(np.zeros((19, 3)))


def test_generalized_procrustes_of_exact_copies_converges_on_its_first_pass():
    # The first target (the first mesh) is already the mean: one pass, however many meshes.
    rng = np.random.default_rng(6)
    face = mesh_topology(19).reference_shape
    rotations, translations = _random_poses(rng, 4)
    meshes = np.einsum('fab,nb->fna', rotations, face) + translations[:, None, :]
    for stack in (meshes, meshes[:1]):
        result = generalized_procrustes(stack)
        assert (result.iterations, result.converged) == (1, True)
        np.testing.assert_allclose(result.mean, meshes[0], atol=1e-12)


def test_generalized_procrustes_stops_after_max_iterations_unconverged():
    rng = np.random.default_rng(7)
    face = mesh_topology(19).reference_shape
    rotations, translations = _random_poses(rng, 5)
    noisy = face + rng.normal(scale=0.001, size=(5, 19, 3))
    meshes = np.einsum('fab,fnb->fna', rotations, noisy) + translations[:, None, :]
    for max_iterations in (1, 2):
        result = generalized_procrustes(meshes, max_iterations=max_iterations)
        assert (result.iterations, result.converged) == (max_iterations, False)
        # Even unconverged, the meshes are aligned to the mean returned, not to the target of
        # the last pass (measured 1.4e-7 off the identity after one pass; 2.8e-4 to the last
        # target's alignment).
        onto_mean = rigid_align(result.aligned, result.mean)
        np.testing.assert_allclose(onto_mean.rotation - np.eye(3), 0.0, rtol=0, atol=1e-5)
        np.testing.assert_allclose(onto_mean.t, 0.0, rtol=0, atol=1e-6)
    assert generalized_procrustes(meshes).converged


def test_generalized_procrustes_rejects_an_empty_stack():
    with pytest.raises(InputError, match=r'non-empty \(F, N, 3\) stack, got shape \(0, 19, 3\)'):
        generalized_procrustes(np.zeros((0, 19, 3)))
