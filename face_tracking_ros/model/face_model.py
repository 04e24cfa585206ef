"""The face model of eq. 3: X = mean_shape + S sigma + A alpha, with the Gaussian prior of §4.1.

Shapes are flattened node-major: a mesh of N nodes is a (3N,) vector ``[x0, y0, z0, x1, ...]`` in
the face frame (see :mod:`face_tracking_ros.model.topology`), metres. ``shape_basis`` S is (3N, p)
and ``action_basis`` A is (3N, q), each with orthonormal columns.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
import hashlib
from typing import Any

import numpy as np

from face_tracking_ros.errors import ModelFileError
from face_tracking_ros.geometry.distances import rms_spread
from face_tracking_ros.model.topology import MeshTopology, mesh_topology

ORTHONORMALITY_TOLERANCE = 1e-6
COVARIANCE_TOLERANCE = 1e-9  # relative to the largest entry: asymmetry, negative eigenvalues
FACE_SPREAD_M = (0.01, 0.25)  # RMS node distance from the centroid of a mean shape (adults: 0.05)


@dataclass(frozen=True)
class FaceModel:
    """Mean shape, identity and expression bases and their prior (eq. 3, §4.1).

    Attributes:
        node_names: N node names (the topology's order).
        mean_shape: (3N,) mean neutral face, metres.
        shape_basis: (3N, p) identity basis S, orthonormal columns.
        action_basis: (3N, q) expression basis A, orthonormal columns.
        shape_eigenvalues: (p,) variances of sigma over the training subjects, m^2.
        action_eigenvalues: (q,) variances of alpha over the training frames, m^2.
        sigma_prior_covariance: (p, p) Gaussian prior covariance of sigma (§4.1), m^2.
        alpha_prior_covariance: (q, q) Gaussian prior covariance of alpha (§4.1), m^2.
        method: name of the learning method that made the model (e.g. 'seed', 'joint').
        metadata: free JSON-serialisable facts (training set, iterations, date).
    """

    node_names: tuple[str, ...]
    mean_shape: np.ndarray
    shape_basis: np.ndarray
    action_basis: np.ndarray
    shape_eigenvalues: np.ndarray
    action_eigenvalues: np.ndarray
    sigma_prior_covariance: np.ndarray
    alpha_prior_covariance: np.ndarray
    method: str = 'seed'
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Validate shapes, finiteness and orthonormality; errors name the faulty field."""
        validate_model_arrays(self)

    @classmethod
    def from_prior_covariances(
        cls,
        node_names: tuple[str, ...],
        mean_shape: np.ndarray,
        shape_basis: np.ndarray,
        action_basis: np.ndarray,
        sigma_prior_covariance: np.ndarray,
        alpha_prior_covariance: np.ndarray,
        method: str,
        metadata: dict[str, Any] | None = None,
    ) -> FaceModel:
        """A model whose eigenvalues are the diagonals of its prior covariances (§4.1)."""
        return cls(
            node_names=node_names,
            mean_shape=mean_shape,
            shape_basis=shape_basis,
            action_basis=action_basis,
            shape_eigenvalues=np.diag(sigma_prior_covariance).copy(),
            action_eigenvalues=np.diag(alpha_prior_covariance).copy(),
            sigma_prior_covariance=sigma_prior_covariance,
            alpha_prior_covariance=alpha_prior_covariance,
            method=method,
            metadata={} if metadata is None else metadata,
        )

    @property
    def num_nodes(self) -> int:
        """Number of mesh nodes N."""
        return len(self.node_names)

    @property
    def p(self) -> int:
        """Dimension of the identity subspace."""
        return int(self.shape_basis.shape[1])

    @property
    def q(self) -> int:
        """Dimension of the expression subspace."""
        return int(self.action_basis.shape[1])

    @property
    def topology(self) -> MeshTopology:
        """Mesh topology with this model's node count."""
        return mesh_topology(self.num_nodes)

    @cached_property
    def fingerprint(self) -> str:
        """A digest of what gives sigma and alpha their meaning: nodes, mean shape, S and A.

        Files that hold statistics of a model's sigma or alpha (an identity gallery, an
        expression classifier) record it: another model of the same p and q gives its
        parameters another meaning, and the file must not be used with it.
        """
        digest = hashlib.sha256('\n'.join(self.node_names).encode())
        for array in (self.mean_shape, self.shape_basis, self.action_basis):
            digest.update(repr(array.shape).encode())
            digest.update(np.ascontiguousarray(array, dtype='<f8').tobytes())
        return digest.hexdigest()[:16]

    def shape(
        self, sigma: np.ndarray | None = None, alpha: np.ndarray | None = None
    ) -> np.ndarray:
        """Eq. 3: the (N, 3) mesh in the face frame for identity sigma and expression alpha."""
        flat = self.mean_shape.copy()
        if sigma is not None:
            flat += self.shape_basis @ np.asarray(sigma, dtype=float)
        if alpha is not None:
            flat += self.action_basis @ np.asarray(alpha, dtype=float)
        return flat.reshape(-1, 3)

    def identity_shape(self, sigma: np.ndarray) -> np.ndarray:
        """(N, 3) neutral mesh of identity sigma: eq. 3 with alpha = 0."""
        return self.shape(sigma=sigma)

    def action_basis_nodes(self) -> np.ndarray:
        """A reshaped to (N, 3, q): the expression derivative dX_i/d alpha of eq. 3."""
        return self.action_basis.reshape(self.num_nodes, 3, self.q)

    def shape_basis_nodes(self) -> np.ndarray:
        """S reshaped to (N, 3, p): the identity derivative dX_i/d sigma of eq. 3."""
        return self.shape_basis.reshape(self.num_nodes, 3, self.p)


def validate_model_arrays(model: FaceModel) -> None:
    """Check a model's arrays.

    Raises:
        ModelFileError: naming the field that has the wrong shape, NaN, non-orthonormal columns,
            a negative variance, or a prior covariance that is not symmetric positive
            semi-definite.
    """
    n3 = 3 * len(model.node_names)
    if len(model.node_names) not in (19, 34):
        _fail(f'node count is {len(model.node_names)}; supported meshes have 19 or 34 nodes')
    expected_names = mesh_topology(len(model.node_names)).node_names
    differing = [
        f'{given!r} (the topology: {expected!r})'
        for given, expected in zip(model.node_names, expected_names, strict=True)
        if given != expected
    ]
    if differing:
        _fail(f'node names differ from the {len(expected_names)}-node topology: {differing[0]}')
    _check(model.mean_shape, 'mean_shape', (n3,))
    nodes = model.mean_shape.reshape(-1, 3)
    spread = rms_spread(nodes)
    if not FACE_SPREAD_M[0] <= spread <= FACE_SPREAD_M[1]:
        _fail(
            f'mean_shape spans {spread:.3g} m RMS about its centroid, where a face spans about '
            '0.05 m: the model must be in metres'
        )
    _check(model.shape_basis, 'shape_basis', (n3, None))
    _check(model.action_basis, 'action_basis', (n3, None))
    p, q = model.shape_basis.shape[1], model.action_basis.shape[1]
    _check(model.shape_eigenvalues, 'shape_eigenvalues', (p,))
    _check(model.action_eigenvalues, 'action_eigenvalues', (q,))
    _check(model.sigma_prior_covariance, 'sigma_prior_covariance', (p, p))
    _check(model.alpha_prior_covariance, 'alpha_prior_covariance', (q, q))
    for name, basis in (('shape_basis', model.shape_basis), ('action_basis', model.action_basis)):
        gram_error = np.abs(basis.T @ basis - np.eye(basis.shape[1])).max(initial=0.0)
        if gram_error > ORTHONORMALITY_TOLERANCE:
            _fail(f'{name} is not orthonormal (max |B^T B - I| = {gram_error:.2e})')
    for name in ('shape_eigenvalues', 'action_eigenvalues'):
        if np.any(getattr(model, name) < 0.0):
            _fail(f'{name} holds a negative variance')
    for name in ('sigma_prior_covariance', 'alpha_prior_covariance'):
        _check_covariance(getattr(model, name), name)


def _check(array: np.ndarray, name: str, shape: tuple[int | None, ...]) -> None:
    """Raise ModelFileError unless array has the given shape (None = any) and is finite."""
    actual = np.shape(array)
    if len(actual) != len(shape) or any(
        e is not None and a != e for a, e in zip(actual, shape, strict=True)
    ):
        _fail(f'{name} has shape {actual}, expected {shape}')
    if not np.all(np.isfinite(array)):
        _fail(f'{name} holds NaN or Inf')


def _check_covariance(covariance: np.ndarray, name: str) -> None:
    """Raise ModelFileError unless the matrix is symmetric positive semi-definite."""
    scale = np.abs(covariance).max(initial=0.0)
    if np.abs(covariance - covariance.T).max(initial=0.0) > COVARIANCE_TOLERANCE * scale:
        _fail(f'{name} is not symmetric')
    if len(covariance) and np.linalg.eigvalsh(covariance).min() < -COVARIANCE_TOLERANCE * scale:
        _fail(f'{name} is not positive semi-definite')


def _fail(problem: str) -> None:
    """Raise the model validation error."""
    msg = f'invalid face model: {problem}'
    raise ModelFileError(msg)
