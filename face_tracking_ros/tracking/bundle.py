"""Photometric bundle adjustment of a track's first views (seed §3.5, eq. 1-3 and 6).

Eq. 6 compares every frame with frame 1, so what the tracker gets wrong about frame 1 stays in
the whole track. Two things are wrong there, and one image cannot tell:

- the skin between the nodes: the ROIs lie on the thin-plate surface through the nodes
  (:mod:`.surface_patches`), which misses the real surface by millimetres around the nose, the
  mouth and the cheeks. Compared across a turn of the head, such a ROI slides over the skin
  and biases the rotation (measured on synthetic faces with an exact model, exact
  initialisation, flat light and no expression: 0.80 / 0.82 degrees of pitch / yaw error on
  average, 0.35 / 0.46 with the true skin);
- the pose and identity sigma fitted to the initialisation's 2-D points alone: 1 px of click
  noise turns a 34-node fit by about 0.6 degrees, and the tracker keeps that offset.

A turning head shows both. :func:`adjustment_stages` takes frame 1 and a few views the track has
reached at distinct rotations and solves, in the manner of direct (photometric) bundle
adjustment, for

- the skin: each ROI sample lies on the ray from frame 1's camera through its template pixel,
  at the depth of frame 1's estimate plus ``sum_j d_ij phi_j(u, v)`` with ``phi = 1, u, v, u^2,
  u v, v^2`` over the ROI's patch coordinates (:func:`surface_basis`); the templates therefore
  stay as sampled, and only how they move in the other views changes;
- each view's (omega, t, alpha), relative to frame 1's estimate;
- frame 1's pose, alpha and sigma anew, from the initialisation's 2-D points and the depth of
  the skin under each node (``d_i0``, the first term) that the views measured: eq. 3's node i
  posed by eq. 1 should lie on its ray at that depth, within ``model_depth_noise``.

The cost, in the tracker's units (squared residuals over the robust scale s):

    sum_(v, i, ROI) rho(I_v(x_i(v)) - T_i)                      (eq. 6 with epsilon = 1)
    + lambda sum_i (e_i - mean_j e_j)^2 / s_d^2,  e_i = r_i' (R X_i + t) - |R_0 X_i^0 + t_0| - d_i0
    + lambda sum_k |pi(R X_k + t) - c_k|^2 / s_c^2                 (the 2-D points c_k)
    + lambda_alpha sum_v alpha_v' Sigma_alpha^-1 alpha_v + lambda_sigma sigma' Sigma_s^-1 sigma
    + lambda sum_(i, j) (d_ij / tau_j)^2                           (skin prior)

with r_i the unit ray to node i of frame 1's estimate (R_0, t_0, X^0); the node depths enter
relative to their mean, since their common part is the single camera's scale. Where the views
do not constrain the skin (a head that has hardly turned), the priors keep it on the thin-plate
surface and frame 1 where the 2-D points put it. The residuals are projected like the tracker's
(:mod:`~face_tracking_ros.imaging.photometric`) and Huber-weighted; the Jacobians are the
tracker's own (:func:`~.mono_kernels.roi_jacobian`). Levenberg-Marquardt on the dense normal
equations: p + 6 N + (6 + q) (V + 1) unknowns, a few hundred; each view's part is one compiled
pass over its samples (:mod:`.bundle_kernels`).

Measured on the mono benchmark's 1000-frame sequences (3 seeds x 3 draws of 1 px click noise,
true model, published pose), the tracker with the adjustment against without: rotation error
1.21 / 1.20 / 0.23 -> 0.60 / 0.77 / 0.15 degrees, translation error in z 5.7 -> 4.5 mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.linalg import LinAlgError
from scipy.linalg import cho_factor, cho_solve

from face_tracking_ros.errors import check_fields
from face_tracking_ros.geometry.rotation import matrix_to_omega, rodrigues
from face_tracking_ros.imaging import (
    GRADIENT_MARGIN,
    inside_xy,
    sample_with_gradient_xy,
    sample_xy,
)
from face_tracking_ros.imaging.photometric import PhotometricInvariance, PhotometricProjection
from face_tracking_ros.tracking.bundle_kernels import add_view_normal_equations
from face_tracking_ros.tracking.mono_kernels import (
    huber_irls,
    roi_jacobian,
    roi_points,
)
from face_tracking_ros.tracking.projection import POSE_DIM
from face_tracking_ros.tracking.stages import Stages

SURFACE_TERMS = 6  # 1, u, v, u^2, u v, v^2
_MAD_TO_STD = 1.4826

Pose = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(omega (3,), t (3,), alpha (q,)) of one view."""


