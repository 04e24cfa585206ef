"""Photometric bundle adjustment of a track's first views (seed §3.5, eq. 1-3 and 6).

Eq. 6 compares every frame with frame 1, so what the tracker gets wrong about frame 1 stays in
the whole track. Two things are wrong there, and one image cannot tell:

- the pose and identity sigma fitted to the initialisation's 2-D points (1 px of click noise
  turns a 34-node fit by about 0.6 degrees, and the tracker keeps that offset);
- the skin between the nodes: the ROIs lie on the thin-plate surface through the nodes
  (:mod:`.surface_patches`), which misses the real surface by millimetres around the nose, the
  mouth and the cheeks. Compared across a turn of the head, such a ROI slides over the skin
  and biases the rotation by up to a degree (measured on synthetic faces with an exact model,
  exact initialisation and flat light: 0.8 degrees per axis on average, 0.2 with the true skin).

A turning head shows both: seen from several directions, the skin around each node is where its
appearance in every view agrees. :func:`adjust` solves for them jointly, over frame 1 and a few
views the track has already reached at distinct rotations:

    min  sum_(v, i, ROI) rho(I_v(x_i(v)) - I_1(x_i(1)))                      (eq. 6, epsilon = 1)
         + lambda (sum_v alpha_v' Sigma_alpha^-1 alpha_v + sigma' Sigma_sigma^-1 sigma)   (§4.1)
         + lambda sum_i |x_i(1) - c_i|^2 / s_c^2                               (the 2-D points)
         + lambda sum_(i, j) (d_ij / tau)^2                                    (skin prior)

over sigma, each view's (omega, t, alpha) (frame 1's included) and the skin depth d: each ROI
sample moves along the face frame's z by ``sum_j d_ij phi_j(u, v)``, a quadratic in the sample's
patch coordinates without the constant term (:func:`surface_basis`), so the node itself stays on
eq. 3's mesh and the model alone places it. With the nodes tied to the model, the views fix frame
1's pose (a rigid motion of the skin is not a motion of the mesh), while the initialisation's
points anchor it where the head has not turned enough to tell. Only the face's size against its
distance stays with the sigma prior, as in any single camera.

The residuals are projected like the tracker's (:mod:`~face_tracking_ros.imaging.photometric`),
Huber-weighted, and the Jacobians are the tracker's own (:func:`~.mono_kernels.roi_jacobian`),
with the template's gradient for frame 1's side. Levenberg-Marquardt on the dense normal equations
(a few hundred unknowns: p + 5 N + 6 + q per view) takes a few milliseconds per iteration.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.linalg import LinAlgError

from face_tracking_ros.errors import check_fields
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging import PhotometricInvariance, inside_xy, sample_with_gradient_xy
from face_tracking_ros.tracking.mono_kernels import damped_step, huber_irls, roi_jacobian, roi_points
from face_tracking_ros.tracking.projection import POSE_DIM

SURFACE_TERMS = 6  # 1, u, v, u^2, u v, v^2
_MAD_TO_STD = 1.4826


@dataclass(frozen=True)
class BundleConfig:
    """Tunables of the bundle adjustment of the first views.

    Attributes:
        views: most views kept besides frame 1 (>= 0; 0 switches the adjustment off). Each new
            view triggers one adjustment, so this also bounds their number.
        view_spacing: a tracked frame becomes a view when its rotation differs from frame 1's
            and every other view's by more than this, rad (> 0).
        iterations: Levenberg-Marquardt iterations per adjustment (>= 1).
        surface_prior: tau, the prior standard deviation of each skin depth coefficient, i.e.
            of the depth at the ROI's edge per term, m (> 0).
        click_noise_px: standard deviation of the initialisation's 2-D points, px (> 0).
        weight: lambda of the 2-D points' and the skin prior's terms, in units of squared
            residuals / s^2 like the tracker's ``prior_weight`` (> 0): neighbouring ROI samples
            are far from independent, so the photometric term overstates its evidence.
    """

    views: int = 8
    view_spacing: float = 0.1
    iterations: int = 10
    surface_prior: float = 0.003
    click_noise_px: float = 1.0
    node_depth_prior: float = 0.005
    weight: float = 10.0
    first_fixed: bool = False

    def __post_init__(self) -> None:
        """Validate every field; the error names the field and its value."""
        check_fields(
            self,
            {
                'views': self.views >= 0,
                'view_spacing': self.view_spacing > 0,
                'iterations': self.iterations >= 1,
                'surface_prior': self.surface_prior > 0,
                'click_noise_px': self.click_noise_px > 0,
                'node_depth_prior': self.node_depth_prior > 0,
                'weight': self.weight > 0,
            },
        )


class View(NamedTuple):
    """One image of the track and its estimate.

    Attributes:
        image: (H, W) float32 full-resolution image (the tracker's pyramid level 0).
        omega: (3,) rotation vector, rad.
        t: (3,) translation, m.
        alpha: (q,) expression.
        visibility: (N,) node visibility weights at this estimate.
    """

    image: np.ndarray
    omega: np.ndarray
    t: np.ndarray
    alpha: np.ndarray
    visibility: np.ndarray


class Patches(NamedTuple):
    """The level-0 ROI samples of the track (the tracker's ``_Roi`` of level 0).

    Attributes:
        offsets: (3, N, M) offsets from the nodes to their samples at alpha = 0 and ``sigma``,
            face frame, m, without skin depth.
        action: (q, 3, N, M) their derivative with respect to alpha.
        identity: (p, 3, N, M) their derivative with respect to sigma.
        sigma: (p,) the sigma of ``offsets``.
        surface: (SURFACE_TERMS, N, M) the skin depth basis at the samples
            (:func:`surface_basis`).
        direction: (N, 3) unit vector, face frame, along which each node's skin depth moves its
            samples: the ray from frame 1's camera to the node, so that frame 1's view of the
            samples (the templates) does not change with the depth.
    """

    offsets: np.ndarray
    action: np.ndarray
    identity: np.ndarray
    sigma: np.ndarray
    surface: np.ndarray
    direction: np.ndarray


class Problem(NamedTuple):
    """What stays fixed in an adjustment.

    Attributes:
        camera: (3, 4) projection matrix of level-0 pixels.
        mean_shape: (N, 3) the model's mean shape, m.
        action_nodes: (N, 3, q) the action basis per node.
        shape_nodes: (N, 3, p) the shape basis per node.
        patches: the ROI samples.
        node_weights: (N,) weight of each node's ROI (the tracker's edge weight).
        invariance: the photometric invariance of the residuals.
        alpha_precision: (q, q) lambda Sigma_alpha^-1.
        sigma_precision: (p, p) lambda Sigma_sigma^-1, or None to hold sigma fixed.
        first_fixed: hold frame 1's (omega, t, alpha) fixed.
        click_nodes: (K,) indices of the nodes given by the initialisation.
        clicks: (K, 2) their pixels in frame 1.
        click_weight: lambda / s_c^2, per px^2.
        surface_weight: (SURFACE_TERMS,) lambda / tau^2 of each skin depth term, per m^2.
        huber_k: the Huber threshold, in robust standard deviations.
        scale_floor: smallest robust residual scale, grey levels.
    """

    camera: np.ndarray
    mean_shape: np.ndarray
    action_nodes: np.ndarray
    shape_nodes: np.ndarray
    patches: Patches
    node_weights: np.ndarray
    invariance: PhotometricInvariance
    alpha_precision: np.ndarray
    sigma_precision: np.ndarray | None
    first_fixed: bool
    click_nodes: np.ndarray
    clicks: np.ndarray
    click_weight: float
    surface_weight: np.ndarray
    huber_k: float
    scale_floor: float


class Estimate(NamedTuple):
    """The unknowns of an adjustment.

    Attributes:
        sigma: (p,) identity.
        depth: (N, SURFACE_TERMS) skin depth coefficients, m.
        views: per view (frame 1 first): (omega, t, alpha).
    """

    sigma: np.ndarray
    depth: np.ndarray
    views: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]


class Adjustment(NamedTuple):
    """Outcome of :func:`adjust`.

    Attributes:
        estimate: the adjusted unknowns (the start when nothing improved).
        initial_cost: the cost at the start.
        cost: the cost at ``estimate``.
        iterations: Levenberg-Marquardt iterations run.
    """

    estimate: Estimate
    initial_cost: float
    cost: float
    iterations: int


def surface_basis(grid: np.ndarray) -> np.ndarray:
    """(SURFACE_TERMS, N, M) skin depth basis ``1, u, v, u^2, u v, v^2`` at ROI samples.

    Args:
        grid: (N, M, 2) each sample's patch coordinates (u, v), in units of the ROI's
            half-width (so |u|, |v| <= 1 over an unshifted level-0 ROI).
    """
    u, v = grid[..., 0], grid[..., 1]
    return np.ascontiguousarray(np.stack([np.ones_like(u), u, v, u * u, u * v, v * v]))


def skin_offsets(patches: Patches, depth: np.ndarray) -> np.ndarray:
    """(3, N, M) sample offsets with the skin depth ``depth`` (N, SURFACE_TERMS) applied."""
    along = np.einsum('jnm,nj->nm', patches.surface, depth)
    return patches.offsets + patches.direction.T[:, :, None] * along


class _Sampled(NamedTuple):
    """One view's samples of its ROIs, their Jacobian and the node pixels."""

    values: np.ndarray  # (N, M)
    inside: np.ndarray  # (N, M) bool
    jacobian: np.ndarray  # (6 + q + p + 1, N, M): pose, alpha, sigma, skin depth along z
    node_jacobian: np.ndarray  # (2 N, 6 + q + p + 1)
    nodes_px: np.ndarray  # (N, 2)


class _Layout(NamedTuple):
    """Where each unknown sits in the parameter vector."""

    sigma: np.ndarray  # (p,) or (0,)
    depth: np.ndarray  # (N, SURFACE_TERMS)
    views: list[np.ndarray]  # per view (6 + q,), or (0,) for a view held fixed

    @property
    def size(self) -> int:
        """Number of unknowns."""
        return int(self.sigma.size + self.depth.size + sum(v.size for v in self.views))


def adjust(
    problem: Problem, images: list[np.ndarray], visibility: list[np.ndarray], start: Estimate,
    iterations: int,
) -> Adjustment:
    """Levenberg-Marquardt on the bundle cost from ``start``.

    Args:
        problem: what stays fixed.
        images: V (H, W) float32 images, frame 1 first.
        visibility: V (N,) node visibility weights, frame 1 first.
        start: the tracker's estimates.
        iterations: most iterations.

    Returns:
        The adjustment; its estimate is ``start`` when no step lowered the cost.
    """
    p, q = problem.shape_nodes.shape[2], problem.action_nodes.shape[2]
    layout = _layout(problem, len(images), p, q)
    weights = [problem.node_weights * visibility[0] * v for v in visibility[1:]]
    estimate, damping = start, 1e-3
    sampled = [_sample(problem, image, estimate, view) for view, image in enumerate(images)]
    scale = _scale(problem, sampled, weights)
    cost, hessian, gradient = _normal_equations(problem, layout, estimate, sampled, weights, scale)
    initial, done = cost, 0
    for done in range(1, iterations + 1):
        try:
            step = damped_step(hessian, gradient, damping)
        except LinAlgError:
            break
        trial = _updated(estimate, layout, step)
        trial_sampled = [_sample(problem, image, trial, view) for view, image in enumerate(images)]
        trial_cost, trial_hessian, trial_gradient = _normal_equations(
            problem, layout, trial, trial_sampled, weights, scale
        )
        if not np.isfinite(trial_cost) or trial_cost >= cost:
            damping *= 10.0
            if damping > 1e3:
                break
            continue
        converged = cost - trial_cost < 1e-6 * cost
        estimate, cost, hessian, gradient = trial, trial_cost, trial_hessian, trial_gradient
        damping = max(0.1 * damping, 1e-9)
        if converged:
            break
    return Adjustment(estimate, initial, cost, done)


def _layout(problem: Problem, views: int, p: int, q: int) -> _Layout:
    """Indices of sigma (if free), the skin depth and each view's (omega, t, alpha)."""
    free = p if problem.sigma_precision is not None else 0
    nodes = problem.mean_shape.shape[0]
    depth = free + np.arange(nodes * SURFACE_TERMS).reshape(nodes, SURFACE_TERMS)
    first = free + depth.size
    held = 1 if problem.first_fixed else 0
    moving = first + np.arange((views - held) * (POSE_DIM + q)).reshape(-1, POSE_DIM + q)
    return _Layout(np.arange(free), depth, [np.zeros(0, int)] * held + list(moving))


def _updated(estimate: Estimate, layout: _Layout, step: np.ndarray) -> Estimate:
    """The estimate moved by a solver step."""
    sigma = estimate.sigma + step[layout.sigma] if layout.sigma.size else estimate.sigma
    views = tuple(
        (omega + step[index[:3]], t + step[index[3:POSE_DIM]], alpha + step[index[POSE_DIM:]])
        if index.size
        else (omega, t, alpha)
        for (omega, t, alpha), index in zip(estimate.views, layout.views, strict=True)
    )
    return Estimate(sigma, estimate.depth + step[layout.depth], views)


def _sample(problem: Problem, image: np.ndarray, estimate: Estimate, view: int) -> _Sampled:
    """Samples of one view's ROIs at the estimate, with their Jacobian (eq. 1-3)."""
    omega, t, alpha = estimate.views[view]
    patches = problem.patches
    rotation, d_rotation = rodrigues(omega)
    shape = (
        problem.mean_shape
        + problem.shape_nodes @ estimate.sigma
        + problem.action_nodes @ alpha
    )
    rotated, (x, y) = roi_points(
        rotation,
        np.ascontiguousarray(shape),
        np.asarray(t, dtype=float),
        problem.camera,
        skin_offsets(patches, estimate.depth),
        patches.action,
        np.asarray(alpha, dtype=float),
        patches.identity,
        estimate.sigma - patches.sigma,
    )
    values, gradient = sample_with_gradient_xy(image, x, y)
    nodes = shape.shape[0]
    along = np.broadcast_to(patches.direction.T[None, :, :, None], (1, 3, *x.shape))
    node_basis = np.concatenate(
        [problem.action_nodes, problem.shape_nodes, np.zeros((nodes, 3, 1))], axis=2
    )
    jacobian, node_jacobian = roi_jacobian(
        rotated,
        np.ascontiguousarray(rotation @ shape.T),
        np.asarray(t, dtype=float),
        problem.camera,
        gradient,
        rotation,
        d_rotation,
        np.ascontiguousarray(node_basis),
        np.ascontiguousarray(np.concatenate([patches.action, patches.identity, along])),
    )
    camera_nodes = shape @ rotation.T + t
    homogeneous = camera_nodes @ problem.camera[:, :3].T + problem.camera[:, 3]
    return _Sampled(
        values,
        inside_xy(x, y, image.shape, margin=1.0),
        jacobian,
        node_jacobian,
        homogeneous[:, :2] / homogeneous[:, 2:],
    )


def _scale(problem: Problem, sampled: list[_Sampled], weights: list[np.ndarray]) -> float:
    """The robust residual scale of the start: 1.4826 MAD of the weighted residuals."""
    projection = problem.invariance.projection(sampled[0].values)
    active = [
        np.abs(projection.apply(view.values - sampled[0].values))[
            (weight[:, None] * view.inside * sampled[0].inside) > 0
        ]
        for view, weight in zip(sampled[1:], weights, strict=True)
    ]
    values = np.concatenate(active) if active else np.zeros(0)
    spread = _MAD_TO_STD * float(np.median(values)) if values.size else 0.0
    return max(problem.scale_floor, spread)


def _normal_equations(
    problem: Problem,
    layout: _Layout,
    estimate: Estimate,
    sampled: list[_Sampled],
    weights: list[np.ndarray],
    scale: float,
) -> tuple[float, np.ndarray, np.ndarray]:
    """Cost, (halved) Hessian and gradient of the bundle cost at ``estimate``."""
    p, q = problem.shape_nodes.shape[2], problem.action_nodes.shape[2]
    hessian = np.zeros((layout.size, layout.size))
    gradient = np.zeros(layout.size)
    first = sampled[0]
    projection = problem.invariance.projection(first.values)
    local = POSE_DIM + q
    sigma_rows = slice(local, local + p)
    cost = 0.0
    for view, (other, weight) in enumerate(zip(sampled[1:], weights, strict=True), start=1):
        residuals = projection.apply(other.values - first.values)
        sample_weights = np.ascontiguousarray(weight[:, None] * other.inside * first.inside)
        irls, data_cost = huber_irls(residuals, sample_weights, scale, problem.huber_k)
        cost += data_cost
        irls = irls.reshape(residuals.shape) / scale**2
        dense = [other.jacobian[:local]]
        columns = [layout.views[view]]
        if layout.views[0].size:
            dense.append(-first.jacobian[:local])
            columns.append(layout.views[0])
        if layout.sigma.size:
            dense.append(other.jacobian[sigma_rows] - first.jacobian[sigma_rows])
            columns.append(layout.sigma)
        dense_rows = projection.apply(np.concatenate(dense))
        depth_change = other.jacobian[-1] - first.jacobian[-1]
        depth_rows = projection.apply(problem.patches.surface * depth_change)
        _accumulate(
            hessian,
            gradient,
            np.concatenate(columns),
            dense_rows,
            layout.depth,
            depth_rows,
            residuals,
            irls,
        )
    cost += _clicks(problem, layout, first, hessian, gradient)
    cost += _priors(problem, layout, estimate, hessian, gradient)
    return cost, hessian, gradient


def _accumulate(
    hessian: np.ndarray,
    gradient: np.ndarray,
    dense_index: np.ndarray,
    dense: np.ndarray,
    depth_index: np.ndarray,
    depth: np.ndarray,
    residuals: np.ndarray,
    irls: np.ndarray,
) -> None:
    """Add one view's ``J' W J`` and ``J' W r``; the skin depth columns act on one node each.

    Args:
        hessian, gradient: the normal equations, added to in place.
        dense_index: (D,) parameters of the (D, N, M) rows ``dense`` (every node's samples).
        depth_index: (N, SURFACE_TERMS) parameters of the (SURFACE_TERMS, N, M) rows ``depth``
            (node n's coefficients act on node n's samples only).
        residuals: (N, M) projected residuals.
        irls: (N, M) IRLS weights over s^2.
    """
    weighted_dense, weighted_depth = dense * irls, depth * irls
    hessian[np.ix_(dense_index, dense_index)] += np.einsum('anm,bnm->ab', weighted_dense, dense)
    cross = np.einsum('anm,jnm->anj', weighted_dense, depth).reshape(len(dense_index), -1)
    flat_depth = depth_index.ravel()
    hessian[np.ix_(dense_index, flat_depth)] += cross
    hessian[np.ix_(flat_depth, dense_index)] += cross.T
    blocks = np.einsum('jnm,knm->njk', weighted_depth, depth)
    hessian[depth_index[:, :, None], depth_index[:, None, :]] += blocks
    gradient[dense_index] += np.einsum('anm,nm->a', weighted_dense, residuals)
    gradient[flat_depth] += np.einsum('jnm,nm->nj', weighted_depth, residuals).ravel()


def _clicks(
    problem: Problem, layout: _Layout, first: _Sampled, hessian: np.ndarray, gradient: np.ndarray
) -> float:
    """Add the initialisation's 2-D points to the normal equations; their cost."""
    if not problem.click_nodes.size:
        return 0.0
    if not layout.views[0].size and not layout.sigma.size:
        return 0.0
    p, q = problem.shape_nodes.shape[2], problem.action_nodes.shape[2]
    error = (first.nodes_px[problem.click_nodes] - problem.clicks).ravel()
    rows = np.stack([2 * problem.click_nodes, 2 * problem.click_nodes + 1], axis=1).ravel()
    jacobian = first.node_jacobian[rows]
    index, blocks = [], []
    if layout.views[0].size:
        index.append(layout.views[0])
        blocks.append(jacobian[:, : POSE_DIM + q])
    if layout.sigma.size:
        index.append(layout.sigma)
        blocks.append(jacobian[:, POSE_DIM + q : POSE_DIM + q + p])
    index_all, block = np.concatenate(index), np.concatenate(blocks, axis=1)
    weight = problem.click_weight
    hessian[np.ix_(index_all, index_all)] += weight * block.T @ block
    gradient[index_all] += weight * block.T @ error
    return float(weight * error @ error)


def _priors(
    problem: Problem, layout: _Layout, estimate: Estimate, hessian: np.ndarray, gradient: np.ndarray
) -> float:
    """Add the alpha, sigma and skin depth priors to the normal equations; their cost."""
    cost = 0.0
    for index, (_, _, alpha) in zip(layout.views, estimate.views, strict=True):
        if not index.size:
            continue
        rows = index[POSE_DIM:]
        hessian[np.ix_(rows, rows)] += problem.alpha_precision
        gradient[rows] += problem.alpha_precision @ alpha
        cost += float(alpha @ problem.alpha_precision @ alpha)
    if layout.sigma.size:
        hessian[np.ix_(layout.sigma, layout.sigma)] += problem.sigma_precision
        gradient[layout.sigma] += problem.sigma_precision @ estimate.sigma
        cost += float(estimate.sigma @ problem.sigma_precision @ estimate.sigma)
    flat = layout.depth.ravel()
    weights = np.broadcast_to(problem.surface_weight, estimate.depth.shape).ravel()
    hessian[flat, flat] += weights
    gradient[flat] += weights * estimate.depth.ravel()
    cost += float(weights @ estimate.depth.ravel() ** 2)
    return cost
