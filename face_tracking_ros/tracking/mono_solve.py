"""Eq. 6 solved for one image: Levenberg-Marquardt, coarse to fine (seed §3.5, §4.1).

The solve minimises, over (omega, t, alpha) and while it is estimated sigma, eq. 6 plus the
§4.1/§4.4 Gaussian priors ``lambda alpha' Sigma_alpha^-1 alpha`` (and ``lambda sigma'
Sigma_sigma^-1 sigma``, :class:`~.mono_priors.Priors`):

- Both terms of eq. 6 share ``I_n(x_i(n))``, so eq. 6 equals ``sum (I_n(x_i(n)) - T)^2`` plus a
  constant, with the blended template ``T = (1 - epsilon) I_(n-1)(x(n-1)) + epsilon I_1(x(1))``:
  one residual per sample, and the exact Gauss-Newton step of eq. 6.
- Residuals ignore a brightness gain and bias varying linearly across each ROI
  (:mod:`~face_tracking_ros.imaging.photometric`): the shading of a turning head under a fixed
  light changes far more than eq. 6's brightness constancy allows.
- Levenberg-Marquardt over (omega, t, alpha) (and sigma during the first ``sigma_frames`` frames),
  coarse to fine on a Gaussian pyramid (made where the ROIs read it,
  :meth:`~face_tracking_ros.imaging.pyramid.ImagePyramid.level`), with Huber IRLS weights,
  per-node visibility (nodes whose normal turns away from the camera lose their weight) and
  analytic Jacobians: the image gradient sampled on the patches times d pixel / d X_c (eq. 2)
  times d X_c / d(omega, t, alpha) (eq. 1, 3), evaluated where a pyramid level starts and
  refreshed after half a pixel of motion. A level ends when the nodes stop moving or a step
  raises the cost, and a coarser level runs only when the first step on a finer one shows the
  face is too far for it (:func:`.coarse_to_fine`). The loops over the ROI samples are compiled
  (:mod:`.mono_kernels`).
- A caller can give a solve up before level 0 (``hopeless``): level 0 then is not solved when the
  coarser levels' solution, seen on level 0, already shows the solve cannot pass the caller's
  checks (the tracker's re-acquisition of a lost face, whose solves mostly fail).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from face_tracking_ros.imaging import ImagePyramid
from face_tracking_ros.imaging.photometric import PhotometricInvariance, PhotometricProjection
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.tracking.coarse_to_fine import coarse_to_fine
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.mono_kernels import (
    condition_number,
    iteration,
    linearised,
    point_cost,
)
from face_tracking_ros.tracking.mono_priors import Priors
from face_tracking_ros.tracking.mono_projection import FaceProjection, Sampled
from face_tracking_ros.tracking.mono_rois import Params, Roi
from face_tracking_ros.tracking.projection import POSE_DIM

Hopeless = Callable[[Params, Sampled, np.ndarray], bool]
"""``hopeless(params, sampled, residuals)``: whether a solve is given up before level 0, from the
coarser levels' solution ``params``, its level-0 samples and their (N, M) photometrically projected
residuals against level 0's template."""


class Level(NamedTuple):
    """One pyramid level of a frame's solve: what stays fixed while it runs.

    Attributes:
        index: the level l.
        pyramid: I_n's pyramid, read through :meth:`ImagePyramid.level`.
        camera: (3, 4) projection matrix P of level pixels (its first two rows times 2^-l).
        roi: the level's ROI samples.
        template: (N, M) blended template T of the level.
        projection: the photometric invariance of the residuals for ``template``.
        visibility: (N, M) the node visibility weight of every sample.
    """

    index: int
    pyramid: ImagePyramid
    camera: np.ndarray
    roi: Roi
    template: np.ndarray
    projection: PhotometricProjection
    visibility: np.ndarray