@dataclass(frozen=True)
class BundleConfig:
    """Tunables of the bundle adjustment of the first views.

    Attributes:
        views: most views kept besides frame 1 (>= 0; 0 switches the adjustment off). Each new
            view triggers one adjustment, so this also bounds their number.
        view_spacing: a tracked frame becomes a view when its rotation differs from frame 1's
            and every other view's by more than this, rad (> 0).
        iterations: Levenberg-Marquardt iterations per adjustment (>= 1). The first two steps
            take most of the cost's decrease (78-100 %, median 97 %, of what five take, on the
            mono protocol's tracks), and 2 would cut the adjustments' time by a fifth with the
            34-node rotation errors as they are or lower (true model 0.81 / 0.83 / 0.21 -> 0.78
            / 0.82 / 0.20 degrees, learned 1.58 / 1.27 -> 1.50 / 1.21); but the 19-node mesh's
            error about x grows from 1.37 to 1.81 degrees (mean of the three seeds; seed 1: 1.46,
            2.40, 2.82 with 4, 3, 2 iterations).
        surface_prior: tau of the skin depth's slope and curvature terms: their prior standard
            deviation, i.e. of the depth each adds at the ROI's edge, m (> 0).
        node_depth_prior: tau of the skin depth under the nodes (the constant term), m (> 0).
        model_depth_noise: s_d, how far eq. 3's node may lie from the skin along its ray, m
            (> 0): the model's own error.
        click_noise_px: s_c, standard deviation of the initialisation's 2-D points, px (> 0).
        weight: lambda of the terms above, in units of squared residuals / s^2 like the
            tracker's ``prior_weight`` (> 0): neighbouring ROI samples are far from independent,
            so the photometric term overstates its evidence by about an order of magnitude.
        max_change: an adjustment that turns frame 1 or the newest view by more than this, or
            moves the newest view's nodes in its image by more than such a turn would (and
            2 px), is not applied, rad (> 0): the views did not agree (an occlusion, a fast
            motion, the ambiguous pose of a small face).
        stages_per_frame: how many stages of an adjustment (setting it up, each iteration,
            each pyramid level's new ROIs) run per frame (>= 0), after the frame's result; the
            track continues from it after the frame its last stage ran on, the head's motion
            since its newest view carried over. 0 runs it whole after the frame that starts it,
            which then takes many times a frame's usual time.
    """

    views: int = 8
    view_spacing: float = 0.2
    iterations: int = 5
    surface_prior: float = 0.003
    node_depth_prior: float = 0.005
    model_depth_noise: float = 0.001
    click_noise_px: float = 1.0
    weight: float = 10.0
    max_change: float = 0.1
    stages_per_frame: int = 2

    def __post_init__(self) -> None:
        """Validate every field; the error names the field and its value."""
        check_fields(
            self,
            {
                'views': self.views >= 0,
                'view_spacing': self.view_spacing > 0,
                'iterations': self.iterations >= 1,
                'surface_prior': self.surface_prior > 0,
                'node_depth_prior': self.node_depth_prior > 0,
                'model_depth_noise': self.model_depth_noise > 0,
                'click_noise_px': self.click_noise_px > 0,
                'weight': self.weight > 0,
                'max_change': self.max_change > 0,
                'stages_per_frame': self.stages_per_frame >= 0,
            },
        )

    def surface_weights(self) -> np.ndarray:
        """(SURFACE_TERMS,) lambda / tau^2 of each skin depth term, per m^2."""
        tau = np.full(SURFACE_TERMS, self.surface_prior)
        tau[0] = self.node_depth_prior
        return self.weight / tau**2


class Patches(NamedTuple):
    """The level-0 ROI samples of the track at frame 1's estimate (a :class:`.mono_rois.Roi`).

    Attributes:
        offsets: (3, N, M) offsets from the nodes to their samples at alpha = 0, face frame, m,
            without skin depth.
        action: (q, 3, N, M) their derivative with respect to alpha.
        surface: (SURFACE_TERMS, N, M) float64 the skin depth basis at the samples
            (:func:`surface_basis`; the compiled normal equations take it as it is).
        direction: (3, N, M) unit rays from frame 1's camera centre through the samples, face
            frame: the skin depth moves the samples along them (:func:`skin_offsets`).
    """

    offsets: np.ndarray
    action: np.ndarray
    surface: np.ndarray
    direction: np.ndarray


