"""The regularisation terms of eq. 5 that keep the stereo-tracked mesh whole (seed §3.3).

For the nodes X_c^i(n) of frame n (left camera frame, metres), with dX^i = X^i(n) - X^i(n-1):

    E_reg = sum_i rho_i ||dX^i||^2
          + sum_(i,j) beta_ij ||dX^i - dX^j||^2
          + sum_(i,j) delta_ij (||X^i - X^j||^2 - ||X^i(1) - X^j(1)||^2)^2

over the edges (i, j) of the mesh triangulation. The terms are written as least-squares residuals
``r`` with ``E_reg = r . r`` so a Gauss-Newton solver can stack them with the image terms of eq. 4.

Units: image terms are sums of squared grey levels, so rho and beta are in grey^2 / m^2. The raw
delta_ij of eq. 5 is in grey^2 / m^4; it is set from a stiffness ``delta`` in grey^2 / m^2 as
``delta_ij = delta * s_ij / (2 L_ij)^2`` with L_ij the frame-1 edge length, so that a stretch dL
of any edge costs about ``delta * s_ij * dL^2`` whatever the edge length.

Stiffness per node and edge comes from the anatomical group (:class:`~.topology.Group`): rigid
parts (eyes, eye corners, nose) are stiff, lips and brows soft, as §3.3 prescribes (an edge takes
the softer of its two nodes).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from face_tracking_ros.errors import FieldError, InputError, check_fields
from face_tracking_ros.model.topology import Group, MeshTopology
from face_tracking_ros.tracking.block_assembly import scatter_blocks, scatter_vectors


@dataclass(frozen=True)
class RegularisationConfig:
    """Weights of eq. 5 (plain numbers, so each is a ROS parameter of the stereo node).

    Attributes:
        rho: rho_i of the stiffest nodes: cost of a node's motion, grey^2 / m^2, >= 0.
        beta: beta_ij of the stiffest edges: cost of differential motion, grey^2 / m^2, >= 0.
        delta: stiffness of the stiffest edges against stretching from frame 1, grey^2 / m^2,
            >= 0 (delta_ij = delta * s_ij / (2 L_ij)^2, see the module docstring). 0 by default:
            the stereo tracker's face-model term keeps the mesh whole, and every expression
            stretches edges from frame 1 (on 380-frame training sequences 2e7 raised the largest
            reprojection error from 1.48 / 1.36 to 1.93 / 1.62 px).
        eye: stiffness factor s in [0, 1] of the eye-centre nodes.
        eye_corner: stiffness factor of the eye-corner nodes.
        nose: stiffness factor of the nose nodes.
        edge: stiffness factor of the face-edge nodes (jaw and chin move with the mouth).
        brow: stiffness factor of the eyebrow nodes. beta's cost of differential motion held a
            fast frown's inner brow back (0.5 px a frame: 1.35 px behind on one of issue 5's
            populations, 19 nodes); 0.1 against 0.2 cuts that to 1.03 px and the population's
            largest reprojection error to 1.18 px, and moves three others by 0.01 px at most.
        mouth: stiffness factor of the lip and mouth-corner nodes (the softest, §3.3).
    """

    rho: float = 1e6
    beta: float = 2e7
    delta: float = 0.0
    eye: float = 1.0
    eye_corner: float = 1.0
    nose: float = 1.0
    edge: float = 0.5
    brow: float = 0.1
    mouth: float = 0.05

    def __post_init__(self) -> None:
        """Validate the weights.

        Raises:
            ConfigError: for a negative or non-finite weight (naming it, e.g. 'invalid
                RegularisationConfig.delta = nan, expected a finite number'), or a factor
                outside [0, 1].
        """
        check_fields(
            self, {'rho': self.rho >= 0, 'beta': self.beta >= 0, 'delta': self.delta >= 0}
        )
        bad = {g.value: s for g, s in self.group_stiffness().items() if not 0.0 <= s <= 1.0}
        if bad:
            msg = f'group stiffness factors must lie in [0, 1], got {bad}'
            raise FieldError(msg, next(iter(bad)), 'in [0, 1]')

    def group_stiffness(self) -> dict[Group, float]:
        """The stiffness factor s of every anatomical group.

        rho_i (the node's group) and beta_ij, delta_ij (the softer of the two nodes' groups) are
        the base weights times s.
        """
        return {group: float(getattr(self, group.value)) for group in Group}


@dataclass(frozen=True)
class Regulariser:
    """Eq. 5 for one tracking run: weights fixed at frame 1.

    Attributes:
        edges: (E, 2) node index pairs (i, j).
        rho: (N,) rho_i, grey^2 / m^2.
        beta: (E,) beta_ij, grey^2 / m^2.
        delta: (E,) delta_ij of eq. 5, grey^2 / m^4.
        stretch_stiffness: (E,) delta times the edge's stiffness factor s_ij, grey^2 / m^2.
        first_sq_lengths: (E,) ||X^i(1) - X^j(1)||^2, m^2.
        linear_jacobian: (3N + 3E, 3N) constant Jacobian of the rho and beta residuals.
        linear_hessian: (3N, 3N) its J^T J.
    """

    edges: np.ndarray
    rho: np.ndarray
    beta: np.ndarray
    delta: np.ndarray
    stretch_stiffness: np.ndarray
    first_sq_lengths: np.ndarray
    linear_jacobian: np.ndarray
    linear_hessian: np.ndarray

    @classmethod
    def build(
        cls, topology: MeshTopology, config: RegularisationConfig, first_nodes: np.ndarray
    ) -> Regulariser:
        """Per-node and per-edge weights of eq. 5 for a mesh whose frame-1 nodes are given.

        Args:
            topology: the mesh topology (its edges and node groups).
            config: the base weights and group stiffness.
            first_nodes: (N, 3) nodes X_c(1) of frame 1, m.

        Raises:
            InputError: if first_nodes is not a finite (N, 3) array or has coincident edge nodes.
        """
        first_nodes = np.asarray(first_nodes, dtype=float)
        if first_nodes.shape != (topology.num_nodes, 3) or not np.all(np.isfinite(first_nodes)):
            msg = f'first_nodes must be finite ({topology.num_nodes}, 3), got {first_nodes.shape}'
            raise InputError(msg)
        edges = np.asarray(topology.edges)
        factors = config.group_stiffness()
        stiffness = np.array([factors[g] for g in topology.groups])
        edge_stiffness = np.minimum(stiffness[edges[:, 0]], stiffness[edges[:, 1]])
        rho = config.rho * stiffness
        beta = config.beta * edge_stiffness
        linear = _linear_jacobian(edges, rho, beta)
        stretch_stiffness = config.delta * edge_stiffness
        sq_lengths = _sq_lengths(edges, first_nodes)
        return cls(
            edges=edges,
            rho=rho,
            beta=beta,
            delta=stretch_stiffness / (4.0 * sq_lengths),
            stretch_stiffness=stretch_stiffness,
            first_sq_lengths=sq_lengths,
            linear_jacobian=linear,
            linear_hessian=linear.T @ linear,
        )

    def moved(self, first_nodes: np.ndarray) -> Regulariser:
        """The same weights for other frame-1 nodes (N, 3), m: only the delta terms change.

        Raises:
            InputError: if first_nodes has coincident edge nodes.
        """
        sq_lengths = _sq_lengths(self.edges, first_nodes)
        return replace(
            self, delta=self.stretch_stiffness / (4.0 * sq_lengths), first_sq_lengths=sq_lengths
        )

    @cached_property
    def stretches(self) -> bool:
        """Whether any delta term is on (with delta = 0, the default, they all vanish)."""
        return bool(np.any(self.delta))

    def residuals(self, nodes: np.ndarray, previous: np.ndarray) -> np.ndarray:
        """Residual vector r of eq. 5 with E_reg = r . r.

        Args:
            nodes: (N, 3) X_c(n), m.
            previous: (N, 3) X_c(n-1), m.

        Returns:
            (3N + 3E + E,) residuals: rho terms, beta terms, delta terms, grey levels.
        """
        stretch, _ = self._stretch(nodes)
        return np.concatenate([self.linear_jacobian @ (nodes - previous).ravel(), stretch])

    def jacobian(self, nodes: np.ndarray) -> np.ndarray:
        """Dense Jacobian dr/dX of :meth:`residuals`, (3N + 4E, 3N), node-major columns."""
        _, gradient = self._stretch(nodes)
        i, j = self.edges[:, 0], self.edges[:, 1]
        rows = np.arange(self.edges.shape[0])[:, None]
        stretch_jacobian = np.zeros((self.edges.shape[0], nodes.size))
        stretch_jacobian[rows, 3 * i[:, None] + np.arange(3)] = gradient
        stretch_jacobian[rows, 3 * j[:, None] + np.arange(3)] = -gradient
        return np.vstack([self.linear_jacobian, stretch_jacobian])

    def cost(self, nodes: np.ndarray, previous: np.ndarray) -> float:
        """E_reg of eq. 5 for nodes (N, 3) and previous nodes (N, 3), m."""
        motion = (nodes - previous).ravel()
        cost = motion @ self.linear_hessian @ motion
        if not self.stretches:
            return float(cost)
        stretch, _ = self._stretch(nodes)
        return float(cost + stretch @ stretch)

    def normal_equations(
        self, nodes: np.ndarray, previous: np.ndarray
    ) -> tuple[float, np.ndarray, np.ndarray]:
        """Gauss-Newton terms of eq. 5 at the current nodes.

        The rho and beta residuals are linear in the motion, so their share of J^T J is the
        constant :attr:`linear_hessian` and their share of J^T r is that matrix times the motion.
        Each delta residual depends on two nodes only; its share is accumulated by 3x3 blocks.

        Args:
            nodes: (N, 3) X_c(n), m.
            previous: (N, 3) X_c(n-1), m.

        Returns:
            ``(cost, hessian, gradient)``: E_reg; J^T J (3N, 3N); J^T r (3N,), node-major.
        """
        motion = (nodes - previous).ravel()
        linear_gradient = self.linear_hessian @ motion
        if not self.stretches:
            return float(motion @ linear_gradient), self.linear_hessian, linear_gradient
        stretch, gradient = self._stretch(nodes)
        cost = float(motion @ linear_gradient + stretch @ stretch)
        n = nodes.shape[0]
        i, j = self.edges[:, 0], self.edges[:, 1]
        outer = gradient[:, :, None] * gradient[:, None, :]
        blocks = np.stack([outer, outer, -outer, -outer])
        hessian = self.linear_hessian + scatter_blocks(
            np.stack([i, j, i, j]), np.stack([i, j, j, i]), blocks, n
        )
        pull = stretch[:, None] * gradient
        node_gradient = scatter_vectors(np.stack([i, j]), np.stack([pull, -pull]), n)
        return cost, hessian, linear_gradient + node_gradient

    def _stretch(self, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The delta residuals (E,) and their gradient (E, 3) with respect to X^i (-X^j)."""
        i, j = self.edges[:, 0], self.edges[:, 1]
        differences = nodes[i] - nodes[j]
        sqrt_delta = np.sqrt(self.delta)
        squared = np.einsum('ed,ed->e', differences, differences)
        stretch = sqrt_delta * (squared - self.first_sq_lengths)
        return stretch, 2.0 * sqrt_delta[:, None] * differences


def _sq_lengths(edges: np.ndarray, first_nodes: np.ndarray) -> np.ndarray:
    """(E,) squared edge lengths ||X^i(1) - X^j(1)||^2, m^2.

    Raises:
        InputError: if an edge has zero length.
    """
    vectors = first_nodes[edges[:, 0]] - first_nodes[edges[:, 1]]
    sq_lengths = np.einsum('ed,ed->e', vectors, vectors)
    if np.any(sq_lengths <= 0):
        msg = 'first_nodes has two connected nodes at the same position'
        raise InputError(msg)
    return sq_lengths


def _linear_jacobian(edges: np.ndarray, rho: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Constant Jacobian (3N + 3E, 3N) of the rho and beta residuals with respect to dX."""
    n, e = rho.shape[0], edges.shape[0]
    eye = np.eye(3)
    jacobian = np.zeros((n + e, 3, n, 3))
    jacobian[np.arange(n), :, np.arange(n), :] = np.sqrt(rho)[:, None, None] * eye
    sqrt_beta = np.sqrt(beta)[:, None, None] * eye
    jacobian[n + np.arange(e), :, edges[:, 0], :] = sqrt_beta
    jacobian[n + np.arange(e), :, edges[:, 1], :] = -sqrt_beta
    return jacobian.reshape(3 * (n + e), 3 * n)