class Linearisation(NamedTuple):
    """Jacobians at a linearisation point on one pyramid level.

    Attributes:
        params: the linearisation point.
        sampled: the level's samples at ``params`` (taken with the gradient).
        jacobian_t: (P, N M) transposed derivative of the projected residuals, grey levels per
            parameter (rows contiguous, for the weighted products of the normal equations).
        hessian: (P, P) ``J' V J`` with the samples' visibility weights V alone; the normal
            equations of an iteration correct it for the samples whose weight differs.
        node_jacobian: (2 N, P) derivative of the node pixels, level px per parameter.
    """

    params: Params
    sampled: Sampled
    jacobian_t: np.ndarray
    hessian: np.ndarray
    node_jacobian: np.ndarray


class System(NamedTuple):
    """Eq. 6 normal equations at one parameter vector on one pyramid level, and the step from it.

    Attributes:
        cost: the cost, data term and priors.
        hessian: (P, P) the normal matrix H.
        scale: the robust residual scale s.
        sampled: the level's samples at the point.
        residuals: (N, M) their photometrically projected residuals.
        step: (P,) the damped step from the point (empty if the cost rose: none is taken).
        motion: the most the step moves a node, level px.
    """

    cost: float
    hessian: np.ndarray
    scale: float
    sampled: Sampled
    residuals: np.ndarray
    step: np.ndarray
    motion: float


class Solution(NamedTuple):
    """Outcome of the coarse-to-fine solve.

    Attributes:
        params: the solution: level 0's last point, or the one before it if the last step (which
            no iteration evaluated) raised the cost; level 1's solution if the solve was given up
            before level 0 (``hopeless`` of :meth:`MonoSolver.solve`).
        sampled: level 0's samples at ``params``.
        residuals: (N, M) their photometrically projected residuals against level 0's template.
        iterations: the iterations of every level solved.
        costs: the cost of each iteration, in the order they were run, then that of ``params``
            (not when given up: no level-0 cost was evaluated).
        condition: condition number of the last solved level's Jacobi-scaled normal matrix
            (level 0's unless given up).
        coarsest_solved: whether the coarsest pyramid level was solved.
    """

    params: Params
    sampled: Sampled
    residuals: np.ndarray
    iterations: int
    costs: tuple[float, ...]
    condition: float
    coarsest_solved: bool