class Problem(NamedTuple):
    """What stays fixed in an adjustment.

    Attributes:
        camera: (3, 4) projection matrix of level-0 pixels.
        mean_shape: (N, 3) the model's mean shape, m.
        action_nodes: (N, 3, q) the action basis per node.
        shape_nodes: (N, 3, p) the shape basis per node.
        first: frame 1's estimate (omega, t, alpha) before the adjustment: the templates and
            the face frame the views are expressed in.
        first_sigma: (p,) sigma before the adjustment.
        patches: the ROI samples at ``first``.
        node_weights: (N,) weight of each node's ROI (the tracker's edge weight).
        invariance: the photometric invariance of the residuals.
        alpha_precision: (q, q) lambda_alpha Sigma_alpha^-1.
        sigma_precision: (p, p) lambda_sigma Sigma_sigma^-1, or None to hold sigma fixed.
        click_nodes: (K,) indices of the nodes given by the initialisation.
        clicks: (K, 2) their pixels in frame 1.
        config: the weights.
        huber_k: the Huber threshold, in robust standard deviations.
        scale_floor: smallest robust residual scale, grey levels.
    """

    camera: np.ndarray
    mean_shape: np.ndarray
    action_nodes: np.ndarray
    shape_nodes: np.ndarray
    first: Pose
    first_sigma: np.ndarray
    patches: Patches
    node_weights: np.ndarray
    invariance: PhotometricInvariance
    alpha_precision: np.ndarray
    sigma_precision: np.ndarray | None
    click_nodes: np.ndarray
    clicks: np.ndarray
    config: BundleConfig
    huber_k: float
    scale_floor: float

    def nodes(self, sigma: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        """(N, 3) eq. 3's nodes, face frame, m."""
        return self.mean_shape + self.shape_nodes @ sigma + self.action_nodes @ alpha


class Estimate(NamedTuple):
    """The unknowns of an adjustment.

    Attributes:
        sigma: (p,) identity.
        depth: (N, SURFACE_TERMS) skin depth coefficients, m.
        first: frame 1's (omega, t, alpha).
        views: each other view's (omega, t, alpha); in :func:`adjustment_stages`, relative to
            the face frame of ``Problem.first``.
    """

    sigma: np.ndarray
    depth: np.ndarray
    first: Pose
    views: tuple[Pose, ...]


class Adjustment(NamedTuple):
    """Outcome of :func:`adjustment_stages`.

    Attributes:
        estimate: the adjusted unknowns, views in the face frame of the adjusted frame 1 and
            the skin depth relative to its nodes (:func:`rebased`); the start when nothing
            improved.
        initial_cost: the cost at the start.
        cost: the cost at the end.
        iterations: Levenberg-Marquardt iterations run.
    """

    estimate: Estimate
    initial_cost: float
    cost: float
    iterations: int


def surface_basis(grid: np.ndarray) -> np.ndarray:
    """(SURFACE_TERMS, N, M) float64 skin depth basis ``1, u, v, u^2, u v, v^2`` at ROI samples.

    Args:
        grid: (N, M, 2) each sample's patch coordinates (u, v), in units of the ROI's
            half-width (so |u|, |v| <= 1 over an unshifted level-0 ROI).
    """
    u, v = grid[..., 0], grid[..., 1]
    return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v]).astype(float)


