"""Tests of the eq. 5 regularisation of the stereo tracker."""

from __future__ import annotations

import numpy as np
import pytest

from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.tracking.regularisation import RegularisationConfig, Regulariser

# The tracker's default leaves the stretch term out (delta = 0); these tests need all three.
ALL_TERMS = RegularisationConfig(delta=2e7)


def _face(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame-1, previous and current 34-node meshes 0.6 m in front of the camera, m."""
    rng = np.random.default_rng(seed)
    first = mesh_topology(34).reference_shape + np.array([0.0, 0.0, 0.6])
    previous = first + rng.normal(0, 0.002, first.shape)
    current = previous + rng.normal(0, 0.002, first.shape)
    return first, previous, current


def test_jacobian_matches_finite_differences() -> None:
    first, previous, current = _face(0)
    regulariser = Regulariser.build(mesh_topology(34), ALL_TERMS, first)
    jacobian = regulariser.jacobian(current)
    step = 1e-7
    numeric = np.empty_like(jacobian)
    for k in range(current.size):
        plus, minus = current.copy().ravel(), current.copy().ravel()
        plus[k] += step
        minus[k] -= step
        numeric[:, k] = (
            regulariser.residuals(plus.reshape(-1, 3), previous)
            - regulariser.residuals(minus.reshape(-1, 3), previous)
        ) / (2 * step)
    scale = np.abs(jacobian).max()
    assert np.abs(numeric - jacobian).max() < 1e-6 * scale


def test_normal_equations_equal_the_stacked_residuals() -> None:
    first, previous, current = _face(1)
    regulariser = Regulariser.build(mesh_topology(34), ALL_TERMS, first)
    residuals = regulariser.residuals(current, previous)
    jacobian = regulariser.jacobian(current)
    cost, hessian, gradient = regulariser.normal_equations(current, previous)
    assert cost == pytest.approx(residuals @ residuals, rel=1e-10)
    assert regulariser.cost(current, previous) == pytest.approx(cost, rel=1e-12)
    assert np.allclose(hessian, jacobian.T @ jacobian, rtol=1e-10, atol=1e-6)
    assert np.allclose(gradient, jacobian.T @ residuals, rtol=1e-10, atol=1e-9)


def test_moved_regulariser_is_the_one_built_on_the_new_first_nodes() -> None:
    """Depth refinement moves frame 1's nodes: the delta terms follow, as if built there."""
    first, previous, current = _face(3)
    topology = mesh_topology(34)
    moved = Regulariser.build(topology, ALL_TERMS, first).moved(current)
    rebuilt = Regulariser.build(topology, ALL_TERMS, current)
    assert np.allclose(moved.delta, rebuilt.delta, rtol=1e-12, atol=0.0)
    assert np.allclose(moved.first_sq_lengths, rebuilt.first_sq_lengths, rtol=1e-12, atol=0.0)
    assert moved.residuals(previous, current) == pytest.approx(
        rebuilt.residuals(previous, current), rel=1e-12, abs=0.0
    )


def test_eq5_values_by_hand() -> None:
    """One edge stretched by dL costs about delta * s * dL^2; a still mesh costs nothing."""
    first, _, _ = _face(2)
    topology = mesh_topology(34)
    config = RegularisationConfig(rho=0.0, beta=0.0, delta=1e8)
    regulariser = Regulariser.build(topology, config, first)
    assert regulariser.normal_equations(first, first)[0] == 0.0
    # Move the chin 1 mm straight down: every edge touching it stretches by dL_e.
    chin = topology.index('chin')
    moved = first.copy()
    moved[chin, 1] += 0.001
    expected = 0.0
    for (i, j), delta_ij in zip(topology.edges, regulariser.delta, strict=True):
        if chin in (i, j):
            length_0 = np.linalg.norm(first[i] - first[j])
            length_1 = np.linalg.norm(moved[i] - moved[j])
            factors = RegularisationConfig().group_stiffness()
            stiffness = min(factors[topology.groups[k]] for k in (i, j))
            assert delta_ij * 4 * length_0**2 == pytest.approx(1e8 * stiffness)
            expected += 1e8 * stiffness * (length_1 - length_0) ** 2
    cost = regulariser.normal_equations(moved, first)[0]
    assert cost == pytest.approx(expected, rel=0.05)


def test_eq5_motion_terms_by_hand() -> None:
    """rho_i ||dX^i||^2 and beta_ij ||dX^i - dX^j||^2, from the configured weights by hand.

    A shift of the whole mesh costs the rho terms alone (no differential motion); one node
    moved by d costs its rho_i |d|^2 plus beta_ij |d|^2 for each edge it has.
    """
    first, _, _ = _face(5)
    topology = mesh_topology(34)
    config = RegularisationConfig(rho=3e6, beta=2e7)
    factors = config.group_stiffness()
    stiffness = np.array([factors[g] for g in topology.groups])
    regulariser = Regulariser.build(topology, config, first)
    shift = np.array([0.002, -0.001, 0.0005])
    squared = float(shift @ shift)
    expected = 3e6 * stiffness.sum() * squared
    assert regulariser.cost(first + shift, first) == pytest.approx(expected, rel=1e-12)
    nose = topology.index('nose_tip')
    moved = first.copy()
    moved[nose] += shift
    expected = 3e6 * stiffness[nose] * squared
    for i, j in topology.edges:
        if nose in (i, j):
            expected += 2e7 * min(stiffness[i], stiffness[j]) * squared
    assert regulariser.cost(moved, first) == pytest.approx(expected, rel=1e-12)
    assert regulariser.normal_equations(moved, first)[0] == pytest.approx(expected, rel=1e-12)
    residuals = regulariser.residuals(moved, first)
    assert residuals @ residuals == pytest.approx(expected, rel=1e-12)


def test_rigid_parts_are_stiffer_than_lips() -> None:
    first, _, _ = _face(3)
    topology = mesh_topology(34)
    regulariser = Regulariser.build(topology, RegularisationConfig(), first)
    groups = np.array([g.value for g in topology.groups])
    assert regulariser.rho[groups == 'nose'].min() > regulariser.rho[groups == 'mouth'].max()
    edge_groups = groups[topology.edges]
    lip = np.all(edge_groups == 'mouth', axis=1)
    rigid = np.all(np.isin(edge_groups, ['eye', 'eye_corner', 'nose']), axis=1)
    assert lip.any() and rigid.any()
    assert regulariser.beta[rigid].min() > regulariser.beta[lip].max()


def test_gauss_newton_step_restores_a_translated_mesh_exactly() -> None:
    """A rigid shift leaves the delta terms at zero; rho pulls the mesh back to X(n-1)."""
    first, _, _ = _face(4)
    regulariser = Regulariser.build(mesh_topology(34), ALL_TERMS, first)
    shifted = first + np.array([0.003, -0.001, 0.002])
    cost, hessian, gradient = regulariser.normal_equations(shifted, first)
    assert cost > 0
    step = np.linalg.solve(hessian, -gradient)
    assert np.abs(shifted.ravel() + step - first.ravel()).max() < 1e-12


@pytest.mark.parametrize(
    ('kwargs', 'match'),
    [
        ({'rho': -1.0}, r'^invalid RegularisationConfig.rho = -1.0$'),
        ({'delta': float('nan')}, 'invalid RegularisationConfig.delta = nan, expected a finite'),
        ({'beta': float('inf')}, 'invalid RegularisationConfig.beta = inf, expected a finite'),
        ({'edge': 2.0}, r"must lie in \[0, 1\], got \{'edge': 2.0\}"),
        ({'mouth': -0.1}, r"\{'mouth': -0.1\}"),
    ],
)
def test_config_rejects_bad_weights(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        RegularisationConfig(**kwargs)


def test_build_rejects_bad_nodes() -> None:
    topology = mesh_topology(19)
    with pytest.raises(InputError, match=r'finite \(19, 3\)'):
        Regulariser.build(topology, RegularisationConfig(), np.zeros((34, 3)))
    with pytest.raises(InputError, match='same position'):
        Regulariser.build(topology, RegularisationConfig(), np.zeros((19, 3)))