class MonoSolver:
    """Levenberg-Marquardt on eq. 6 plus priors, coarse to fine down to level 0.

    Args:
        model: the face model (eq. 3).
        config: the tracker's tunables (the solve's: ``damping``, ``max_iterations``,
            ``convergence_px``, ``coarse_convergence_px``, ``jacobian_refresh_px``, ``huber_k``,
            ``residual_scale_floor``).
        face: the model posed and projected, which samples the ROIs.
        invariance: the photometric invariance of the residuals.
        priors: the priors on alpha and sigma.
    """

    def __init__(
        self,
        model: FaceModel,
        config: MonoTrackerConfig,
        face: FaceProjection,
        invariance: PhotometricInvariance,
        priors: Priors,
    ) -> None:
        """Keep the collaborators; precompute the node bases and the priors' Hessians."""
        self._config = config
        self._q = model.q
        self._face = face
        self._invariance = invariance
        self._action_basis = np.ascontiguousarray(model.action_basis_nodes())  # (N, 3, q)
        self._identity_action_basis = np.concatenate(
            (self._action_basis, model.shape_basis_nodes()), axis=-1
        )
        self._prior_hessians = {free: priors.hessian(free) for free in (False, True)}

    def solve(
        self,
        pyramid: ImagePyramid,
        start: Params,
        templates: Sequence[np.ndarray],
        node_weights: np.ndarray,
        rois: tuple[Roi, ...],
        free_sigma: bool,
        first_level: int,
        restart_px: float,
        hopeless: Hopeless | None = None,
        levels: int | None = None,
    ) -> Solution:
        """Solve eq. 6 from ``start``, coarse to fine.

        The solve starts on ``first_level``; when its first step exceeds ``restart_px`` (the
        configured ``coarsest_level_px``, or infinite: never) it starts over from ``start`` on a
        coarser level (:func:`.coarse_to_fine`). The Jacobian is evaluated where a level
        starts and re-evaluated only once the samples have moved ``jacobian_refresh_px`` since,
        for an iteration to come (not after a level's ``max_iterations``-th: the solves of a LOST
        image, far off the face, moved that far on most levels' last step, and 12 % of their
        Jacobians went unused); the iterations in between only sample the image (one
        ``cv2.remap`` of the ROI points each). A level ends when the nodes stop moving
        (``convergence_px``, ``coarse_convergence_px``) or at the first step that raises the
        cost: with the damping this small, a retry with more of it moves to about the same point.
        Level 0's last step, which no iteration evaluated, is undone if it raised the cost.

        Args:
            pyramid: I_n's pyramid.
            start: where the solve starts.
            templates: (N, M) blended template T of every level.
            node_weights: (N,) weight of each node's ROI.
            rois: every level's ROI samples.
            free_sigma: whether sigma is estimated too.
            first_level: the level solved first.
            restart_px: start over on a coarser level when the first step moves a node more
                than this, px of level 0.
            hopeless: when given, level 0 reached from a coarser level is solved only if this
                is false at the coarser levels' solution (:data:`Hopeless`); else the solve
                ends there, with that solution.
            levels: how many of the pyramid's finest levels are solved (all if None): the
                coarsest of them is the coarsest solved.
        """
        num_levels = pyramid.num_levels if levels is None else levels
        costs: list[float] = []
        projections: list[PhotometricProjection | None] = [None] * num_levels

        def projection(index: int) -> PhotometricProjection:
            made = projections[index]  # made for the levels solved only
            if made is None:
                made = projections[index] = self._invariance.projection(templates[index])
            return made

        accepted: list[tuple[Params, System]] = []  # each level's last accepted point
        coarsest = num_levels - 1
        coarsest_solved = False  # the coarsest level is always solved once it is started
        given_up: tuple[Sampled, np.ndarray] | None = None  # level 0 at the coarser solution

        def solve(index: int, params: Params, first_step_limit: float) -> Params | None:
            nonlocal coarsest_solved, given_up
            if index == 0 and accepted and hopeless is not None:
                sampled = self._face.sample(pyramid, params, 0, rois[0])
                residuals = projection(0).residuals(sampled.samples, templates[0])
                if hopeless(params, sampled, residuals):
                    given_up = (sampled, residuals)
                    return params  # level 0 left unsolved
            level = Level(
                index=index,
                pyramid=pyramid,
                camera=self._face.level_cameras[index],
                roi=rois[index],
                template=templates[index],
                projection=projection(index),
                visibility=np.repeat(node_weights[:, None], templates[index].shape[1], axis=1),
            )
            solution, last = self._solve_level(level, params, free_sigma, costs, first_step_limit)
            accepted.append(last)
            coarsest_solved |= index == coarsest
            return solution

        params = coarse_to_fine(num_levels, first_level, restart_px, start, solve)
        fallback, system = accepted[-1]  # level 0's, or the coarser one's if given up
        condition = condition_number(system.hessian)
        if given_up is not None:
            return Solution(
                params, *given_up, len(costs), tuple(costs), condition, coarsest_solved
            )
        first = self._face.sample(pyramid, params, 0, rois[0])
        residuals, cost = point_cost(
            first.samples,
            templates[0],
            projection(0).basis_rows,
            node_weights,
            first.inside,
            system.scale,
            self._config.huber_k,
            self._prior_hessians[free_sigma],
            _coefficients(params, free_sigma),
        )
        if cost > system.cost:  # the last, unchecked step made things worse
            params, first, residuals = fallback, system.sampled, system.residuals
        return Solution(
            params=params,
            sampled=first,
            residuals=residuals,
            iterations=len(costs),
            costs=(*costs, min(cost, system.cost)),
            condition=condition,
            coarsest_solved=coarsest_solved,
        )

    def _solve_level(
        self,
        level: Level,
        params: Params,
        free_sigma: bool,
        costs: list[float],
        first_step_limit: float,
    ) -> tuple[Params | None, tuple[Params, System]]:
        """Levenberg-Marquardt iterations on one pyramid level from ``params``.

        Appends each evaluated cost to ``costs``.

        Returns:
            The level's solution (None, without a step, when the first step would move a node
            more than ``first_step_limit`` level px) and the last accepted point with its
            system (the solution or the point before it).
        """
        config = self._config
        linear = self._linearise(level, params, free_sigma)
        damping = config.damping
        converged = config.coarse_convergence_px if level.index else config.convergence_px
        accepted: tuple[Params, System] | None = None
        scale = None
        moved = 0.0
        for done in range(1, config.max_iterations + 1):
            damping = max(0.1 * damping, 1e-9)  # the step's, if this point is accepted
            bound = np.inf if accepted is None else accepted[1].cost
            system = self._evaluate(level, params, linear, scale, damping, bound)
            scale = system.scale
            costs.append(system.cost)
            if accepted is not None and system.cost > bound:
                return accepted[0], accepted  # no lower cost within reach: the level ends here
            accepted = (params, system)
            motion = system.motion
            if motion > first_step_limit:
                return None, accepted
            first_step_limit = np.inf
            params = params.updated(system.step, self._q)
            if motion < converged:
                break
            moved += motion
            if moved > config.jacobian_refresh_px and done < config.max_iterations:
                linear = self._linearise(level, params, free_sigma)
                moved = 0.0
        assert accepted is not None  # max_iterations >= 1
        return params, accepted

    def _linearise(self, level: Level, params: Params, free_sigma: bool) -> Linearisation:
        """The Jacobian of eq. 6's photometrically projected residuals at ``params``.

        Image gradient (sampled on the ROIs only) x d pixel / d X_c (eq. 2) x d X_c / d(omega,
        t, alpha[, sigma]) (eq. 1, 3), then ``1 - P`` of the photometric model, and ``J' V J``:
        one compiled pass over the samples (:func:`~.mono_kernels.linearised`).
        """
        basis = self._identity_action_basis if free_sigma else self._action_basis
        rotation, shape = self._face.pose(params)
        maps, sampled, stencil = self._face.sample_stencil(
            level.pyramid, params, level.index, level.roi
        )
        jacobian_t, hessian, node_jacobian = linearised(
            stencil,
            maps.rotated,
            rotation @ shape.T,
            params.t,
            level.camera,
            rotation,
            self._face.d_rotation(params),
            basis,
            level.roi.basis(free_sigma),
            level.projection.basis_rows,
            level.visibility.ravel(),
        )
        return Linearisation(params, sampled, jacobian_t, hessian, node_jacobian)

    def _evaluate(
        self,
        level: Level,
        params: Params,
        linear: Linearisation,
        scale: float | None,
        damping: float,
        bound: float,
    ) -> System:
        """Residuals, Huber-weighted normal equations, cost and step of eq. 6 on one level.

        ``J' W J`` is the linearisation's ``J' V J`` plus the columns of the samples whose IRLS
        weight W (Huber times visibility times inside the image) differs from their visibility V;
        the priors' terms are added, and the damped step taken unless the cost exceeds ``bound``
        (:func:`~.mono_kernels.iteration`, one compiled call after the sampling).

        Args:
            level: the pyramid level, with its template, photometric projection and visibility.
            params: where to evaluate.
            linear: the Jacobian (from a nearby linearisation point).
            scale: the robust residual scale s, or None to estimate it from these residuals.
            damping: the step's damping lambda.
            bound: the cost of the level's last accepted point (inf for none).
        """
        sampled = (
            linear.sampled
            if params is linear.params
            else self._face.sample(level.pyramid, params, level.index, level.roi)
        )
        free_sigma = linear.jacobian_t.shape[0] > POSE_DIM + self._q
        result = iteration(
            sampled.samples,
            level.template,
            level.projection.basis_rows,
            level.visibility,
            sampled.inside,
            scale,
            self._config.residual_scale_floor,
            self._config.huber_k,
            (linear.jacobian_t, linear.hessian, linear.node_jacobian),
            self._prior_hessians[free_sigma],
            _coefficients(params, free_sigma),
            damping,
            bound,
        )
        return System(
            cost=result.cost,
            hessian=result.hessian,
            scale=result.scale,
            sampled=sampled,
            residuals=result.residuals,
            step=result.step,
            motion=result.motion,
        )


def _coefficients(params: Params, free_sigma: bool) -> np.ndarray:
    """The coefficients the priors weigh: alpha, then sigma while it is free."""
    return np.concatenate((params.alpha, params.sigma)) if free_sigma else params.alpha