def ray_directions(points: np.ndarray, omega: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(..., 3) unit rays, face frame, from the camera of pose (omega, t) to (..., 3) points."""
    rotation = rodrigues(omega)[0]
    rays = points + rotation.T @ t
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def skin_offsets(
    offsets: np.ndarray, surface: np.ndarray, direction: np.ndarray, depth: np.ndarray
) -> np.ndarray:
    """(3, N, M) sample offsets moved by the skin depth along their rays.

    Args:
        offsets: (3, N, M) offsets on the thin-plate surface, m.
        surface: (SURFACE_TERMS, N, M) skin depth basis (:func:`surface_basis`).
        direction: (3, N, M) unit rays from frame 1's camera (:func:`ray_directions`).
        depth: (N, SURFACE_TERMS) skin depth coefficients, m.
    """
    return offsets + direction * np.einsum('jnm,nj->nm', surface, depth)


class _Layout(NamedTuple):
    """Where each unknown sits in the parameter vector."""

    sigma: np.ndarray  # (p,), or (0,) when sigma is held fixed
    depth: np.ndarray  # (N, SURFACE_TERMS)
    first: np.ndarray  # (6 + q,)
    views: np.ndarray  # (V - 1, 6 + q)

    @classmethod
    def of(cls, problem: Problem, views: int) -> _Layout:
        """The layout for ``views`` views besides frame 1."""
        p, q = problem.shape_nodes.shape[2], problem.action_nodes.shape[2]
        free = p if problem.sigma_precision is not None else 0
        nodes = problem.mean_shape.shape[0]
        depth = free + np.arange(nodes * SURFACE_TERMS).reshape(nodes, SURFACE_TERMS)
        first = free + depth.size + np.arange(POSE_DIM + q)
        others = first[-1] + 1 + np.arange(views * (POSE_DIM + q)).reshape(views, POSE_DIM + q)
        return cls(np.arange(free), depth, first, others)

    @property
    def size(self) -> int:
        """Number of unknowns."""
        return int(self.sigma.size + self.depth.size + self.first.size + self.views.size)


class _Template(NamedTuple):
    """Frame 1's samples of the ROIs at its estimate, fixed during an adjustment."""

    values: np.ndarray  # (N, M)
    inside: np.ndarray  # (N, M) bool
    projection: PhotometricProjection  # of ``values``


class _Posed(NamedTuple):
    """Frame 1's nodes posed by eq. 1 with their derivatives."""

    points: np.ndarray  # (N, 3) camera frame, m
    jacobian: np.ndarray  # (N, 3, 6 + q + p) d points / d(omega, t, alpha, sigma)


def adjustment_stages(
    problem: Problem,
    images: list[np.ndarray],
    visibility: list[np.ndarray],
    start: Estimate,
) -> Stages[Adjustment]:
    """Levenberg-Marquardt on the bundle cost from ``start`` (``problem.config.iterations``).

    Staged (:mod:`.stages`): the first stage sets the adjustment up and linearises it at
    ``start``; each further one is one iteration: a damped step and the cost at its end, then,
    when the cost is lower and another iteration follows, the normal equations there from the
    same samples of the views (a rejected or last step needs none). The images must stay
    unchanged until it returns.

    Args:
        problem: what stays fixed.
        images: V (H, W) float32 level-0 images, frame 1 first.
        visibility: V (N,) node visibility weights, frame 1 first.
        start: the tracker's estimates (``start.first`` equal to ``problem.first``).

    Returns:
        The adjustment (:func:`rebased` estimate); the start when no step lowered the cost.
    """
    solve, views = _Solve.of(problem, images, visibility, start)
    estimate, damping = start, 1e-3
    evaluation = solve.evaluate(estimate, views)
    hessian, gradient = solve.normal_equations(estimate, evaluation)
    cost = initial = evaluation.cost
    done = 0
    while done < problem.config.iterations:
        done += 1
        yield
        try:
            step = _damped_step(hessian, gradient, damping)
        except LinAlgError:
            break
        trial = _updated(estimate, solve.layout, step)
        evaluation = solve.evaluate(trial)
        if not np.isfinite(evaluation.cost) or evaluation.cost >= cost:
            damping *= 10.0
            if damping > 1e3:
                break
            continue
        converged = cost - evaluation.cost < 1e-4 * cost
        estimate, cost = trial, evaluation.cost
        damping = max(0.1 * damping, 1e-9)
        if converged or done == problem.config.iterations:
            break
        hessian, gradient = solve.normal_equations(estimate, evaluation)
    if cost >= initial:
        return Adjustment(start, initial, initial, done)
    return Adjustment(rebased(problem, estimate), initial, cost, done)


def _damped_step(hessian: np.ndarray, gradient: np.ndarray, damping: float) -> np.ndarray:
    """Levenberg-Marquardt step ``-(H + lambda diag H)^-1 g`` by a Jacobi-scaled Cholesky.

    The tracker's compiled :func:`~.mono_kernels.damped_step` does the same for its dozen
    unknowns; for the few hundred here LAPACK's blocked factorisation is much faster.

    Raises:
        LinAlgError: if H or g is not finite, or the damped matrix is not positive definite.
    """
    if not (np.all(np.isfinite(hessian)) and np.all(np.isfinite(gradient))):
        raise LinAlgError('non-finite normal equations')
    scaling = 1.0 / np.sqrt(np.maximum(np.diag(hessian), 1e-12))
    # Built in LAPACK's (Fortran) order, in place: cho_factor then factors it where it lies
    # instead of copying it, and no second temporary is made (the same products, bit for bit).
    scaled = np.multiply(hessian, scaling[:, None], order='F')
    scaled *= scaling[None, :]
    scaled[np.diag_indices_from(scaled)] += damping
    factor = cho_factor(scaled, overwrite_a=True, check_finite=False)
    return -scaling * cho_solve(factor, scaling * gradient, check_finite=False)


def rebased(problem: Problem, estimate: Estimate) -> Estimate:
    """The views in the face frame of the adjusted frame 1; the skin depth from its nodes.

    A point P' of the adjusted frame 1's face frame (pose R, t) is ``P = R_0' (R P' + t - t_0)``
    in the face frame of ``problem.first`` (R_0, t_0), so a view's pose (R_v, t_v) becomes
    ``(R_v R_0' R, R_v R_0' (t - t_0) + t_v)``. The node depths are measured from frame 1's
    nodes before the adjustment; from the adjusted nodes, along the same rays, they are what the
    model did not explain.
    """
    omega, t, _ = estimate.first
    old_rotation = rodrigues(problem.first[0])[0]
    change = old_rotation.T @ rodrigues(omega)[0]
    views = []
    for view_omega, view_t, view_alpha in estimate.views:
        view_rotation = rodrigues(view_omega)[0]
        moved = view_rotation @ old_rotation.T @ (t - problem.first[1]) + view_t
        views.append((matrix_to_omega(view_rotation @ change), moved, view_alpha))
    depth = estimate.depth.copy()
    depth[:, 0] -= _node_depths(problem, estimate)
    return Estimate(estimate.sigma, depth, estimate.first, tuple(views))


def _node_depths(problem: Problem, estimate: Estimate) -> np.ndarray:
    """(N,) how far along its ray each adjusted node lies beyond frame 1's node before, m."""
    omega, t, alpha = estimate.first
    rays, distances = _rays(problem)
    posed = problem.nodes(estimate.sigma, alpha) @ rodrigues(omega)[0].T + t
    return np.einsum('na,na->n', rays, posed) - distances


def _rays(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (N, 3, camera frame) to frame 1's nodes before the adjustment, and distances."""
    omega, t, alpha = problem.first
    posed = problem.nodes(problem.first_sigma, alpha) @ rodrigues(omega)[0].T + t
    distances = np.linalg.norm(posed, axis=1)
    return posed / distances[:, None], distances


def _updated(estimate: Estimate, layout: _Layout, step: np.ndarray) -> Estimate:
    """The estimate moved by a solver step."""

    def moved(pose: Pose, index: np.ndarray) -> Pose:
        omega, t, alpha = pose
        return omega + step[index[:3]], t + step[index[3:POSE_DIM]], alpha + step[index[POSE_DIM:]]

    sigma = estimate.sigma + step[layout.sigma] if layout.sigma.size else estimate.sigma
    return Estimate(
        sigma,
        estimate.depth + step[layout.depth],
        moved(estimate.first, layout.first),
        tuple(moved(v, i) for v, i in zip(estimate.views, layout.views, strict=True)),
    )


def _template(problem: Problem, image: np.ndarray) -> _Template:
    """Frame 1's samples at its estimate (the skin depth moves them along their rays only)."""
    omega, t, alpha = problem.first
    shape = problem.nodes(problem.first_sigma, alpha)
    _, (x, y) = _points(problem, rodrigues(omega)[0], shape, t, alpha, problem.patches.offsets)
    values = sample_xy(image, x, y)
    inside = inside_xy(x, y, image.shape, margin=GRADIENT_MARGIN)
    return _Template(values, inside, problem.invariance.projection(values))


def _points(
    problem: Problem,
    rotation: np.ndarray,
    shape: np.ndarray,
    t: np.ndarray,
    alpha: np.ndarray,
    offsets: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``R P`` (3, N, M) of a view's ROI samples in frame 1's old face frame and their pixels.

    Args:
        problem: the problem.
        rotation: (3, 3) the view's R(omega).
        shape: (N, 3) eq. 3's nodes at its alpha (frame 1's sigma), face frame.
        t: (3,) its translation.
        alpha: (q,) its alpha.
        offsets: (3, N, M) the samples' offsets from their nodes at alpha = 0, on the skin
            (:func:`skin_offsets`).
    """
    return roi_points(
        rotation,
        np.ascontiguousarray(shape),
        np.asarray(t, dtype=float),
        problem.camera,
        offsets,
        problem.patches.action,
        np.asarray(alpha, dtype=float),
        np.zeros((0, *offsets.shape)),
        np.zeros(0),
    )


class _ViewSamples(NamedTuple):
    """A view's samples at an estimate and what its Jacobian needs (:func:`_view_residuals`).

    Attributes:
        residuals: (N, M) projected residuals.
        inside: (N, M) sample mask.
        rotated: (3, N, M) ``R P`` of the samples.
        gradient: (2, N, M) the image gradient at them.
        rotation: (3, 3) R(omega) of the view.
        d_rotation: (3, 3, 3) its derivatives dR / d omega_k.
        shape: (N, 3) eq. 3's nodes at the view's alpha, face frame.
    """

    residuals: np.ndarray
    inside: np.ndarray
    rotated: np.ndarray
    gradient: np.ndarray
    rotation: np.ndarray
    d_rotation: np.ndarray
    shape: np.ndarray


def _view_residuals(
    problem: Problem, template: _Template, image: np.ndarray, pose: Pose, offsets: np.ndarray
) -> _ViewSamples:
    """A view's projected residuals (N, M), its sample mask and what its Jacobian needs.

    ``offsets``: (3, N, M) the samples' offsets on the skin, as :func:`_points` takes them.
    """
    omega, t, alpha = pose
    rotation, d_rotation = rodrigues(omega)
    shape = problem.nodes(problem.first_sigma, alpha)
    rotated, (x, y) = _points(problem, rotation, shape, t, alpha, offsets)
    values, gradient = sample_with_gradient_xy(image, x, y)
    residuals = template.projection.apply(values - template.values)
    inside = inside_xy(x, y, image.shape, margin=GRADIENT_MARGIN) & template.inside
    return _ViewSamples(residuals, inside, rotated, gradient, rotation, d_rotation, shape)


class _Bases(NamedTuple):
    """What moves a view's samples besides its pose, for :func:`~.mono_kernels.roi_jacobian`."""

    nodes: np.ndarray  # (N, 3, q + 1): the action basis per node, and nothing for the skin
    samples: np.ndarray  # (q + 1, 3, N, M): the ROI offsets' action basis, and their rays

    @classmethod
    def of(cls, problem: Problem) -> _Bases:
        """The bases of ``problem`` (alpha, then the skin depth along the rays)."""
        nodes = len(problem.mean_shape)
        return cls(
            np.concatenate([problem.action_nodes, np.zeros((nodes, 3, 1))], axis=2),
            np.concatenate([problem.patches.action, problem.patches.direction[None]]),
        )


def _view_jacobian(
    problem: Problem, bases: _Bases, view: _ViewSamples, t: np.ndarray
) -> np.ndarray:
    """(6 + q + 1, N, M) derivative of a view's samples: pose, alpha, skin depth along rays."""
    jacobian, _ = roi_jacobian(
        view.rotated,
        np.ascontiguousarray(view.rotation @ view.shape.T),
        np.asarray(t, dtype=float),
        problem.camera,
        view.gradient,
        view.rotation,
        view.d_rotation,
        bases.nodes,
        bases.samples,
    )
    return jacobian


class _Evaluation(NamedTuple):
    """The bundle cost at an estimate, with what its normal equations need.

    Attributes:
        cost: the cost.
        views: each other view's samples there.
        irls: each other view's (N, M) IRLS weights over s^2.
        hessian: the (halved) Hessian of the node depth, 2-D point and prior terms.
        gradient: their (halved) gradient.
    """

    cost: float
    views: list[_ViewSamples]
    irls: list[np.ndarray]
    hessian: np.ndarray
    gradient: np.ndarray


class _Solve(NamedTuple):
    """What stays fixed while an adjustment runs, and the cost and normal equations it needs.

    Attributes:
        problem: the problem.
        layout: where each unknown sits.
        template: frame 1's samples.
        images: the other views' (H, W) float32 images.
        weights: each other view's (N,) node weights (ROI weight, visibility in both views).
        bases: what moves the samples besides the pose.
        scale: the robust residual scale s of the start, grey levels.
    """

    problem: Problem
    layout: _Layout
    template: _Template
    images: list[np.ndarray]
    weights: list[np.ndarray]
    bases: _Bases
    scale: float

    @classmethod
    def of(
        cls,
        problem: Problem,
        images: list[np.ndarray],
        visibility: list[np.ndarray],
        start: Estimate,
    ) -> tuple[_Solve, list[_ViewSamples]]:
        """The fixed part of an adjustment from ``start`` (the scale: 1.4826 MAD there).

        Returns:
            It and its views' samples at ``start``.
        """
        template = _template(problem, images[0])
        weights = [problem.node_weights * visibility[0] * v for v in visibility[1:]]
        layout = _Layout.of(problem, len(images) - 1)
        solve = cls(problem, layout, template, images[1:], weights, _Bases.of(problem), 1.0)
        views = solve._views(start)
        active = [
            np.abs(residuals[(weight[:, None] * inside) > 0])
            for (residuals, inside, *_), weight in zip(views, weights, strict=True)
        ]
        values = np.concatenate(active) if active else np.zeros(0)
        spread = _MAD_TO_STD * float(np.median(values)) if values.size else 0.0
        return solve._replace(scale=max(problem.scale_floor, spread)), views

    def _views(self, estimate: Estimate) -> list[_ViewSamples]:
        """Each other view's residuals, sample mask and Jacobian inputs at ``estimate``."""
        patches = self.problem.patches
        offsets = skin_offsets(patches.offsets, patches.surface, patches.direction, estimate.depth)
        return [
            _view_residuals(self.problem, self.template, image, pose, offsets)
            for image, pose in zip(self.images, estimate.views, strict=True)
        ]

    def _robust(
        self, residuals: np.ndarray, inside: np.ndarray, weight: np.ndarray
    ) -> tuple[np.ndarray, float]:
        """IRLS weights over s^2 (N, M) and Huber cost of one view's residuals."""
        sample_weights = np.ascontiguousarray(weight[:, None] * inside, dtype=float)
        irls, cost = huber_irls(residuals, sample_weights, self.scale, self.problem.huber_k)
        return irls.reshape(residuals.shape) / self.scale**2, cost

    def evaluate(self, estimate: Estimate, views: list[_ViewSamples] | None = None) -> _Evaluation:
        """The bundle cost at ``estimate``, and the model terms' part of its normal equations.

        ``views``: the views' samples there, when already taken (:meth:`of`).
        """
        views = self._views(estimate) if views is None else views
        irls, cost = [], 0.0
        for (residuals, inside, *_), weight in zip(views, self.weights, strict=True):
            view_irls, data_cost = self._robust(residuals, inside, weight)
            irls.append(view_irls)
            cost += data_cost
        hessian = np.zeros((self.layout.size, self.layout.size))
        gradient = np.zeros(self.layout.size)
        cost += self._model_terms(estimate, hessian, gradient)
        return _Evaluation(cost, views, irls, hessian, gradient)

    def normal_equations(
        self, estimate: Estimate, evaluation: _Evaluation
    ) -> tuple[np.ndarray, np.ndarray]:
        """(Halved) Hessian and gradient of the bundle cost at ``estimate``.

        The views' terms are added to ``evaluation``'s (its arrays, in place).
        """
        problem, layout = self.problem, self.layout
        hessian, gradient = evaluation.hessian, evaluation.gradient
        for view, irls, (_, t, _), index in zip(
            evaluation.views, evaluation.irls, estimate.views, layout.views, strict=True
        ):
            jacobian = _view_jacobian(problem, self.bases, view, t)
            add_view_normal_equations(
                jacobian,
                problem.patches.surface,
                self.template.projection.basis_rows,
                irls,
                view.residuals,
                int(index[0]),
                int(layout.depth[0, 0]),
                hessian,
                gradient,
            )
        return hessian, gradient

    def _model_terms(self, estimate: Estimate, hessian: np.ndarray, gradient: np.ndarray) -> float:
        """Add the node depth, 2-D point and prior terms to the normal equations; their cost."""
        problem, layout = self.problem, self.layout
        posed = _posed(problem, estimate)
        return (
            _node_depth_term(problem, layout, estimate, posed, hessian, gradient)
            + _click_term(problem, layout, posed, hessian, gradient)
            + _priors(problem, layout, estimate, hessian, gradient)
        )


def _posed(problem: Problem, estimate: Estimate) -> _Posed:
    """Frame 1's adjusted nodes in the camera frame and their derivative (eq. 1, 3)."""
    omega, t, alpha = estimate.first
    rotation, d_rotation = rodrigues(omega)
    nodes = problem.nodes(estimate.sigma, alpha)
    d_omega = np.einsum('kab,nb->nak', d_rotation, nodes)
    d_t = np.broadcast_to(np.eye(3), (len(nodes), 3, 3))
    d_alpha = np.einsum('ab,nbq->naq', rotation, problem.action_nodes)
    d_sigma = np.einsum('ab,nbp->nap', rotation, problem.shape_nodes)
    return _Posed(nodes @ rotation.T + t, np.concatenate([d_omega, d_t, d_alpha, d_sigma], axis=2))


def _first_columns(layout: _Layout, jacobian: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices and (..., columns) of a Jacobian over (omega, t, alpha, sigma) of frame 1."""
    local = layout.first.size
    if not layout.sigma.size:
        return layout.first, jacobian[..., :local]
    return np.concatenate([layout.first, layout.sigma]), jacobian


def _node_depth_term(
    problem: Problem,
    layout: _Layout,
    estimate: Estimate,
    posed: _Posed,
    hessian: np.ndarray,
    gradient: np.ndarray,
) -> float:
    """Add the node depths' term to the normal equations; its cost.

    ``lambda / s_d^2 sum_i (e_i - mean(e))^2`` with ``e_i = r_i' X_i - distance_i - d_i0``: the
    nodes' depths relative to each other. Their common part is a single camera's scale (a face
    twice the size twice as far looks the same in every view), which the views do not measure;
    it stays with the 2-D points and the sigma prior, as in the fit to the points alone
    (measured on the mono protocol: translation error in z 5.6 -> 4.5 mm with the mean removed).
    """
    rays, distances = _rays(problem)
    error = np.einsum('na,na->n', rays, posed.points) - distances - estimate.depth[:, 0]
    index, block = _first_columns(layout, np.einsum('na,nak->nk', rays, posed.jacobian))
    depth = layout.depth[:, 0]
    jacobian = np.hstack([block, -np.eye(len(error))])
    error = error - error.mean()
    jacobian = jacobian - jacobian.mean(axis=0)
    columns = np.concatenate([index, depth])
    weight = problem.config.weight / problem.config.model_depth_noise**2
    hessian[np.ix_(columns, columns)] += weight * jacobian.T @ jacobian
    gradient[columns] += weight * jacobian.T @ error
    return float(weight * error @ error)


def _click_term(
    problem: Problem, layout: _Layout, posed: _Posed, hessian: np.ndarray, gradient: np.ndarray
) -> float:
    """Add ``lambda / s_c^2 |pi(R X_k + t) - c_k|^2`` of the 2-D points; their cost."""
    if not problem.click_nodes.size:
        return 0.0
    points = posed.points[problem.click_nodes]
    homogeneous = points @ problem.camera[:, :3].T + problem.camera[:, 3]
    pixels = homogeneous[:, :2] / homogeneous[:, 2:]
    # d pixel / d X_c = (P_(1,2) - x P_3) / h_3
    d_pixels = (
        problem.camera[None, :2, :3] - pixels[:, :, None] * problem.camera[None, 2:3, :3]
    ) / homogeneous[:, 2, None, None]
    full = np.einsum('kab,kbc->kac', d_pixels, posed.jacobian[problem.click_nodes])
    index, block = _first_columns(layout, full.reshape(-1, full.shape[-1]))
    error = (pixels - problem.clicks).ravel()
    weight = problem.config.weight / problem.config.click_noise_px**2
    hessian[np.ix_(index, index)] += weight * block.T @ block
    gradient[index] += weight * block.T @ error
    return float(weight * error @ error)


def _priors(
    problem: Problem,
    layout: _Layout,
    estimate: Estimate,
    hessian: np.ndarray,
    gradient: np.ndarray,
) -> float:
    """Add the alpha, sigma and skin depth priors to the normal equations; their cost."""
    cost = 0.0
    poses = (estimate.first, *estimate.views)
    for index, (_, _, alpha) in zip((layout.first, *layout.views), poses, strict=True):
        rows = index[POSE_DIM:]
        hessian[np.ix_(rows, rows)] += problem.alpha_precision
        gradient[rows] += problem.alpha_precision @ alpha
        cost += float(alpha @ problem.alpha_precision @ alpha)
    if layout.sigma.size:
        hessian[np.ix_(layout.sigma, layout.sigma)] += problem.sigma_precision
        gradient[layout.sigma] += problem.sigma_precision @ estimate.sigma
        cost += float(estimate.sigma @ problem.sigma_precision @ estimate.sigma)
    flat = layout.depth.ravel()
    weights = np.broadcast_to(problem.config.surface_weights(), estimate.depth.shape).ravel()
    hessian[flat, flat] += weights
    gradient[flat] += weights * estimate.depth.ravel()
    cost += float(weights @ estimate.depth.ravel() ** 2)
    return cost
